// telehand-web's WebSocket handling, against the real program (loopback DDS, a partition of
// its own, stopped by PID): malformed and oversized messages, unknown session ids, closed
// tabs, the browser limit, and that none of them leaves a thread or memory behind; a replay's
// hand, computed from the record, cut at its bound, or missing for want of a patient case.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <regex>
#include <thread>

#include "process.h"
#include "process_test.h"
#include "telehand/core/clock.h"
#include "telehand/core/joint_model.h"
#include "telehand/server/store/sqlite_store.h"
#include "ws_client.h"

namespace telehand::test {
namespace {

using namespace std::chrono_literals;

/// A number from /proc/PID/status ("Threads", "VmRSS" in kB).
uint64_t procStatus(pid_t pid, const std::string& key) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind(key + ":", 0) == 0) return std::stoull(line.substr(key.size() + 1));
  }
  return 0;
}

uint64_t statOf(const std::string& json, const std::string& key) {
  return matchNumber(json, "\"" + key + "\":(\\d+)");
}

/// A closed record of `seconds` of a 3 Hz mobilization of the index MCP on `case_name`, written
/// into the store as the server writes a session's samples.
uint64_t writeRecord(const std::string& db, const std::string& case_name, double seconds,
                     uint64_t first_seq = 0) {
  server::store::SqliteStore store(db);
  server::store::SessionInfo info;
  info.user = "student";
  info.case_name = case_name;
  info.mode = "mobilization";
  info.state = "active";
  info.started_ns = wallNs();
  const uint64_t id = store.createSession(info);
  const JointModel joint(healthyIndexMcp());
  const auto n = static_cast<uint64_t>(seconds * 1000.0) + 1;
  std::vector<Sample> batch;
  for (uint64_t i = 0; i < n; ++i) {
    const double t = static_cast<double>(i) * 1e-3;
    Sample d;
    d.session_id = id;
    d.seq = first_seq + i;
    d.source_time_ns = info.started_ns + static_cast<int64_t>(i) * 1'000'000;
    d.model_version = 1;
    const Vec3 angles(degToRad(20.0 + 8.0 * std::sin(2 * M_PI * 3.0 * t)), 0.0, 0.0);
    const PerFinger<Vec3> p = joint.gripFromAngles(angles, 0.008);
    for (int k = 0; k < 2; ++k) {
      const Quat q = joint.thimbleOrientation(k, angles);
      const double qv[4] = {q.w(), q.x(), q.y(), q.z()};
      for (int j = 0; j < 3; ++j) d.fingers[k].position_m[j] = p[k][j];
      for (int j = 0; j < 4; ++j) d.fingers[k].orientation_q[j] = qv[j];
    }
    d.fingers[1].normal_n = static_cast<float>((14.0 + 2.0 * std::sin(2 * M_PI * 3.0 * t)) * 0.25);
    for (int j = 0; j < 3; ++j) d.mcp_angles_rad[j] = angles[j];
    batch.push_back(d);
    if (batch.size() == 10'000 || i + 1 == n) {
      const std::vector<uint8_t> valid(batch.size(), 1);
      store.appendSamples(id, batch, valid);
      batch.clear();
    }
  }
  store.closeSession(id, wallNs(), first_seq + n, "closed");
  return id;
}

/// What a replay sends: the per-sample frame, its hand's chunks (frames in order), the end.
struct ReplayReceived {
  std::optional<std::string> replay;
  std::vector<nlohmann::json> frames;
  std::size_t chunks = 0;
  std::size_t bytes = 0;  ///< of the chunks
  std::optional<nlohmann::json> end;
};

class GatewayTest : public ProcessTest {
 protected:
  GatewayTest() : ProcessTest("web", TELEHAND_LOOPBACK_XML) {}
  void SetUp() override {
    ProcessTest::SetUp();
    useOwnDomain();  // ClosedTabsLeaveNothingBehind measures the gateway's memory
    db_ = path("records.db");
    { server::store::SqliteStore store(db_); }  // an empty store
    startWeb({});
  }
  /// Starts the gateway on the test's record, with `extra` options besides the fixture's.
  void startWeb(const std::vector<std::string>& extra) {
    if (web_) {
      EXPECT_EQ(web_->stop(), 0) << web_->output();
      web_.reset();
    }
    port_ = 0;
    std::vector<std::string> args = {"--db",          db_,   "--bind",          "127.0.0.1:0",
                                     "--max-clients", "8",   "--replay-hand-s", "20",
                                     "--log-level",   "warn"};
    args.insert(args.end(), extra.begin(), extra.end());
    web_.emplace(
        cmd(TELEHAND_WEB_BIN, args),
        path(++starts_ == 1 ? std::string("web.log") : "web-" + std::to_string(starts_) + ".log"));
    // Port 0: the system chooses; the gateway prints which.
    for (int i = 0; i < 200 && port_ == 0; ++i) {
      std::this_thread::sleep_for(50ms);
      port_ =
          static_cast<int>(matchNumber(web_->output(), R"(serving http://127\.0\.0\.1:(\d+)/)"));
    }
    ASSERT_GT(port_, 0) << web_->output();
    ASSERT_FALSE(httpGet(port_, "/api/stats").empty()) << web_->output();
  }
  void TearDown() override {
    if (web_) {
      EXPECT_EQ(web_->stop(), 0) << web_->output();
    }
    ProcessTest::TearDown();
  }
  std::string stats() { return httpGet(port_, "/api/stats"); }
  /// Waits (up to 60 s: a loaded machine delays the writer threads' exits; a browser dropped
  /// while its replays are read waits for them, and in a full suite at nice 19 20 s was once
  /// not enough) until the gateway holds no browser and no writer thread.
  bool drained() {
    for (int i = 0; i < 1200; ++i) {
      const std::string s = stats();
      if (statOf(s, "clients_open") == 0 && statOf(s, "writer_threads") == 0) return true;
      std::this_thread::sleep_for(50ms);
    }
    return false;
  }

