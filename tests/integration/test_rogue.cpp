// A rogue participant against a real session (server and client as processes): it sends
// RecordChunks just ahead of the client's sequence numbers, a CLOSE, a 20 MB SessionFile, a
// forged SessionStatus CLOSED and a forged JointModel (coefficients x100) for the client's
// session, and floods the server with OPENs. Without security the rogue is a participant on
// the same partition; with it, an authenticated device of the same PKI. Either way the
// client's session is recorded whole and only the client's samples are in it.
#include <gtest/gtest.h>
#include <stdlib.h>

#include <algorithm>
#include <chrono>
#include <fstream>
#include <iostream>
#include <string>
#include <string_view>
#include <thread>

#include "process.h"
#include "process_test.h"
#include "telehand/server/store/sqlite_store.h"

namespace telehand::test {
namespace {

using namespace std::chrono_literals;

/// What telehand-test-inject writes into another session (inject_main.cpp).
constexpr uint32_t kForgedVersion = 4242;
constexpr double kMarkerM = 0.0424242;

/// VmRSS of a process in kB (0 when it is gone).
uint64_t rssKb(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.starts_with("VmRSS:")) return std::stoull(line.substr(6));
  }
  return 0;
}

class RogueTest : public ProcessTest {
 protected:
  RogueTest() : ProcessTest("rogue", TELEHAND_LOOPBACK_XML) {}
  void SetUp() override {
    ProcessTest::SetUp();
    // A secure participant of this process (SecurityTest) leaves its PKI and identity in
    // the environment, where the children would take them as their defaults.
    ::unsetenv("TELEHAND_PKI");
    ::unsetenv("TELEHAND_IDENTITY");
  }

  /// A PKI with the default identities and a second device, 'lab9-mf2', for the rogue.
  void makePki() {
    const std::string dir = path("pki");
    Process make({TELEHAND_MAKE_PKI, dir}, path("pki.log"));
    ASSERT_EQ(make.wait(60s), std::optional<int>(0)) << make.output();
    Process more({TELEHAND_MAKE_PKI, dir, "lab9-mf2:device"}, path("pki-more.log"));
    ASSERT_EQ(more.wait(60s), std::optional<int>(0)) << more.output();
    pki_ = dir;
  }

  /// The rogue's command line: as 'lab9-mf2' under security.
  std::vector<std::string> rogue(std::vector<std::string> args) const {
    if (!pki_.empty()) {
      args.push_back("--identity");
      args.push_back("lab9-mf2");
    }
    return cmd(TELEHAND_INJECT_BIN, std::move(args));
  }

  struct Attacks {
    std::string chunk, close, file, status, model;
    std::optional<int> status_rc, model_rc;
  };

