// Crash recovery (docs/recovery.md) with real processes over loopback DDS: a server killed
// (SIGKILL) or stopped (SIGTERM) in the middle of a session and started again 5 s later on
// the same record; the client's loop runs on, keeps every sample the server had not
// acknowledged as stored, and the session resumes under the same id with nothing missing.
#include <gtest/gtest.h>
#include <signal.h>

#include <fstream>
#include <thread>

#include "process.h"
#include "process_test.h"
#include "telehand/server/store/sqlite_store.h"

namespace telehand::test {
namespace {

using namespace std::chrono_literals;

class RecoveryTest : public ProcessTest {
 protected:
  RecoveryTest() : ProcessTest("rec", TELEHAND_LOOPBACK_XML) {}

  std::vector<std::string> serverCmd(double resume_wait_s) {
    {
      std::ofstream cfg(path("server.toml"));
      cfg << "[server]\nresume_wait_s = " << resume_wait_s << "\n";
    }
    return cmd(TELEHAND_SERVER_BIN,
               {"--config", path("server.toml"), "--db", path("records.db"), "--seconds", "120"});
  }

  /// Waits until `p`'s output matches `pattern` (group 1 a number); 0 on timeout.
  static uint64_t awaitNumber(Process& p, const std::string& pattern,
                              std::chrono::milliseconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < deadline) {
      if (const uint64_t n = matchNumber(p.output(), pattern)) return n;
      std::this_thread::sleep_for(50ms);
    }
    return 0;
  }

  /// The record of `session`: every sequence number below `sent` exactly once.
  void expectWholeRecord(uint64_t session, uint64_t sent) {
    server::store::SqliteStore store(path("records.db"),
                                     server::store::SqliteStore::Mode::kReadOnly);
    const auto info = store.session(session);
    ASSERT_TRUE(info.has_value());
    EXPECT_EQ(info->state, "closed");
    EXPECT_EQ(info->samples, sent);
    EXPECT_EQ(info->samples_expected, sent);
    uint64_t expect_seq = 0, gaps = 0;
    store.forEachSample(session, [&](const Sample& s, bool) {
      gaps += s.seq != expect_seq;
      expect_seq = s.seq + 1;
    });
    EXPECT_EQ(gaps, 0u);
    EXPECT_EQ(expect_seq, sent);
    std::string events;
    for (const auto& e : store.events(session)) events += e.kind + ": " + e.text + "\n";
    EXPECT_NE(events.find("resumed: mobilization"), std::string::npos) << events;
  }