  /// Asks `c` to replay `session` and takes what comes until the hand's end.
  static ReplayReceived replay(WsClient& c, uint64_t session) {
    ReplayReceived r;
    EXPECT_TRUE(c.send(R"({"op":"replay","session":)" + std::to_string(session) + "}"));
    r.replay = c.waitFor("\"type\":\"replay\"");
    while (!r.end) {
      const auto m = c.waitFor("\"type\":\"replay_hand", 60s);
      if (!m) break;
      auto j = nlohmann::json::parse(*m);
      if (j["type"] == "replay_hand_end") {
        r.end = std::move(j);
      } else {
        EXPECT_EQ(j["first"].get<std::size_t>(), r.frames.size());
        for (auto& f : j["frames"]) r.frames.push_back(std::move(f));
        ++r.chunks;
        r.bytes += m->size();
      }
    }
    return r;
  }

  std::string db_;
  int port_ = 0;
  int starts_ = 0;
  std::optional<Process> web_;
};

TEST_F(GatewayTest, MalformedMessagesAreNamedAndTheConnectionStays) {
  WsClient c(port_);
  ASSERT_TRUE(c.ok()) << c.error();
  ASSERT_TRUE(c.waitFor("\"type\":\"hello\""));
  const std::pair<std::string, std::string> cases[] = {
      {"not json", "not JSON: [json.exception.parse_error.101] parse error at line 1, column 2"},
      {"[1,2,3]", "not a JSON object but array"},
      {R"({"session":1})", R"(no \"op\" string)"},
      {R"({"op":"watch","session":"abc"})", R"(is not a session id: \"abc\")"},
      {R"({"op":"watch","session":-4})", "is not a session id: -4"},
      // A sign, a space or a number past 2^64 in a string is not a session id either (no
      // "-5" read as 2^64 - 5).
      {R"({"op":"watch","session":"-5"})", R"(is not a session id: \"-5\")"},
      {R"({"op":"watch","session":"+7"})", "is not a session id"},
      {R"({"op":"watch","session":" 7"})", "is not a session id"},
      {R"({"op":"watch","session":"18446744073709551616"})", "is not a session id"},
      {R"({"op":"watch"})", R"(needs a \"session\" id)"},
      {R"({"op":"mark","session":1})", R"(needs a \"text\" string)"},
      {R"({"op":"launch"})", "unknown op"},
  };
  for (const auto& [msg, why] : cases) {
    ASSERT_TRUE(c.send(msg));
    const auto e = c.waitFor("\"type\":\"error\"");
    ASSERT_TRUE(e) << msg;
    EXPECT_NE(e->find(why), std::string::npos) << msg << " -> " << *e;
  }
  ASSERT_TRUE(c.send("\x01\x02", MG_WEBSOCKET_OPCODE_BINARY));
  const auto bin = c.waitFor("\"type\":\"error\"");
  ASSERT_TRUE(bin);
  EXPECT_NE(bin->find("binary messages are not accepted"), std::string::npos) << *bin;
  // Still served.
  // The page's clock comes back exactly (a tab open for hours sends 10^7 ms and more).
  ASSERT_TRUE(c.send(R"({"op":"ping","t":12345678.901})"));
  const auto pong = c.waitFor("\"type\":\"pong\"");
  ASSERT_TRUE(pong);
  EXPECT_NE(pong->find("\"t\":12345678.901,"), std::string::npos) << *pong;
  EXPECT_EQ(statOf(stats(), "bad_messages"), std::size(cases) + 1);
}

TEST_F(GatewayTest, AnOversizedMessageIsRefusedAndTheConnectionClosed) {
  WsClient c(port_);
  ASSERT_TRUE(c.ok()) << c.error();
  ASSERT_TRUE(c.waitFor("\"type\":\"hello\""));
  ASSERT_TRUE(c.send(R"({"op":"mark","session":1,"text":")" + std::string(100'000, 'x') + "\"}"));
  const auto e = c.waitFor("\"type\":\"error\"");
  ASSERT_TRUE(e);
  EXPECT_NE(e->find("\"code\":\"oversized\""), std::string::npos) << *e;
  EXPECT_NE(e->find("the limit is 4096 bytes"), std::string::npos) << *e;
  EXPECT_TRUE(c.waitClosed(5s));
  c.close();
  EXPECT_TRUE(drained()) << stats();
  EXPECT_EQ(statOf(stats(), "marks"), 0u);
}