  /// Server, an 8 s client, and the rogue's attacks on the client's session; then the
  /// checks every run shares: the client exits 0 and its record is whole and its own.
  Attacks run() {
    Attacks a;
    const std::string db = path("records.db");
    Process server(cmd(TELEHAND_SERVER_BIN, {"--db", db, "--seconds", "60"}), path("server.log"));
    // --no-fault-stop: a loop stalled on a busy machine is a fault of its own (tested
    // elsewhere), not what this test is about.
    Process client(cmd(TELEHAND_CLIENT_BIN, {"--seconds", "8", "-q", "--no-fault-stop"}),
                   path("client.log"));
    // First the chunks ahead of the client (the refusal it reports is the first of the
    // session, so the event names it), then the rest at once. The forged status goes on
    // past the client's CLOSE, at 1 kHz: forgeries share the session's instance with the
    // server's samples and must not push its CLOSED out of the client's reader.
    Process chunk(rogue({"chunk-ahead", "--wait", "2"}), path("chunk.log"));
    EXPECT_EQ(chunk.wait(30s), std::optional<int>(0)) << chunk.output();
    const std::string victim =
        std::to_string(matchNumber(chunk.output(), R"(attacking session (\d+))"));
    Process close(rogue({"close", "--session", victim, "--wait", "1"}), path("close.log"));
    Process file(rogue({"file", "--session", victim, "--bytes", "20000000", "--wait", "1"}),
                 path("file.log"));
    Process status(rogue({"forge-status", "--session", victim, "--wait", "10", "--period-ms", "1"}),
                   path("status.log"));
    Process model(rogue({"forge-model", "--session", victim, "--wait", "5", "--period-ms", "1"}),
                  path("model.log"));
    EXPECT_EQ(close.wait(30s), std::optional<int>(0)) << close.output();
    EXPECT_EQ(file.wait(60s), std::optional<int>(0)) << file.output();
    a.model_rc = model.wait(30s);
    a.status_rc = status.wait(30s);

    const auto client_rc = client.wait(30s);
    EXPECT_TRUE(client_rc.has_value()) << "client did not finish\n" << client.output();
    EXPECT_EQ(client_rc, std::optional<int>(0)) << client.output();
    EXPECT_EQ(server.stop(), 0) << server.output();
    a.chunk = chunk.output();
    a.close = close.output();
    a.file = file.output();
    a.status = status.output();
    a.model = model.output();

    const std::string out = client.output();
    const uint64_t session = matchNumber(out, R"(session (\d+) open)");
    const uint64_t sent = matchNumber(out, R"((\d+) samples sent)");
    EXPECT_GT(session, 0u) << out;
    EXPECT_GT(sent, 6000u) << out;  // 8 s at 1 kHz
    // The client took its record's figures from the server, not from the forged status.
    EXPECT_NE(out.find("record: " + std::to_string(sent) + " samples recorded, 0 missing"),
              std::string::npos)
        << out;
    EXPECT_EQ(
        a.chunk.find("attacking session " + std::to_string(session) + "\n") != std::string::npos,
        true)
        << a.chunk;

    server::store::SqliteStore store(db, server::store::SqliteStore::Mode::kReadOnly);
    const auto info = store.session(session);
    EXPECT_TRUE(info.has_value());
    if (!info) return a;
    EXPECT_EQ(info->state, "closed");
    EXPECT_EQ(info->samples, sent);
    EXPECT_EQ(info->samples_expected, sent) << "the rogue's CLOSE (1 sample) was taken";
    EXPECT_EQ(info->rejected, 0u);
    EXPECT_FALSE(info->owner.empty());
    uint64_t rows = 0, gaps = 0, next = 0, marked = 0, forged = 0, invalid = 0;
    uint32_t highest_version = 0;
    store.forEachSample(session, [&](const Sample& s, bool valid) {
      ++rows;
      gaps += s.seq != next;
      next = s.seq + 1;
      marked += s.fingers[0].position_m[0] == kMarkerM;
      forged += s.model_version == kForgedVersion;
      highest_version = std::max(highest_version, s.model_version);
      invalid += !valid;
    });
    EXPECT_EQ(rows, sent);
    EXPECT_EQ(gaps, 0u);
    EXPECT_EQ(next, sent) << "no sequence number past the client's last";
    EXPECT_EQ(marked, 0u) << "rows from the rogue's chunks";
    EXPECT_EQ(forged, 0u) << "the client rendered the forged JointModel";
    EXPECT_LT(highest_version, 100u);
    EXPECT_EQ(invalid, 0u);
    EXPECT_TRUE(store.files(session).empty());
    // The refusal is an event of the session's record, naming what and whom.
    std::string refused;
    for (const auto& e : store.events(session)) {
      if (e.text.find("security: refused") != std::string::npos) refused += e.text + "\n";
    }
    EXPECT_NE(refused.find("security: refused a RecordChunk from participant "), std::string::npos)
        << refused;
    EXPECT_NE(refused.find("session " + std::to_string(session) + " belongs to " + info->owner),
              std::string::npos)
        << refused;
    EXPECT_NE(a.chunk.find("refused: security: refused a RecordChunk"), std::string::npos)
        << a.chunk;
    return a;
  }
};

