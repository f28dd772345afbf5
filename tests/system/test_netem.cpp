// Real telehand-server and telehand-client processes in two network namespaces that this test
// creates, joined by telehand-linkem (a user-space delay line: the kernel has no netem) with
// the spain-australia profile, over the WAN Cyclone config. Namespaces and processes are
// removed by name and PID even when a check fails.
#include <gtest/gtest.h>
#include <signal.h>
#include <stdlib.h>
#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <regex>

#include "../integration/process.h"
#include "../integration/process_test.h"
#include "telehand/server/store/sqlite_store.h"

namespace telehand::test {
namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;

constexpr const char* kIp = "/usr/sbin/ip";
constexpr const char* kEnv = "/usr/bin/env";

int run(std::vector<std::string> argv) {
  Process p(std::move(argv), "/dev/null");
  return p.wait(20s).value_or(-1);
}

/// A network namespace that exists for the scope of this object.
class Netns {
 public:
  explicit Netns(std::string name) : name_(std::move(name)) {
    ok_ = run({kIp, "netns", "add", name_}) == 0;
  }
  ~Netns() {
    if (ok_) run({kIp, "netns", "del", name_});
  }
  Netns(const Netns&) = delete;
  Netns& operator=(const Netns&) = delete;
  bool ok() const { return ok_; }
  const std::string& name() const { return name_; }

 private:
  std::string name_;
  bool ok_ = false;
};

/// Namespaces left by an earlier run of this test that was killed (its PID is gone).
void removeStaleNamespaces() {
  std::error_code ec;
  for (const auto& e : fs::directory_iterator("/var/run/netns", ec)) {
    std::smatch m;
    const std::string n = e.path().filename().string();
    if (!std::regex_match(n, m, std::regex(R"(thsys(\d+)[ab])"))) continue;
    const pid_t pid = static_cast<pid_t>(std::stol(m[1]));
    if (kill(pid, 0) != 0 && errno == ESRCH) run({kIp, "netns", "del", n});
  }
}

class NetemTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (geteuid() != 0) GTEST_SKIP() << "needs root for network namespaces";
    struct stat st {};
    if (stat("/dev/net/tun", &st) != 0 || stat(kIp, &st) != 0)
      GTEST_SKIP() << "no /dev/net/tun or ip";
    removeStaleNamespaces();
    char tmpl[] = "/tmp/telehand-netem-XXXXXX";
    dir_ = mkdtemp(tmpl);
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    partition_ = std::string("netem-") + std::to_string(getpid()) + "-" + info->name();
  }
  void TearDown() override {
    if (!HasFailure() && !dir_.empty()) fs::remove_all(dir_);
  }
  std::string path(const std::string& n) const { return (fs::path(dir_) / n).string(); }

  /// argv running `bin` in namespace `ns` with the WAN config's addresses set.
  std::vector<std::string> inNs(const Netns& ns, const std::string& self, const std::string& peer,
                                std::string bin, std::vector<std::string> args) const {
    std::vector<std::string> v{kIp,
                               "netns",
                               "exec",
                               ns.name(),
                               kEnv,
                               "TELEHAND_DDS_ADDRESS=" + self,
                               "TELEHAND_DDS_PEER=" + peer,
                               std::move(bin)};
    v.insert(v.end(), args.begin(), args.end());
    // The namespaces are this test's own closed network.
    for (const std::string& a :
         {std::string("--dds-config"), std::string(TELEHAND_WAN_XML), std::string("--insecure"),
          std::string("--partition"), partition_}) {
      v.push_back(a);
    }
    return v;
  }

  /// Starts the delay line between the two namespaces and waits until it reports ready.
  std::unique_ptr<Process> linkem(const Netns& a, const Netns& b, const std::string& profile) {
    auto p = std::make_unique<Process>(
        std::vector<std::string>{TELEHAND_LINKEM_BIN, "--ns-a", a.name(), "--ns-b", b.name(),
                                 "--profile", profile, "--seconds", "120"},
        path("linkem.log"));
    for (int i = 0; i < 100 && p->output().find("linkem ready") == std::string::npos; ++i) {
      if (p->wait(50ms)) break;
    }
    return p;
  }

  std::string dir_;
  std::string partition_;
};