TEST_F(GatewayTest, UnknownSessionIdsAreNamed) {
  WsClient c(port_);
  ASSERT_TRUE(c.ok()) << c.error();
  ASSERT_TRUE(c.waitFor("\"type\":\"hello\""));
  for (const std::string op : {"watch", "mark", "replay", "takeover"}) {
    ASSERT_TRUE(c.send(R"({"op":")" + op + R"(","session":987654,"text":"hello","from":5})"));
    const auto e = c.waitFor("\"type\":\"error\"");
    ASSERT_TRUE(e) << op;
    EXPECT_NE(e->find("\"code\":\"unknown_session\""), std::string::npos) << op << ": " << *e;
    EXPECT_NE(e->find("987654"), std::string::npos) << op << ": " << *e;
  }
  EXPECT_EQ(statOf(stats(), "unknown_session"), 4u);
  EXPECT_EQ(statOf(stats(), "marks"), 0u);  // nothing was written to DDS
  EXPECT_EQ(statOf(stats(), "takeovers"), 0u);
  // A take-over's leading session must be an id.
  ASSERT_TRUE(c.send(R"({"op":"takeover","session":987654,"from":"mine"})"));
  const auto bad = c.waitFor("\"code\":\"malformed\"");
  ASSERT_TRUE(bad);
  EXPECT_NE(bad->find(R"(\"from\" is not a session id)"), std::string::npos) << *bad;
  // The empty store lists no records; watching nothing (0) is allowed.
  ASSERT_TRUE(c.send(R"({"op":"records"})"));
  const auto r = c.waitFor("\"type\":\"records\"");
  ASSERT_TRUE(r);
  EXPECT_NE(r->find("\"sessions\":[]"), std::string::npos) << *r;
  ASSERT_TRUE(c.send(R"({"op":"watch","session":0})"));
  EXPECT_TRUE(c.waitFor("\"type\":\"watching\""));
}

// A store of many sessions is listed by its newest only (a reply of every one would pass a
// browser's queue bound and drop it at every connection), saying how many there are.
TEST_F(GatewayTest, TheRecordsListTheNewestSessionsAndHowManyThereAre) {
  constexpr std::size_t kListed = 1000;  // web::kMaxRecordsListed (server/apps/web/replay.h)
  uint64_t last = 0;
  {
    server::store::SqliteStore store(db_);
    server::store::SessionInfo info;
    info.user = "student";
    info.case_name = "healthy";
    info.mode = "mobilization";
    info.state = "closed";
    for (std::size_t i = 0; i < kListed + 5; ++i) last = store.createSession(info);
  }
  WsClient c(port_);
  ASSERT_TRUE(c.ok()) << c.error();
  ASSERT_TRUE(c.send(R"({"op":"records"})"));
  const auto r = c.waitFor("\"type\":\"records\"", 20s);
  ASSERT_TRUE(r);
  const auto j = nlohmann::json::parse(*r);
  EXPECT_EQ(j["total"].get<std::size_t>(), kListed + 5);
  ASSERT_EQ(j["sessions"].size(), kListed);
  EXPECT_EQ(j["sessions"].back()["id"].get<uint64_t>(), last);
  EXPECT_EQ(j["sessions"].front()["id"].get<uint64_t>(), last - kListed + 1);
}

TEST_F(GatewayTest, ClosedTabsLeaveNothingBehind) {
  constexpr int kRounds = 20;
  // Tabs closed properly, tabs that vanish (no close frame), one mid-request: 5 a round.
  auto rounds = [&] {
    for (int round = 0; round < kRounds; ++round) {
      std::vector<std::unique_ptr<WsClient>> tabs;
      for (int i = 0; i < 3; ++i) {
        tabs.push_back(std::make_unique<WsClient>(port_));
        ASSERT_TRUE(tabs.back()->ok()) << tabs.back()->error();
      }
      tabs[0]->send(R"({"op":"records"})");
      tabs[1]->send(R"({"op":"watch","session":0})");
      const int raw1 = rawUpgrade(port_);
      const int raw2 = rawUpgrade(port_);
      ASSERT_GE(raw1, 0);
      ASSERT_GE(raw2, 0);
      ::close(raw1);
      ::close(raw2);
      tabs.clear();
    }
  };
  // Warm up: the first connections create what civetweb keeps for good, and the allocator
  // the arenas of the threads that served them (more of them the more the connections
  // overlap on a loaded machine).
  rounds();
  ASSERT_TRUE(drained()) << stats();
  const pid_t pid = web_->pid();
  const uint64_t threads0 = procStatus(pid, "Threads");
  const uint64_t rss0 = procStatus(pid, "VmRSS");
  rounds();
  ASSERT_TRUE(drained()) << stats();
  const std::string s = stats();
  EXPECT_EQ(statOf(s, "clients_total"), 2u * kRounds * 5u) << s;
  EXPECT_EQ(procStatus(pid, "Threads"), threads0) << s;
#if defined(__SANITIZE_ADDRESS__)
  // AddressSanitizer holds freed memory in quarantine: LeakSanitizer checks the gateway at
  // its exit instead (TearDown expects exit code 0).
  (void)rss0;
#else
  // 100 connections later the gateway holds no more memory than a little allocator slack.
  EXPECT_LT(procStatus(pid, "VmRSS"), rss0 + 4096) << "kB before " << rss0;
#endif
}

TEST_F(GatewayTest, BrowsersBeyondTheLimitAreRefused) {
  std::vector<std::unique_ptr<WsClient>> tabs;
  for (int i = 0; i < 8; ++i) {
    tabs.push_back(std::make_unique<WsClient>(port_));
    ASSERT_TRUE(tabs.back()->ok()) << i << ": " << tabs.back()->error();
    ASSERT_TRUE(tabs.back()->waitFor("\"type\":\"hello\""));
  }
  WsClient extra(port_);
  EXPECT_FALSE(extra.ok() && extra.waitFor("\"type\":\"hello\"", 1s));
  EXPECT_EQ(statOf(stats(), "clients_refused"), 1u);
  // The refusal says why, for the page to show.
  const std::string answer = upgradeWith(port_, "");
  EXPECT_NE(answer.find(" 503 "), std::string::npos) << answer;
  EXPECT_NE(answer.find("--max-clients"), std::string::npos) << answer;
  EXPECT_EQ(statOf(stats(), "clients_refused"), 2u);
  tabs.clear();
  EXPECT_TRUE(drained()) << stats();
}