TEST_F(RogueTest, AParticipantOnThePartitionCannotTouchAnotherSession) {
  const Attacks a = run();
  // Unsecured, the rogue can write anything; the server and the client take none of it.
  EXPECT_EQ(a.status_rc, std::optional<int>(0)) << a.status;
  EXPECT_GT(matchNumber(a.status, R"(forged (\d+) SessionStatus)"), 1000u) << a.status;
  EXPECT_EQ(a.model_rc, std::optional<int>(0)) << a.model;
  EXPECT_GT(matchNumber(a.model, R"(forged (\d+) JointModel)"), 1000u) << a.model;
  EXPECT_NE(a.close.find("sent CLOSE"), std::string::npos) << a.close;
  EXPECT_NE(a.file.find("sent a SessionFile of 20000000 bytes"), std::string::npos) << a.file;
}

TEST_F(RogueTest, AnAuthenticatedDeviceCannotTouchAnotherSession) {
  makePki();
  const Attacks a = run();
  // The device role may not write what only servers publish: the writers are not created.
  EXPECT_EQ(a.status_rc, std::optional<int>(4)) << a.status;
  EXPECT_NE(a.status.find("writer refused: SessionStatus"), std::string::npos) << a.status;
  EXPECT_EQ(a.model_rc, std::optional<int>(4)) << a.model;
  EXPECT_NE(a.model.find("writer refused: JointModel"), std::string::npos) << a.model;
  // What it may write (chunks, commands, files) is refused by ownership.
  EXPECT_NE(a.close.find("sent CLOSE"), std::string::npos) << a.close;
  EXPECT_NE(a.file.find("sent a SessionFile of 20000000 bytes"), std::string::npos) << a.file;
}