TEST_F(NetemTest, SpainAustraliaSessionRecordsEverySampleAcrossTheDelayLine) {
  const std::string tag = "thsys" + std::to_string(getpid());
  Netns srv_ns(tag + "a"), cli_ns(tag + "b");
  ASSERT_TRUE(srv_ns.ok() && cli_ns.ok()) << "cannot create network namespaces";
  auto line =
      linkem(srv_ns, cli_ns, std::string(TELEHAND_DEPLOY_DIR) + "/links/spain-australia.toml");
  ASSERT_NE(line->output().find("linkem ready"), std::string::npos) << line->output();

  const std::string db = path("records.db");
  Process server(inNs(srv_ns, "10.77.0.1", "10.77.0.2", TELEHAND_SERVER_BIN,
                      {"--db", db, "--seconds", "90", "--hand-deadband", "0.05"}),
                 path("server.log"));
  Process client(inNs(cli_ns, "10.77.0.2", "10.77.0.1", TELEHAND_CLIENT_BIN,
                      {"--seconds", "6", "-q", "--deadband", "0.05", "--connect-timeout", "20"}),
                 path("client.log"));
  const auto rc = client.wait(60s);
  ASSERT_TRUE(rc.has_value()) << "client did not finish\n" << client.output();
  EXPECT_EQ(*rc, 0) << client.output() << "\n" << server.output();
  EXPECT_EQ(server.stop(), 0) << server.output();
  line->stop();
  const std::string link_out = line->output();

  const std::string out = client.output();
  const uint64_t session = matchNumber(out, R"(session (\d+) open)");
  const uint64_t sent = matchNumber(out, R"((\d+) samples sent)");
  const uint64_t live = matchNumber(out, R"(\((\d+) of \d+ samples, deadband\))");
  ASSERT_GT(session, 0u) << out;
  ASSERT_GT(sent, 5000u) << out;
  EXPECT_GT(live, 0u) << out;
  EXPECT_LT(live, sent / 5) << "the deadband withholds most live samples\n" << out;

  // The delay line really delayed and lost packets in both directions.
  EXPECT_GT(matchNumber(link_out, R"(b->a: (\d+) packets)"), 500u) << link_out;
  EXPECT_GT(matchNumber(link_out, R"(a->b: \d+ packets, (\d+) lost)") +
                matchNumber(link_out, R"(b->a: \d+ packets, (\d+) lost)"),
            0u)
      << link_out;
  EXPECT_NE(link_out.find("delay mean 1"), std::string::npos) << link_out;  // 130-170 ms

  // The record is complete: every sequence number once, the live ones flagged.
  server::store::SqliteStore store(db, server::store::SqliteStore::Mode::kReadOnly);
  const auto info = store.session(session);
  ASSERT_TRUE(info.has_value());
  EXPECT_EQ(info->state, "closed");
  EXPECT_EQ(info->samples, sent);
  uint64_t expect = 0, gaps = 0, flagged_live = 0;
  store.forEachSample(session, [&](const Sample& s, bool valid) {
    gaps += s.seq != expect;
    expect = s.seq + 1;
    flagged_live += (s.flags & sample_flags::kSentLive) != 0;
    EXPECT_TRUE(valid);
  });
  EXPECT_EQ(gaps, 0u);
  EXPECT_EQ(expect, sent);
  EXPECT_EQ(flagged_live, live);
  bool rates = false;
  for (const auto& e : store.events(session))
    rates = rates || e.text.find("packets/s received live") != std::string::npos;
  EXPECT_TRUE(rates) << "the link's packet rates are in the record";
}

TEST_F(NetemTest, DirectModeRunsAcrossTheDelayLineAndTheGuardActs) {
  const std::string tag = "thsys" + std::to_string(getpid());
  Netns srv_ns(tag + "a"), cli_ns(tag + "b");
  ASSERT_TRUE(srv_ns.ok() && cli_ns.ok()) << "cannot create network namespaces";
  auto line =
      linkem(srv_ns, cli_ns, std::string(TELEHAND_DEPLOY_DIR) + "/links/spain-australia.toml");
  ASSERT_NE(line->output().find("linkem ready"), std::string::npos) << line->output();
  Process server(inNs(srv_ns, "10.77.0.1", "10.77.0.2", TELEHAND_SERVER_BIN,
                      {"--db", path("records.db"), "--seconds", "90", "--hand", "none"}),
                 path("server.log"));
  Process client(inNs(cli_ns, "10.77.0.2", "10.77.0.1", TELEHAND_CLIENT_BIN,
                      {"--seconds", "5", "-q", "--render", "direct", "--connect-timeout", "20"}),
                 path("client.log"));
  const auto rc = client.wait(60s);
  ASSERT_TRUE(rc.has_value()) << client.output();
  EXPECT_EQ(server.stop(), 0) << server.output();
  const std::string out = client.output();
  // The baseline renders forces computed a round trip (300 ms) ago: the passivity guard
  // acts, and where the rendering still diverges the fault detector ends the session and
  // says so (exit 4) instead of rendering on. Either way the server's forces were rendered:
  // how long before the fault is the detector's and the machine's (650-1,470 forces on an
  // idle machine when a runaway had to stay out of range for 20 ms on end; 50-80 since its
  // time out adds up, the rendering then 130° past the range), so a fault needs only some.
  ASSERT_TRUE(*rc == 0 || *rc == 4) << *rc << "\n" << out << "\n" << server.output();
  if (*rc == 4) {
    EXPECT_NE(out.find("rendering fault ("), std::string::npos) << out;
    EXPECT_GT(matchNumber(out, R"((\d+) server forces received)"), 0u) << out;
  } else {
    EXPECT_GT(matchNumber(out, R"((\d+) server forces received)"), 2000u) << out;
  }
  EXPECT_GT(matchNumber(out, R"(controller active (\d+) ticks)"), 0u) << out;
}