// Browsers that open together: no more than --max-clients are served, the others are
// refused (before the upgrade, or at once after it with 1013 when they passed the count
// together before any was connected), and the statistics are still served meanwhile.
TEST_F(GatewayTest, ABurstOfBrowsersDoesNotPassTheLimit) {
  constexpr int kBurst = 16;  // the fixture's --max-clients 8, and civetweb's 8 more threads
  std::vector<std::unique_ptr<WsClient>> tabs(kBurst);
  std::vector<std::thread> openers;
  for (int i = 0; i < kBurst; ++i)
    openers.emplace_back(
        [&, i] { tabs[static_cast<std::size_t>(i)] = std::make_unique<WsClient>(port_); });
  for (auto& t : openers) t.join();
  int served = 0;
  for (auto& t : tabs)
    if (t->ok() && t->waitFor("\"type\":\"hello\"", 2s)) ++served;
  EXPECT_LE(served, 8);
  EXPECT_GE(served, 1);
  const std::string s = stats();
  EXPECT_LE(statOf(s, "clients_open"), 8u) << s;
  // Those closed at once after the upgrade were never served: not counted as open or served.
  EXPECT_EQ(statOf(s, "clients_total"), static_cast<uint64_t>(served)) << s;
  EXPECT_EQ(statOf(s, "clients_refused") + static_cast<uint64_t>(served),
            static_cast<uint64_t>(kBurst))
      << s;
  // The page is still served meanwhile.
  EXPECT_NE(httpGet(port_, "/api/stats").find("clients_open"), std::string::npos);
  tabs.clear();
  EXPECT_TRUE(drained()) << stats();
}

// A page of another site open in the supervisor's browser could open the console's
// WebSocket (browsers allow it) and mark or take over sessions with the console's DDS
// identity: a WebSocket whose Origin is not the console's own page is refused and says why.
// A program sends no Origin and is served, as is the console's own page.
TEST_F(GatewayTest, AnotherSitesPageCannotOpenTheWebSocket) {
  const std::string foreign = upgradeWith(port_, "Origin: http://evil.example\r\n");
  EXPECT_NE(foreign.find(" 403 "), std::string::npos) << foreign;
  EXPECT_NE(foreign.find("evil.example"), std::string::npos) << foreign;
  // Same host, another port: another site.
  const std::string other_port =
      upgradeWith(port_, "Origin: http://127.0.0.1:" + std::to_string(port_ + 1) + "\r\n");
  EXPECT_NE(other_port.find(" 403 "), std::string::npos) << other_port;
  std::string s = stats();
  EXPECT_EQ(statOf(s, "foreign_origin"), 2u) << s;
  EXPECT_EQ(statOf(s, "clients_total"), 0u) << s;

  int own = -1;
  const std::string answer =
      upgradeWith(port_, "Origin: http://127.0.0.1:" + std::to_string(port_) + "\r\n", &own);
  EXPECT_NE(answer.find(" 101 "), std::string::npos) << answer;
  int program = -1;
  upgradeWith(port_, "", &program);
  EXPECT_GE(program, 0);
  for (int i = 0; i < 100 && statOf(stats(), "clients_total") < 2; ++i)
    std::this_thread::sleep_for(50ms);
  s = stats();
  EXPECT_EQ(statOf(s, "clients_total"), 2u) << s;
  EXPECT_EQ(statOf(s, "foreign_origin"), 2u) << s;
  if (own >= 0) ::close(own);
  if (program >= 0) ::close(program);
  EXPECT_TRUE(drained()) << stats();
}

// DNS rebinding: a page of another site whose name was made to point at this machine has an
// Origin that matches its Host. The Host itself names no address, localhost or allowed name:
// refused, for the WebSocket and for every other request.
TEST_F(GatewayTest, APageOfANameMadeToPointHereIsRefused) {
  const std::string host = "rebind.example:" + std::to_string(port_);
  const std::string ws = upgradeWith(port_, "Origin: http://" + host + "\r\n", nullptr, 0, host);
  EXPECT_NE(ws.find(" 403 "), std::string::npos) << ws;
  EXPECT_NE(ws.find("--allow-host"), std::string::npos) << ws;
  EXPECT_EQ(httpGet(port_, "/api/stats", host).find("clients_open"), std::string::npos);
  EXPECT_EQ(httpGet(port_, "/index.html", "REBIND.example").find("<html"), std::string::npos);
  // By address (v4, v6) or as localhost, with or without a port: served.
  for (const std::string& ok : std::vector<std::string>{
           "127.0.0.1", "localhost:" + std::to_string(port_), "[::1]:80", "LocalHost"}) {
    EXPECT_NE(httpGet(port_, "/api/stats", ok).find("clients_open"), std::string::npos) << ok;
  }
  int own = -1;
  const std::string local = "localhost:" + std::to_string(port_);
  const std::string answer = upgradeWith(port_, "Origin: http://" + local + "\r\n", &own, 0, local);
  EXPECT_NE(answer.find(" 101 "), std::string::npos) << answer;
  if (own >= 0) ::close(own);
  const std::string s = stats();
  EXPECT_EQ(statOf(s, "foreign_host"), 3u) << s;
  EXPECT_TRUE(drained()) << stats();
}