TEST_F(RogueTest, AFloodOfOpensIsBoundedByMaxSessions) {
  // 10,000 OPENs from 16 participants (4 sessions each at most): the server opens its 64
  // (server.max_sessions, each with a Bullet hand) and refuses the rest. Measured, not
  // timed: the server's RSS before, at the peak and after the sessions end.
  const std::string db = path("records.db");
  {
    std::ofstream cfg(path("server.toml"));
    // Without the participant made again when idle: the injector sends each OPEN once, and
    // a participant only just made missed some of a flood's (docs/security.md "Memory").
    cfg << "[server]\nstatus_keep_s = 2.0\nrenew_when_idle = false\n";
  }
  Process server(
      cmd(TELEHAND_SERVER_BIN, {"--config", path("server.toml"), "--db", db, "--seconds", "300"}),
      path("server.log"));
  // A first session and its end: what the server keeps once it has served one.
  Process warm(cmd(TELEHAND_INJECT_BIN, {"open-flood", "--count", "1", "--hold", "0"}),
               path("warm.log"));
  ASSERT_EQ(warm.wait(30s), std::optional<int>(0)) << warm.output();
  // The server ends a session (and frees its place under server.max_sessions) in its own
  // time: each step waits for the sessions before it to have ended, as the server's log says.
  std::size_t ended = 0;
  const auto waitEnded = [&](std::size_t more) {
    ended += more;
    const auto deadline = std::chrono::steady_clock::now() + 60s;
    std::size_t seen = 0;
    while (std::chrono::steady_clock::now() < deadline) {
      const std::string log = server.output();
      seen = 0;
      for (auto at = log.find(" samples recorded"); at != std::string::npos;
           at = log.find(" samples recorded", at + 1)) {
        ++seen;
      }
      if (seen >= ended) return true;
      std::this_thread::sleep_for(100ms);
    }
    ADD_FAILURE() << seen << " sessions ended in 60 s, not " << ended;
    return false;
  };
  ASSERT_TRUE(waitEnded(1));
  std::this_thread::sleep_for(3s);
  const uint64_t baseline = rssKb(server.pid());
  ASSERT_GT(baseline, 0u);
  Process four(cmd(TELEHAND_INJECT_BIN, {"open-flood", "--count", "4", "--hold", "3"}),
               path("four.log"));
  uint64_t four_peak = 0;
  while (!four.wait(0ms)) {
    four_peak = std::max(four_peak, rssKb(server.pid()));
    std::this_thread::sleep_for(50ms);
  }
  ASSERT_EQ(four.wait(0ms), std::optional<int>(0)) << four.output();
  ASSERT_EQ(matchNumber(four.output(), R"(opened=(\d+))"), 4u) << four.output();
  const double per_session_kb = static_cast<double>(four_peak - baseline) / 4.0;
  ASSERT_TRUE(waitEnded(4));
  std::this_thread::sleep_for(3s);

  Process flood(cmd(TELEHAND_INJECT_BIN,
                    {"open-flood", "--count", "10000", "--participants", "16", "--hold", "3"}),
                path("flood.log"));
  uint64_t peak = 0;
  while (!flood.wait(0ms)) {
    peak = std::max(peak, rssKb(server.pid()));
    std::this_thread::sleep_for(50ms);
  }
  EXPECT_EQ(flood.wait(0ms), std::optional<int>(0)) << flood.output();
  const std::string out = flood.output();
  EXPECT_EQ(matchNumber(out, R"(opened=(\d+))"), 64u) << out;
  EXPECT_EQ(matchNumber(out, R"(closed=(\d+))"), 64u) << out;
  ASSERT_TRUE(waitEnded(64));
  std::this_thread::sleep_for(3s);  // past status_keep_s: the sessions are retired
  const uint64_t after = rssKb(server.pid());
  // The same flood twice more: what the first one left (caches grown toward their size:
  // SQLite's pages, Cyclone's buffers, the allocator's arenas) must stop growing, or
  // something grows with every session.
  std::vector<uint64_t> after_floods;
  for (int round = 0; round < 2; ++round) {
    Process again(cmd(TELEHAND_INJECT_BIN,
                      {"open-flood", "--count", "10000", "--participants", "16", "--hold", "3"}),
                  path("again-" + std::to_string(round) + ".log"));
    EXPECT_EQ(again.wait(60s), std::optional<int>(0)) << again.output();
    EXPECT_EQ(matchNumber(again.output(), R"(opened=(\d+))"), 64u) << again.output();
    ASSERT_TRUE(waitEnded(64));
    std::this_thread::sleep_for(3s);
    after_floods.push_back(rssKb(server.pid()));
  }
  const uint64_t after_again = after_floods.back();
  // Sessions that come and go, one after another: 640 opened and closed (16 participants,
  // each keeping 4 opening or open, so that every OPEN is taken).
  Process churn(cmd(TELEHAND_INJECT_BIN, {"open-churn", "--count", "640", "--participants", "16"}),
                path("churn.log"));
  EXPECT_TRUE(churn.wait(240s).has_value()) << churn.output();
  // An OPEN the server refused (its limits count a session until its CLOSED is out) is given
  // up after 5 s; nearly all are taken.
  EXPECT_GE(matchNumber(churn.output(), R"(closed=(\d+))"), 600u) << churn.output();
  std::this_thread::sleep_for(3s);
  const uint64_t after_churn = rssKb(server.pid());
  EXPECT_EQ(server.stop(), 0) << server.output();
  EXPECT_NE(server.output().find("security: refused an OPEN from participant"), std::string::npos);

  const double bound_kb = static_cast<double>(baseline) + 64.0 * per_session_kb;
  const auto mb = [](auto kb) { return static_cast<double>(kb) / 1024.0; };
  std::cout << "server RSS: baseline " << mb(baseline) << " MB, " << mb(per_session_kb)
            << " MB per session (4 sessions: peak " << mb(four_peak) << " MB), flood peak "
            << mb(peak) << " MB (bound baseline + 64 x per session = " << mb(bound_kb)
            << " MB), after the sessions end " << mb(after) << " MB, after a second and third "
            << "flood " << mb(after_floods[0]) << " and " << mb(after_floods[1])
            << " MB, after 640 sessions more " << mb(after_churn) << " MB\n";
  RecordProperty("rss_baseline_kb", static_cast<int>(baseline));
  RecordProperty("rss_per_session_kb", static_cast<int>(per_session_kb));
  RecordProperty("rss_flood_peak_kb", static_cast<int>(peak));
  RecordProperty("rss_after_kb", static_cast<int>(after));
  RecordProperty("rss_after_second_flood_kb", static_cast<int>(after_floods[0]));
  RecordProperty("rss_after_third_flood_kb", static_cast<int>(after_again));
  RecordProperty("rss_after_churn_kb", static_cast<int>(after_churn));
  // Generous margins: the bound the limits promise, +25 %, and 1 GB whatever was measured.
  // Beside its 64 sessions a flood brings 16 participants to discover and 10,000 OPENs
  // through Cyclone's receive buffers (2 MB): a few MB that a hand's 7 MB once hid, and that
  // the hand's 0.3 MB no longer does.
  constexpr double kFloodBesidesSessionsKb = 8.0 * 1024.0;
  EXPECT_LT(static_cast<double>(peak), 1.25 * bound_kb + kFloodBesidesSessionsKb);
  EXPECT_LT(peak, 1024u * 1024u);
  // Once the sessions ended the server is back near its baseline (docs/security.md, Memory;
  // tests/bench/bench_server_memory.sh measures 9,000 sessions a round). A flood left +30 %
  // and 1,000 sessions one after another +70 % when the hands' pages stayed resident: here
  // within 25 % after the floods, and within 50 % after the churn, whose first run fills
  // caches a flood does not (Cyclone's pool of freed samples, SQLite's pages) but not in
  // proportion to the sessions.
  const double base_kb = static_cast<double>(baseline);
  EXPECT_LT(static_cast<double>(after), 1.25 * base_kb) << "the first flood's memory went back";
  EXPECT_LT(static_cast<double>(after_again), 1.25 * base_kb) << "three floods";
  EXPECT_LT(static_cast<double>(after_churn), 1.5 * base_kb) << "640 sessions one after another";
  // And it levels off: a further flood adds less than 1 MB.
  EXPECT_LT(static_cast<double>(after_again), static_cast<double>(after_floods[0]) + 1024.0)
      << "the third flood left more behind than the second: something grows per session";
}

