// End-to-end sessions as real processes over loopback DDS, each test in a partition of its
// own. Processes are stopped by PID and reaped.
#include <gtest/gtest.h>
#include <stdlib.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <regex>
#include <set>

#include "process.h"
#include "process_test.h"
#include "telehand/server/store/sqlite_store.h"

namespace telehand::test {
namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;

class SessionTest : public ProcessTest {
 protected:
  SessionTest() : ProcessTest("it", TELEHAND_LOOPBACK_XML) {}
};

TEST_F(SessionTest, ServerClientWatcherRecordEverySample) {
  const std::string db = path("records.db");
  Process server(cmd(TELEHAND_SERVER_BIN, {"--db", db, "--seconds", "60"}), path("server.log"));
  Process client(cmd(TELEHAND_CLIENT_BIN, {"--seconds", "5", "-q"}), path("client.log"));
  std::this_thread::sleep_for(1500ms);  // the supervisor joins a running session
  Process watcher(cmd(TELEHAND_WATCH_BIN, {"--plain", "--exit-on-close", "--wait", "20"}),
                  path("watch.log"));

  const auto client_rc = client.wait(30s);
  ASSERT_TRUE(client_rc.has_value()) << "client did not finish\n" << client.output();
  EXPECT_EQ(*client_rc, 0) << client.output();
  const auto watch_rc = watcher.wait(20s);
  ASSERT_TRUE(watch_rc.has_value()) << "watcher did not exit on close\n" << watcher.output();
  EXPECT_EQ(*watch_rc, 0) << watcher.output();
  EXPECT_EQ(server.stop(), 0) << server.output();

  const std::string out = client.output();
  const uint64_t session = matchNumber(out, R"(session (\d+) open)");
  const uint64_t sent = matchNumber(out, R"((\d+) samples sent)");
  ASSERT_GT(session, 0u) << out;
  ASSERT_GT(sent, 4000u) << out;  // 5 s at 1 kHz

  // The watcher saw this session, live, with the joint moving and the model known.
  const std::string seen = watcher.output();
  EXPECT_NE(seen.find("session=" + std::to_string(session)), std::string::npos) << seen;
  EXPECT_NE(seen.find("mode=mobilization"), std::string::npos) << seen;
  // The model is known: a version the server published (its drift corrections can take it
  // past 1 before the supervisor joins at 1.5 s).
  EXPECT_GE(matchNumber(seen, R"( model_v=(\d+))"), 1u) << seen;
  EXPECT_GT(matchNumber(seen, R"(hand_states=(\d+))"), 50u) << seen;

  // The record holds every sequence number the client sent, once.
  server::store::SqliteStore store(db, server::store::SqliteStore::Mode::kReadOnly);
  const auto info = store.session(session);
  ASSERT_TRUE(info.has_value());
  EXPECT_EQ(info->state, "closed");
  EXPECT_EQ(info->samples, sent);
  uint64_t expect_seq = 0;
  uint64_t gaps = 0;
  store.forEachSample(session, [&](const Sample& s, bool valid) {
    gaps += s.seq != expect_seq;
    expect_seq = s.seq + 1;
    EXPECT_TRUE(valid);
  });
  EXPECT_EQ(gaps, 0u);
  EXPECT_EQ(expect_seq, sent);
}

TEST_F(SessionTest, AnIdleServerMakesItsParticipantAgainAndServesWhoComesNext) {
  // Once its last session has ended and been retired, the server deletes its DDS participant
  // (and with it Cyclone's domain) and makes it again (server.renew_when_idle): the next
  // client finds it, is recorded in full, and the latency echo answers.
  const std::string db = path("records.db");
  {
    std::ofstream cfg(path("server.toml"));
    cfg << "[server]\nstatus_keep_s = 0.5\nrenew_when_idle = true\n";
  }
  Process server(
      cmd(TELEHAND_SERVER_BIN, {"--config", path("server.toml"), "--db", db, "--seconds", "90"}),
      path("server.log"));
  const auto runClient = [&](const std::string& name) {
    Process client(cmd(TELEHAND_CLIENT_BIN, {"--seconds", "2", "-q"}), path(name + ".log"));
    const auto rc = client.wait(60s);
    EXPECT_EQ(rc, std::optional<int>(0)) << client.output();
    return std::pair{matchNumber(client.output(), R"(session (\d+) open)"),
                     matchNumber(client.output(), R"((\d+) samples sent)")};
  };
  const auto awaitRenewals = [&](std::size_t n) {
    return awaitOccurrences([&] { return server.output(); }, "DDS participant made again", n, 30s);
  };
  const auto first = runClient("first");
  ASSERT_EQ(awaitRenewals(1), 1u) << server.output();
  const auto second = runClient("second");
  ASSERT_EQ(awaitRenewals(2), 2u) << server.output();
  Process latency(
      cmd(TELEHAND_LATENCY_BIN, {"--echo", "server", "--seconds", "1", "--rate", "200", "--warmup",
                                 "0.2", "-q", "--json", path("latency.json")}),
      path("latency.log"));
  EXPECT_EQ(latency.wait(60s), std::optional<int>(0)) << latency.output();
  EXPECT_EQ(server.stop(), 0) << server.output();
  std::ifstream json_in(path("latency.json"));
  const std::string json((std::istreambuf_iterator<char>(json_in)), {});
  EXPECT_GT(matchNumber(json, "\"received\": (\\d+)"), 100u) << json;
  EXPECT_NE(json.find("\"echo\": \"external"), std::string::npos) << json;

  server::store::SqliteStore store(db, server::store::SqliteStore::Mode::kReadOnly);
  for (const auto& [session, sent] : {first, second}) {
    ASSERT_GT(session, 0u);
    ASSERT_GT(sent, 1500u);
    const auto info = store.session(session);
    ASSERT_TRUE(info.has_value());
    EXPECT_EQ(info->state, "closed");
    EXPECT_EQ(info->samples, sent);
  }
  EXPECT_NE(first.first, second.first);
}

TEST_F(SessionTest, MalformedConfigIsNamed) {
  {
    std::ofstream bad(path("client.toml"));
    bad << "[operator]\nfrequency_hz = \"three\"\n";
  }
  Process client({TELEHAND_CLIENT_BIN, "--config", path("client.toml")}, path("client.log"));
  EXPECT_EQ(client.wait(10s), 2);
  EXPECT_NE(client.output().find("client.toml"), std::string::npos) << client.output();
  EXPECT_NE(client.output().find("operator.frequency_hz"), std::string::npos) << client.output();

  {
    std::ofstream bad(path("server.toml"));
    bad << "[server]\nhand_state_hz = 100\ndb_path = 'x'\n";  // the key is 'db'
  }
  Process server({TELEHAND_SERVER_BIN, "--config", path("server.toml")}, path("server.log"));
  EXPECT_EQ(server.wait(10s), 2);
  EXPECT_NE(server.output().find("line 3"), std::string::npos) << server.output();
  EXPECT_NE(server.output().find("server.db_path"), std::string::npos) << server.output();

  {
    std::ofstream bad(path("broken.toml"));
    bad << "[server\n";
  }
  Process broken({TELEHAND_SERVER_BIN, "--config", path("broken.toml")}, path("broken.log"));
  EXPECT_EQ(broken.wait(10s), 2);
  EXPECT_NE(broken.output().find("broken.toml: line 1"), std::string::npos) << broken.output();
}

TEST_F(SessionTest, BadInputIsReportedAndOtherSessionsKeepRecording) {
  const std::string db = path("records.db");
  Process server(cmd(TELEHAND_SERVER_BIN, {"--db", db, "--seconds", "60"}), path("server.log"));
  Process client(cmd(TELEHAND_CLIENT_BIN, {"--seconds", "5", "-q"}), path("client.log"));
  std::this_thread::sleep_for(500ms);

  Process close_unknown(cmd(TELEHAND_INJECT_BIN, {"close-unknown", "--session", "987654"}),
                        path("close.log"));
  Process unknown_state(cmd(TELEHAND_INJECT_BIN, {"unknown-state", "--session", "424242"}),
                        path("state.log"));
  Process nan(cmd(TELEHAND_INJECT_BIN, {"nan", "--count", "300"}), path("nan.log"));

  EXPECT_EQ(close_unknown.wait(20s), 0) << close_unknown.output();
  EXPECT_NE(close_unknown.output().find("CLOSE for unknown session 987654"), std::string::npos);
  EXPECT_EQ(unknown_state.wait(20s), 0) << unknown_state.output();
  EXPECT_NE(unknown_state.output().find("DeviceState for unknown session 424242"),
            std::string::npos);
  ASSERT_EQ(nan.wait(30s), 0) << nan.output();
  const std::string nan_out = nan.output();
  EXPECT_NE(nan_out.find("non-finite fingers[1] (index).position_m[0]"), std::string::npos)
      << nan_out;
  EXPECT_NE(nan_out.find("recorded=300 missing=0"), std::string::npos) << nan_out;

  const auto client_rc = client.wait(30s);
  ASSERT_TRUE(client_rc.has_value());
  EXPECT_EQ(*client_rc, 0) << client.output();
  EXPECT_EQ(server.stop(), 0) << server.output();

  const uint64_t session = matchNumber(client.output(), R"(session (\d+) open)");
  const uint64_t sent = matchNumber(client.output(), R"((\d+) samples sent)");
  const uint64_t nan_session = matchNumber(nan_out, R"(session=(\d+))");
  server::store::SqliteStore store(db, server::store::SqliteStore::Mode::kReadOnly);
  EXPECT_EQ(store.session(session)->samples, sent);
  const auto bad = store.session(nan_session);
  ASSERT_TRUE(bad.has_value());
  EXPECT_EQ(bad->samples, 300u);
  EXPECT_EQ(bad->rejected, 1u);  // kept, flagged invalid, not silently dropped
  EXPECT_FALSE(store.session(987654).has_value());
  EXPECT_FALSE(store.session(424242).has_value());
}

}  // namespace
}  // namespace telehand::test