// A browser the gateway dropped (here: a message over the limit) that neither reads nor
// closes is let go when it next sends: nothing more it sends is handled, and its place
// under --max-clients is free again.
TEST_F(GatewayTest, ADroppedBrowserThatSendsAgainIsLetGo) {
  int fd = -1;
  upgradeWith(port_, "", &fd);
  ASSERT_GE(fd, 0);
  ASSERT_TRUE(
      writeTextFrame(fd, R"({"op":"mark","session":1,"text":")" + std::string(5000, 'x') + "\"}"));
  std::this_thread::sleep_for(200ms);
  ASSERT_TRUE(writeTextFrame(fd, R"({"op":"ping"})"));
  const bool gone = drained();
  const std::string s = stats();
  ::close(fd);
  EXPECT_TRUE(gone) << s;
  EXPECT_EQ(statOf(s, "bad_messages"), 1u) << s;
  EXPECT_EQ(statOf(s, "messages_in"), 1u) << "the ping after the drop is not handled\n" << s;
}

// A browser that vanished without closing (a laptop shut, a cable pulled: no FIN) is pinged
// once silent for --ping-s and let go after 6 pings without an answer, its place under
// --max-clients free again; a browser that answers them, as every browser does by itself,
// stays however long it says nothing else.
TEST_F(GatewayTest, AVanishedBrowserIsLetGoAfterUnansweredPings) {
  constexpr double kPingS = 0.5;
  startWeb({"--ping-s", "0.5"});
  int vanished = -1;
  int alive = -1;
  upgradeWith(port_, "", &vanished);
  const std::string answer = upgradeWith(port_, "", &alive);
  ASSERT_GE(vanished, 0);
  ASSERT_GE(alive, 0);
  const std::size_t head = answer.find("\r\n\r\n");
  ASSERT_NE(head, std::string::npos) << answer;
  std::string pending = answer.substr(head + 4);
  WsClient program(port_);  // the tests' and the benchmark's client answers them too
  ASSERT_TRUE(program.ok()) << program.error();
  for (int i = 0; i < 100 && statOf(stats(), "clients_open") < 3; ++i)
    std::this_thread::sleep_for(50ms);
  ASSERT_EQ(statOf(stats(), "clients_open"), 3u) << stats();
  const auto t0 = std::chrono::steady_clock::now();
  const auto since = [&] {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  };
  int pings = 0;
  std::optional<double> let_go_s;
  while (since() < 30.0 && (!let_go_s || since() < *let_go_s + 3.0)) {
    const int n = readFrames(alive, pending, true, 100ms);
    ASSERT_GE(n, 0) << "the gateway closed the browser that answers its pings after " << since()
                    << " s\n"
                    << stats();
    pings += n;
    if (!let_go_s && statOf(stats(), "clients_open") == 2) let_go_s = since();
  }
  const std::string s = stats();
  const bool program_served = program.ok() && !program.waitClosed(0ms);
  program.close();
  ::close(vanished);
  ::close(alive);
  ASSERT_TRUE(let_go_s.has_value()) << "the vanished browser was not let go in 30 s\n" << s;
  std::cout << "pinged every " << kPingS << " s: the vanished browser let go after " << *let_go_s
            << " s; the one that answers pinged " << pings << " times and still served\n";
  // Not before it was silent for its 6 pings and one more wait.
  EXPECT_GE(*let_go_s, 6.0 * kPingS) << s;
  EXPECT_EQ(statOf(s, "clients_open"), 2u) << "the two that answer are still served\n" << s;
  EXPECT_TRUE(program_served);
  EXPECT_GE(pings, 6) << "the answering browser was pinged all along";
  EXPECT_TRUE(drained()) << stats();
}

/// The first match of `pattern`'s group 1 in `p`'s output within `timeout` (0: none).
uint64_t awaitNumber(const Process& p, const std::string& pattern,
                     std::chrono::milliseconds timeout) {
  const auto until = std::chrono::steady_clock::now() + timeout;
  uint64_t n = 0;
  while ((n = matchNumber(p.output(), pattern)) == 0 && std::chrono::steady_clock::now() < until)
    std::this_thread::sleep_for(100ms);
  return n;
}