/// The environment of a running process, NUL-separated entries as /proc shows them.
std::string environOf(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/environ", std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

TEST_F(RogueTest, TheServerRunsWithoutMallocThreadCachesUnlessTold) {
  // glibc's per-thread caches kept ~1 MB of a churn's blocks resident (malloc_tuning.h): the
  // server runs itself again with them off, same PID; an operator's own setting stands.
  const auto serve = [&](const std::string& name, const char* tunables) {
    std::vector<std::string> env;
    for (char** e = environ; *e != nullptr; ++e) {
      if (!std::string_view(*e).starts_with("GLIBC_TUNABLES=")) env.emplace_back(*e);
    }
    if (tunables) env.push_back(std::string("GLIBC_TUNABLES=") + tunables);
    Process server(cmd(TELEHAND_SERVER_BIN, {"--db", path(name + ".db"), "--seconds", "30"}),
                   path(name + ".log"), 0, env);
    const auto log = [&] { return server.output(); };
    EXPECT_EQ(awaitOccurrences(log, "serving on DDS domain", 1, 20s), 1u) << log();
    // glibc, parsing GLIBC_TUNABLES at start, ends each of its tunables with a NUL in
    // place: in /proc the value's further tunables follow as entries of their own.
    std::string seen;
    bool in_tunables = false;
    const std::string all = environOf(server.pid());
    for (std::size_t at = 0; at < all.size();) {
      const std::size_t end = std::min(all.find('\0', at), all.size());
      const std::string_view entry(all.data() + at, end - at);
      if (entry.starts_with("GLIBC_TUNABLES=")) {
        seen = entry.substr(15);
        in_tunables = true;
      } else if (in_tunables && entry.starts_with("glibc.")) {
        seen += ":" + std::string(entry);
      } else {
        in_tunables = false;
      }
      at = end + 1;
    }
    EXPECT_EQ(server.stop(10s), 0) << log();
    return seen;
  };
  EXPECT_EQ(serve("plain", nullptr), "glibc.malloc.tcache_count=0");
  EXPECT_EQ(serve("other", "glibc.malloc.arena_max=2"),
            "glibc.malloc.arena_max=2:glibc.malloc.tcache_count=0");
  EXPECT_EQ(serve("told", "glibc.malloc.arena_max=2:glibc.malloc.tcache_count=3"),
            "glibc.malloc.arena_max=2:glibc.malloc.tcache_count=3");
}

}  // namespace
}  // namespace telehand::test