TEST_F(NetemTest, ALessonDemonstratedAndRunAcrossTheDelayLine) {
  // The expert demonstrates from the far end of the line (Australia, 300 ms RTT with loss);
  // the lesson is made on the server's record; a student at the far end runs it: guided
  // trial, attempt, every sample recorded and both trials scored.
  const std::string tag = "thsys" + std::to_string(getpid());
  Netns srv_ns(tag + "a"), cli_ns(tag + "b");
  ASSERT_TRUE(srv_ns.ok() && cli_ns.ok()) << "cannot create network namespaces";
  auto line =
      linkem(srv_ns, cli_ns, std::string(TELEHAND_DEPLOY_DIR) + "/links/spain-australia.toml");
  ASSERT_NE(line->output().find("linkem ready"), std::string::npos) << line->output();
  const std::string db = path("records.db");
  Process server(
      inNs(srv_ns, "10.77.0.1", "10.77.0.2", TELEHAND_SERVER_BIN, {"--db", db, "--seconds", "110"}),
      path("server.log"));
  Process expert(inNs(cli_ns, "10.77.0.2", "10.77.0.1", TELEHAND_CLIENT_BIN,
                      {"--seconds", "6", "-q", "--user", "expert", "--connect-timeout", "20"}),
                 path("expert.log"));
  ASSERT_EQ(expert.wait(60s), 0) << expert.output();
  const uint64_t demo = matchNumber(expert.output(), R"(session (\d+) open)");
  Process create(
      {TELEHAND_RECORDS_BIN, "--db", db, "lesson", "create", "--demo", std::to_string(demo),
       "--guided", "1", "--attempts", "1", "--trial-seconds", "4", "--no-assessment"},
      path("create.log"));
  ASSERT_EQ(create.wait(30s), 0) << create.output();
  const uint64_t lesson = matchNumber(create.output(), R"(lesson (\d+) )");
  Process student(inNs(cli_ns, "10.77.0.2", "10.77.0.1", TELEHAND_CLIENT_BIN,
                       {"--lesson", std::to_string(lesson), "--user", "student", "--watch-speed",
                        "2", "--connect-timeout", "20", "--no-fault-stop"}),
                  path("student.log"));
  const auto rc = student.wait(70s);
  ASSERT_TRUE(rc.has_value()) << student.output();
  EXPECT_EQ(*rc, 0) << student.output() << "\n" << server.output();
  EXPECT_EQ(server.stop(), 0) << server.output();
  line->stop();
  const uint64_t run = matchNumber(student.output(), R"(session (\d+) open: lesson)");
  const uint64_t sent = matchNumber(student.output(), R"((\d+) samples sent)");
  server::store::SqliteStore store(db, server::store::SqliteStore::Mode::kReadOnly);
  const auto info = store.session(run);
  ASSERT_TRUE(info.has_value()) << student.output();
  EXPECT_EQ(info->state, "closed");
  EXPECT_EQ(info->samples, sent);
  const auto trials = store.trials(run);
  ASSERT_EQ(trials.size(), 2u) << student.output();
  EXPECT_EQ(trials[0].phase, "guided");
  EXPECT_EQ(trials[1].phase, "attempt");
  for (const auto& t : trials) {
    EXPECT_NE(t.figures.find("missing=0;"), std::string::npos) << t.figures;
    EXPECT_GT(t.overall, 0.0) << t.figures;
  }
}

}  // namespace
}  // namespace telehand::test