// A supervisor at their own MF-2 takes over a lesson run's guided trials from the page
// (docs/lessons.md "Take-over"): the run's guide follows the supervisor's live movement
// (2 Hz) rather than the demonstration's (the simulated clinician's 3 Hz). The gateway
// refuses what it can tell is wrong; the record names who took over and every guide taken.
TEST_F(GatewayTest, ATakeOverFromThePageLeadsTheRunsGuidedTrials) {
  Process server(cmd(TELEHAND_SERVER_BIN, {"--db", db_, "--seconds", "150"}), path("server.log"));
  Process clinician(cmd(TELEHAND_CLIENT_BIN, {"--seconds", "6", "-q", "--user", "clinician"}),
                    path("clinician.log"));
  ASSERT_EQ(clinician.wait(40s), 0) << clinician.output();
  const uint64_t demo = matchNumber(clinician.output(), R"(session (\d+) open)");
  ASSERT_GT(demo, 0u);
  Process create(
      {TELEHAND_RECORDS_BIN, "--db", db_, "lesson", "create", "--demo", std::to_string(demo),
       "--guided", "2", "--attempts", "1", "--trial-seconds", "5", "--no-assessment", "--takeover"},
      path("create.log"));
  ASSERT_EQ(create.wait(30s), 0) << create.output();
  const uint64_t lesson = matchNumber(create.output(), R"(lesson (\d+) )");
  ASSERT_GT(lesson, 0u) << create.output();
  EXPECT_NE(create.output().find("a supervisor may take over"), std::string::npos);

  // --no-fault-stop: a stalled loop on a busy machine is a fault of its own, tested elsewhere.
  Process supervisor(cmd(TELEHAND_CLIENT_BIN, {"--seconds", "60", "-q", "--user", "supervisor",
                                               "--frequency", "2", "--no-fault-stop"}),
                     path("supervisor.log"));
  const uint64_t lead = awaitNumber(supervisor, R"(session (\d+) open)", 20s);
  ASSERT_GT(lead, 0u) << supervisor.output();
  Process student(cmd(TELEHAND_CLIENT_BIN,
                      {"--lesson", std::to_string(lesson), "--user", "student", "--no-fault-stop"}),
                  path("student.log"));
  const uint64_t run = awaitNumber(student, R"(session (\d+) open: lesson)", 20s);
  ASSERT_GT(run, 0u) << student.output();

  WsClient c(port_);
  ASSERT_TRUE(c.ok()) << c.error();
  // The session list marks the run as one a supervisor may take over.
  const auto listed = c.waitFor(R"({"id":)" + std::to_string(run) + R"(,"state":"active")", 10s);
  ASSERT_TRUE(listed);
  const auto entry = listed->find(R"({"id":)" + std::to_string(run));
  EXPECT_NE(listed->find(R"("takeover":true)", entry), std::string::npos) << *listed;
  ASSERT_TRUE(c.send(R"({"op":"watch","session":)" + std::to_string(run) + "}"));
  ASSERT_TRUE(c.waitFor(R"("type":"watching")"));
  // What the gateway refuses itself: the supervisor's session runs no lesson; a leading
  // session nobody opened.
  ASSERT_TRUE(c.send(R"({"op":"takeover","session":)" + std::to_string(lead) + R"(,"from":)" +
                     std::to_string(run) + "}"));
  auto e = c.waitFor(R"("type":"error")");
  ASSERT_TRUE(e);
  EXPECT_NE(e->find("not a lesson run that allows a take-over"), std::string::npos) << *e;
  ASSERT_TRUE(
      c.send(R"({"op":"takeover","session":)" + std::to_string(run) + R"(,"from":987654321})"));
  e = c.waitFor(R"("type":"error")");
  ASSERT_TRUE(e);
  EXPECT_NE(e->find("session 987654321 is not an open mobilization"), std::string::npos) << *e;
  EXPECT_EQ(statOf(stats(), "takeovers"), 0u);
  // The take-over: acknowledged, then the server's event in the watched run.
  ASSERT_TRUE(c.send(R"({"op":"takeover","session":)" + std::to_string(run) + R"(,"from":)" +
                     std::to_string(lead) + "}"));
  // The gateway's ack and the server's event may come in either order.
  const auto got = c.waitForAll(
      {R"("op":"takeover")", "leads the guided trials from session " + std::to_string(lead)}, 10s);
  EXPECT_FALSE(got[0].empty()) << "the take-over acknowledged";
  EXPECT_FALSE(got[1].empty()) << "the server's take-over event";
  EXPECT_EQ(statOf(stats(), "takeovers"), 1u);

  const auto rc = student.wait(120s);
  ASSERT_TRUE(rc.has_value()) << "the student's run did not finish\n" << student.output();
  EXPECT_EQ(*rc, 0) << student.output();
  EXPECT_EQ(supervisor.stop(), 0) << supervisor.output();
  EXPECT_EQ(server.stop(), 0) << server.output();

  server::store::SqliteStore store(db_, server::store::SqliteStore::Mode::kReadOnly);
  EXPECT_TRUE(store.lesson(lesson)->takeover);
  std::string events;
  for (const auto& ev : store.events(run)) events += ev.kind + ": " + ev.text + "\n";
  EXPECT_NE(events.find("leads the guided trials from session " + std::to_string(lead)),
            std::string::npos)
      << events;
  // Every guide taken is the supervisor's 2 Hz, not the demonstration's 3 Hz.
  const std::regex follows("the guide follows session " + std::to_string(lead) +
                           R"(: ([0-9.]+) Hz)");
  int guides = 0;
  for (std::sregex_iterator it(events.begin(), events.end(), follows), end; it != end; ++it) {
    EXPECT_NEAR(std::stod((*it)[1]), 2.0, 0.2) << events;
    ++guides;
  }
  EXPECT_GE(guides, 1) << events;
  const auto trials = store.trials(run);
  ASSERT_EQ(trials.size(), 3u);
  EXPECT_EQ(trials[0].phase, "guided");
  EXPECT_EQ(trials[1].phase, "guided");
  // Led at the supervisor's 2 Hz against its own 3 Hz, the student's finger stays in the
  // healthy joint's range (-45..90 deg, a few degrees into the end walls at most) all through
  // the guided trials (from its rest at -17 deg up into the swing): no runaway.
  double lo = 1e9, hi = -1e9;
  uint64_t late = 0;
  store.forEachSampleIn(run, trials[0].first_seq, trials[1].last_seq,
                        [&](const Sample& s, bool valid) {
                          if (!valid) return;
                          lo = std::min(lo, radToDeg(s.mcp_angles_rad[kFlexion]));
                          hi = std::max(hi, radToDeg(s.mcp_angles_rad[kFlexion]));
                          if (s.flags & sample_flags::kLoopOverrun) ++late;
                        });
  EXPECT_GT(lo, -50.0) << lo << ".." << hi << " deg, " << late << " late ticks";
  EXPECT_LT(hi, 95.0) << lo << ".." << hi << " deg, " << late << " late ticks";
}