  /// A 20 s session whose server goes away at 5 s (`sig`) and comes back 5 s later.
  void serverGoesAwayAndComesBack(int sig) {
    auto server = std::make_unique<Process>(serverCmd(60.0), path("server1.log"));
    Process client(cmd(TELEHAND_CLIENT_BIN, {"--seconds", "20", "-q", "--no-fault-stop"}),
                   path("client.log"));
    const uint64_t session = awaitNumber(client, R"(session (\d+) open)", 20s);
    ASSERT_GT(session, 0u) << client.output();
    std::this_thread::sleep_for(5s);
    ASSERT_EQ(::kill(server->pid(), sig), 0);
    const auto gone = server->wait(15s);
    ASSERT_TRUE(gone.has_value()) << server->output();
    if (sig == SIGTERM) {
      EXPECT_EQ(*gone, 0) << server->output();
      server::store::SqliteStore store(path("records.db"),
                                       server::store::SqliteStore::Mode::kReadOnly);
      EXPECT_EQ(store.session(session)->state, "suspended");
    }
    std::this_thread::sleep_for(5s);
    Process again(serverCmd(60.0), path("server2.log"));
    const auto rc = client.wait(60s);
    ASSERT_TRUE(rc.has_value()) << "the client did not finish\n" << client.output();
    EXPECT_EQ(*rc, 0) << client.output();
    EXPECT_EQ(again.stop(), 0) << again.output();
    const std::string out = client.output();
    EXPECT_EQ(matchNumber(out, R"(session (\d+) open)"), session);
    EXPECT_NE(out.find("resumed on a server"), std::string::npos) << out;
    EXPECT_NE(out.find("recovery: resumed 1 time"), std::string::npos) << out;
    const uint64_t sent = matchNumber(out, R"((\d+) samples sent)");
    EXPECT_GT(sent, 19000u) << out;  // the loop never stopped: 20 s at 1 kHz
    expectWholeRecord(session, sent);
    std::cout << "client: " << out.substr(out.find("summary:")) << "\n";
  }
};

TEST_F(RecoveryTest, AServerKilledMidSessionIsResumedWithNothingMissing) {
  serverGoesAwayAndComesBack(SIGKILL);
}

TEST_F(RecoveryTest, AServerStoppedMidSessionSuspendsItAndTheNextResumesIt) {
  serverGoesAwayAndComesBack(SIGTERM);
}

// A client that never comes back: the next server finds the session open in the record,
// waits server.resume_wait_s for it, and closes it as interrupted with `missing` counting
// what the record lacks below the last sample it holds.
TEST_F(RecoveryTest, ASessionNobodyResumesIsClosedAsInterruptedAndSaysWhatIsMissing) {
  auto server = std::make_unique<Process>(serverCmd(60.0), path("server1.log"));
  Process client(cmd(TELEHAND_CLIENT_BIN, {"--seconds", "30", "-q", "--no-fault-stop"}),
                 path("client.log"));
  const uint64_t session = awaitNumber(client, R"(session (\d+) open)", 20s);
  ASSERT_GT(session, 0u) << client.output();
  std::this_thread::sleep_for(3s);
  ASSERT_EQ(::kill(client.pid(), SIGKILL), 0);
  ASSERT_EQ(::kill(server->pid(), SIGKILL), 0);
  ASSERT_TRUE(client.wait(10s).has_value());
  ASSERT_TRUE(server->wait(10s).has_value());
  Process again(serverCmd(2.0), path("server2.log"));
  std::optional<server::store::SessionInfo> info;
  const auto deadline = std::chrono::steady_clock::now() + 20s;
  while (std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(500ms);
    server::store::SqliteStore store(path("records.db"),
                                     server::store::SqliteStore::Mode::kReadOnly);
    info = store.session(session);
    if (info && info->state == "interrupted") break;
  }
  EXPECT_EQ(again.stop(), 0) << again.output();
  ASSERT_TRUE(info.has_value());
  EXPECT_EQ(info->state, "interrupted") << again.output();
  server::store::SqliteStore store(path("records.db"), server::store::SqliteStore::Mode::kReadOnly);
  const auto extent = store.extent(session);
  ASSERT_TRUE(extent.has_value());
  // `missing` (expected − samples) counts exactly the sequence numbers below the last one
  // stored that the record lacks.
  EXPECT_EQ(info->samples_expected, extent->last_seq + 1);
  EXPECT_EQ(info->samples_expected - info->samples,
            extent->last_seq + 1 - store.countSamples(session, 0, extent->last_seq));
  EXPECT_GT(info->samples, 1000u);
  std::string events;
  for (const auto& e : store.events(session)) events += e.kind + ": " + e.text + "\n";
  EXPECT_NE(events.find("recovered: its server died"), std::string::npos) << events;
  EXPECT_NE(events.find("not resumed within 2 s"), std::string::npos) << events;
}

// One server per SQLite record: a second one on the same file would recover, write and close
// the first one's sessions. It is refused by name; the first serves on.
TEST_F(RecoveryTest, ASecondServerOnTheSameRecordIsRefused) {
  Process first(serverCmd(60.0), path("server1.log"));
  Process client(cmd(TELEHAND_CLIENT_BIN, {"--seconds", "4", "-q", "--no-fault-stop"}),
                 path("client.log"));
  ASSERT_GT(awaitNumber(client, R"(session (\d+) open)", 20s), 0u) << client.output();
  Process second(serverCmd(60.0), path("server2.log"));
  EXPECT_EQ(second.wait(20s), std::optional<int>(2)) << second.output();
  EXPECT_NE(second.output().find(path("records.db") + " is already served by another"),
            std::string::npos)
      << second.output();
  EXPECT_EQ(client.wait(30s), std::optional<int>(0)) << client.output();
  EXPECT_EQ(first.stop(), 0) << first.output();
  // Once the first has stopped, the record is free again.
  Process third(serverCmd(60.0), path("server3.log"));
  std::this_thread::sleep_for(2s);
  EXPECT_TRUE(third.alive()) << third.output();
  EXPECT_EQ(third.stop(), 0) << third.output();
}

}  // namespace
}  // namespace telehand::test