TEST_F(GatewayTest, AReplayCarriesTheHandComputedFromTheRecord) {
  const uint64_t session = writeRecord(db_, "healthy", 4.0);
  WsClient c(port_);
  ASSERT_TRUE(c.ok()) << c.error();
  ASSERT_TRUE(c.waitFor("\"type\":\"hello\""));
  const ReplayReceived r = replay(c, session);
  ASSERT_TRUE(r.replay);
  EXPECT_NE(r.replay->find("\"points\":4001"), std::string::npos);
  ASSERT_TRUE(r.end) << web_->output();
  const auto& end = *r.end;
  EXPECT_TRUE(end["ok"].get<bool>()) << end.dump();
  EXPECT_FALSE(end["cut"].get<bool>()) << end.dump();
  EXPECT_EQ(end["case"], "healthy");
  EXPECT_DOUBLE_EQ(end["hz"].get<double>(), 50.0);
  EXPECT_NEAR(end["duration_s"].get<double>(), 4.0, 1e-6);
  // 50 frames a second of record, the first sample's to the last's, each shaped as a live
  // hand frame: all 25 joints, the spheres, the contacts, the carpus.
  ASSERT_EQ(r.frames.size(), 201u);
  EXPECT_EQ(end["frames"].get<std::size_t>(), r.frames.size());
  EXPECT_GE(r.chunks, 3u);
  double mcp_min = 1e9, mcp_max = -1e9;
  for (std::size_t i = 0; i < r.frames.size(); ++i) {
    const auto& f = r.frames[i];
    EXPECT_EQ(f["source"], "bullet");
    EXPECT_EQ(f["dev_seq"].get<uint64_t>(), std::min<uint64_t>(20 * i, 4000)) << i;
    ASSERT_EQ(f["joints"].size(), 25u);
    ASSERT_EQ(f["sphere"].size(), 2u);
    ASSERT_EQ(f["contact"].size(), 2u);
    ASSERT_EQ(f["bone0"].size(), 7u);
    mcp_min = std::min(mcp_min, f["mcp"][0].get<double>());
    mcp_max = std::max(mcp_max, f["mcp"][0].get<double>());
  }
  // The hand follows the 16 deg flexion of the record.
  EXPECT_GT(radToDeg(mcp_max - mcp_min), 10.0);
  EXPECT_FALSE(end["cached"].get<bool>());
  std::cout << "4 s of record's hand: " << r.frames.size() << " frames, " << r.bytes << " bytes in "
            << r.chunks << " chunks, computed in " << end["compute_s"] << " s\n";
  // Another tab replaying the same record gets the same hand at once, from the cache.
  WsClient other(port_);
  ASSERT_TRUE(other.waitFor("\"type\":\"hello\""));
  const ReplayReceived again = replay(other, session);
  ASSERT_TRUE(again.end);
  EXPECT_TRUE((*again.end)["cached"].get<bool>()) << again.end->dump();
  EXPECT_EQ(again.frames, r.frames);
  const std::string s = stats();
  EXPECT_EQ(statOf(s, "replay_hands"), 1u) << s;
  EXPECT_EQ(statOf(s, "replay_hand_cached"), 1u) << s;
  EXPECT_EQ(statOf(s, "replay_hand_frames"), 201u) << s;
  // The record grows (a session still being recorded): computed afresh.
  {
    server::store::SqliteStore store(db_);
    Sample extra;
    extra.session_id = session;
    extra.seq = 4001;
    extra.source_time_ns = 0;
    const uint8_t valid[] = {0};  // an invalid sample: stored, never stepped
    store.appendSamples(session, std::span<const Sample>(&extra, 1), valid);
  }
  const ReplayReceived grown = replay(other, session);
  ASSERT_TRUE(grown.end);
  EXPECT_FALSE((*grown.end)["cached"].get<bool>()) << grown.end->dump();
  EXPECT_EQ(grown.frames.size(), r.frames.size());
}

// Going back to live stops the replay's hand being computed: the replays' worker is free for the
// other browsers, and no more of that hand is queued ahead of the live frames.
TEST_F(GatewayTest, WatchingLiveAgainStopsTheReplaysHand) {
  const uint64_t session = writeRecord(db_, "stiff", 30.0);
  {
    WsClient c(port_);
    ASSERT_TRUE(c.ok()) << c.error();
    ASSERT_TRUE(c.waitFor("\"type\":\"hello\""));
    ASSERT_TRUE(c.send(R"({"op":"replay","session":)" + std::to_string(session) + "}"));
    ASSERT_TRUE(c.waitFor("\"type\":\"replay_hand\""));
    ASSERT_TRUE(c.send(R"({"op":"watch","session":424242})"));  // no such live session here
    ASSERT_TRUE(c.waitFor("\"type\":\"error\""));
    EXPECT_EQ(statOf(stats(), "replay_workers"), 0u) << stats();
    EXPECT_FALSE(c.waitFor("\"type\":\"replay_hand_end\"", 2s)) << "the hand went on";
  }
  EXPECT_TRUE(drained()) << stats();
}

// Sample numbers past 10^6 (17 minutes of a 1 kHz record) come in a replay exactly.
TEST_F(GatewayTest, AReplaysSampleNumbersAreExact) {
  const uint64_t session = writeRecord(db_, "healthy", 1.0, 1'234'567);
  WsClient c(port_);
  ASSERT_TRUE(c.ok()) << c.error();
  ASSERT_TRUE(c.waitFor("\"type\":\"hello\""));
  ASSERT_TRUE(c.send(R"({"op":"replay","session":)" + std::to_string(session) + "}"));
  const auto text = c.waitFor("\"type\":\"replay\"");
  ASSERT_TRUE(text);
  const auto j = nlohmann::json::parse(*text);
  ASSERT_TRUE(j.contains("seq")) << text->substr(0, 300);
  ASSERT_FALSE(j["seq"].empty());
  EXPECT_EQ(j["seq"].front().get<uint64_t>(), 1'234'567u);
  EXPECT_EQ(j["seq"].back().get<uint64_t>(), 1'234'567u + 1000u);
}

TEST_F(GatewayTest, ALongRecordsHandIsCutAtTheBoundWhileTheGatewayAnswers) {
  const uint64_t session = writeRecord(db_, "stiff", 30.0);  // the gateway simulates 20 s
  WsClient c(port_);
  ASSERT_TRUE(c.ok()) << c.error();
  ASSERT_TRUE(c.waitFor("\"type\":\"hello\""));
  ASSERT_TRUE(c.send(R"({"op":"replay","session":)" + std::to_string(session) + "}"));
  ASSERT_TRUE(c.waitFor("\"type\":\"replay\""));
  // While the hand is computed (18 s of record still to go), the gateway answers at once.
  ASSERT_TRUE(c.waitFor("\"type\":\"replay_hand\""));
  ASSERT_TRUE(c.send(R"({"op":"ping","t":7})"));
  const auto pong = c.waitFor("\"type\":\"pong\"", 60s);
  ASSERT_TRUE(pong);
  const auto end_text = c.waitFor("\"type\":\"replay_hand_end\"", 60s);
  ASSERT_TRUE(end_text) << "the pong came after the hand's end, or no end: " << web_->output();
  const auto end = nlohmann::json::parse(*end_text);
  EXPECT_TRUE(end["ok"].get<bool>()) << *end_text;
  EXPECT_TRUE(end["cut"].get<bool>()) << *end_text;
  EXPECT_NEAR(end["simulated_s"].get<double>(), 20.0, 1e-6) << *end_text;
  std::cout << "20 s of record's hand: " << end["frames"] << " frames computed in "
            << end["compute_s"] << " s\n";
  EXPECT_EQ(end["frames"].get<std::size_t>(), 1001u) << *end_text;
  EXPECT_NE(end["message"].get<std::string>().find("the first 20.0 s of the record's 30.0 s"),
            std::string::npos)
      << *end_text;
  // A tab closed while its hand is computed (another record: this one's is in the cache now)
  // stops it and leaves no thread behind.
  const uint64_t another = writeRecord(db_, "healthy", 30.0);
  {
    WsClient gone(port_);
    ASSERT_TRUE(gone.waitFor("\"type\":\"hello\""));
    ASSERT_TRUE(gone.send(R"({"op":"replay","session":)" + std::to_string(another) + "}"));
    ASSERT_TRUE(gone.waitFor("\"type\":\"replay_hand\""));
  }
  c.close();
  EXPECT_TRUE(drained()) << stats();
  EXPECT_EQ(statOf(stats(), "replay_workers"), 0u) << stats();
  EXPECT_EQ(statOf(stats(), "replay_hands"), 1u) << stats();
  EXPECT_LT(statOf(stats(), "replay_hand_frames"), 1001u + 1001u) << stats();
}

// A browser that asks for replays and does not read them: what waits for it is bounded in
// bytes, not only in messages (512 replays of a long record are hundreds of MB), and past
// the bound (--queue-bytes, here 1 MiB) it is dropped as too slow; its next message frees
// its place.
TEST_F(GatewayTest, ABrowserThatDoesNotReadItsReplaysIsDroppedAtTheByteBound) {
  const uint64_t session = writeRecord(db_, "healthy", 30.0);
  startWeb({"--queue-bytes", std::to_string(1 << 20)});
  // A browser that reads slowly: a receive buffer of 4 kB, and it never reads.
  int fd = -1;
  upgradeWith(port_, "", &fd, 4096);
  ASSERT_GE(fd, 0);
  const std::string ask = R"({"op":"replay","session":)" + std::to_string(session) + "}";
  uint64_t dropped = 0;
  for (int i = 0; i < 60 && dropped == 0; ++i) {
    if (!writeTextFrame(fd, ask)) break;
    std::this_thread::sleep_for(100ms);
    dropped = statOf(stats(), "dropped_slow");
  }
  const std::string s = stats();
  EXPECT_EQ(dropped, 1u) << s;
  EXPECT_LT(statOf(s, "replays"), 60u) << s;
  writeTextFrame(fd, R"({"op":"ping"})");
  EXPECT_TRUE(drained()) << stats();
  ::close(fd);
}

TEST_F(GatewayTest, AReplayOnAMissingCaseHasNoHandAndSaysWhy) {
  const uint64_t session = writeRecord(db_, "no-such-case", 1.0);
  WsClient c(port_);
  ASSERT_TRUE(c.ok()) << c.error();
  ASSERT_TRUE(c.waitFor("\"type\":\"hello\""));
  const ReplayReceived r = replay(c, session);
  ASSERT_TRUE(r.replay);  // the record itself replays
  EXPECT_NE(r.replay->find("\"points\":1001"), std::string::npos);
  ASSERT_TRUE(r.end);
  EXPECT_FALSE((*r.end)["ok"].get<bool>()) << r.end->dump();
  EXPECT_TRUE(r.frames.empty());
  const std::string message = (*r.end)["message"];
  EXPECT_NE(message.find("no hand for this replay"), std::string::npos) << message;
  EXPECT_NE(message.find("no-such-case"), std::string::npos) << message;
  // Still served.
  ASSERT_TRUE(c.send(R"({"op":"ping","t":1})"));
  EXPECT_TRUE(c.waitFor("\"type\":\"pong\""));
}

}  // namespace
}  // namespace telehand::test
