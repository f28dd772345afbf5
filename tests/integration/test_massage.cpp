// A massage session on loopback: the server, a client whose simulated clinician circles on
// the web of the case, and a watcher; the record holds every sample with each pad's depth and
// the web's force, the force stays at the paper's 10 ± 2 N, the device's under its 4 N, and
// the watcher draws the web. Processes in a partition of their own, stopped by PID.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <memory>
#include <optional>
#include <regex>
#include <sstream>

#include "process.h"
#include "telehand/core/clock.h"
#include "telehand/server/store/sqlite_store.h"

namespace telehand::test {
namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;

/// One web's massage: its own partition, server, watcher and client, started at once and
/// checked when the client ends.
class WebMassage {
 public:
  explicit WebMassage(std::string web) : web_(std::move(web)) {
    std::string tmpl = "/tmp/telehand-massage-XXXXXX";
    dir_ = mkdtemp(tmpl.data());
    const std::string partition = "it-" + std::to_string(getpid()) + "-massage-" + web_;
    auto cmd = [&](std::string bin, std::vector<std::string> args) {
      return insecureOnLoopback(std::move(bin), std::move(args), TELEHAND_LOOPBACK_XML, partition);
    };
    db_ = (dir_ / "records.db").string();
    server_.emplace(cmd(TELEHAND_SERVER_BIN, {"--db", db_, "--seconds", "90"}),
                    (dir_ / "server.log").string());
    watcher_.emplace(cmd(TELEHAND_WATCH_BIN, {"--plain", "--exit-on-close", "--wait", "20"}),
                     (dir_ / "watch.log").string());
    client_.emplace(cmd(TELEHAND_CLIENT_BIN, {"--technique", "massage", "--case", web_, "--seconds",
                                              "20", "-q", "--seed", "5"}),
                    (dir_ / "client.log").string());
  }

  void check();

 private:
  std::string web_;
  fs::path dir_;
  std::string db_;
  std::optional<Process> server_, watcher_, client_;
};

void WebMassage::check() {
  SCOPED_TRACE("web " + web_);
  const auto rc = client_->wait(60s);
  ASSERT_TRUE(rc) << client_->output();
  EXPECT_EQ(*rc, 0) << client_->output() << server_->output();
  const std::string out = client_->output();
  std::smatch m;
  ASSERT_TRUE(std::regex_search(out, m, std::regex(R"(session (\d+) open: massage)"))) << out;
  const uint64_t id = std::stoull(m[1]);
  EXPECT_TRUE(std::regex_search(out, std::regex(R"(record: \d+ samples recorded, 0 missing)")))
      << out;
  watcher_->wait(30s);
  EXPECT_EQ(server_->stop(), 0) << server_->output();

  server::store::SqliteStore store(db_, server::store::SqliteStore::Mode::kReadOnly);
  const auto info = store.session(id);
  ASSERT_TRUE(info);
  EXPECT_EQ(info->mode, "massage");
  EXPECT_EQ(info->state, "closed");
  EXPECT_GE(info->samples, 19'000u);
  // Every sample: the applied normal force (each thimble's eq. 2, reference scale) within
  // 10 ± 2 N on at least 90 % of them after the first second (the fingers come down onto the
  // web), the device's force within 4 N per finger, each pad pressing the web with the web's
  // force recorded beside it.
  uint64_t n = 0, in_band = 0, pressed = 0;
  double device_max = 0.0, depth_max = 0.0;
  int64_t t0 = 0;
  store.forEachSample(id, [&](const Sample& s, bool valid) {
    EXPECT_TRUE(valid);
    if (t0 == 0) t0 = s.source_time_ns;
    for (const auto& f : s.fingers) {
      device_max =
          std::max(device_max, Vec3(f.command_n[0], f.command_n[1], f.command_n[2]).norm());
      depth_max = std::max(depth_max, f.contact_depth_m);
    }
    if (s.source_time_ns - t0 < 1'000'000'000) return;
    ++n;
    bool band = true, both = true;
    for (const auto& f : s.fingers) {
      const double normal = f.normal_n / 0.25;
      band = band && normal >= 8.0 && normal <= 12.0;
      const double web_n =
          Vec3(f.tissue_force_n[0], f.tissue_force_n[1], f.tissue_force_n[2]).norm();
      both = both && f.contact_depth_m > 0.0 && web_n > 1.0;
    }
    in_band += band;
    pressed += both;
  });
  ASSERT_GT(n, 18'000u);
  EXPECT_GE(static_cast<double>(in_band) / static_cast<double>(n), 0.90);
  EXPECT_GE(static_cast<double>(pressed) / static_cast<double>(n), 0.99);
  EXPECT_LE(device_max, 4.0 + 1e-9);
  EXPECT_GT(depth_max, 0.001);
  EXPECT_LT(depth_max, 0.02);
  // The watcher saw the server's web: both pads in it.
  const std::string w = watcher_->output();
  std::smatch d;
  ASSERT_TRUE(std::regex_search(
      w, d, std::regex(R"(web_thumb_depth_mm=([0-9.]+) web_index_depth_mm=([0-9.]+))")))
      << w;
  bool deep = false;
  const std::regex thumb_depth(R"(web_thumb_depth_mm=([0-9.]+))");
  for (std::sregex_iterator it(w.begin(), w.end(), thumb_depth), end; it != end; ++it)
    deep = deep || std::stod((*it)[1]) > 1.0;
  EXPECT_TRUE(deep) << w;
  // The record's CSV carries the web per finger.
  Process exported({TELEHAND_RECORDS_BIN, "--db", db_, "export", std::to_string(id), "--output",
                    (dir_ / "m.csv").string()},
                   (dir_ / "export.log").string());
  const auto erc = exported.wait(60s);
  ASSERT_TRUE(erc && *erc == 0) << exported.output();
  std::ifstream csv(dir_ / "m.csv");
  std::string header;
  std::getline(csv, header);
  for (const char* col : {"thumb_depth_m", "index_depth_m", "thumb_tissuez_n", "index_tissuez_n"})
    EXPECT_NE(header.find(col), std::string::npos) << col << " in " << header;
  if (!::testing::Test::HasFailure()) fs::remove_all(dir_);
}

// Three webs massaged at once, each on a server of its own: the machine's load of three 1 kHz
// clients, their servers and watchers is on every one of them, and each still holds the band.
TEST(MassageTest,
     TwentySecondMassagesOfThreeWebsAtOnceStayInBandUnderTheDeviceLimitAndAreRecordedWhole) {
  std::vector<std::unique_ptr<WebMassage>> runs;
  for (const char* web : {"healthy", "hypertonic", "oedema"})
    runs.push_back(std::make_unique<WebMassage>(web));
  for (auto& run : runs) run->check();
}

// A massage lesson (docs/lessons.md "Massage lessons"): a clinician's massage on the scar
// becomes a lesson of a guided trial and two attempts, which refuses a take-over and a
// mobilization's client; the guided trial is scored like the others; in the attempts the
// clinician's own hand scores above a student who presses 1.5 N too hard and circles 0.3 Hz too
// fast; every trial is in the record with the massage's figures, and the report draws it.
TEST(MassageLessonTest, AMassageDemonstrationBecomesALessonThatScoresCircles) {
  char tmpl[] = "/tmp/telehand-massage-lesson-XXXXXX";
  const fs::path dir = mkdtemp(tmpl);
  const std::string partition = "it-" + std::to_string(getpid()) + "-massage-lesson";
  auto cmd = [&](std::string bin, std::vector<std::string> args) {
    return insecureOnLoopback(std::move(bin), std::move(args), TELEHAND_LOOPBACK_XML, partition);
  };
  const std::string db = (dir / "records.db").string();
  Process server(cmd(TELEHAND_SERVER_BIN, {"--db", db, "--seconds", "170"}),
                 (dir / "server.log").string());
  auto run = [&](const std::string& name, std::vector<std::string> args) {
    Process p(std::move(args), (dir / (name + ".log")).string());
    const auto rc = p.wait(90s);
    return std::make_pair(rc ? *rc : -1, p.output());
  };
  const auto [demo_rc, demo_out] =
      run("clinician",
          cmd(TELEHAND_CLIENT_BIN, {"--technique", "massage", "--case", "scar", "--seconds", "8",
                                    "-q", "--seed", "5", "--user", "clinician"}));
  ASSERT_EQ(demo_rc, 0) << demo_out << server.output();
  std::smatch m;
  ASSERT_TRUE(std::regex_search(demo_out, m, std::regex(R"(session (\d+) open: massage)")));
  const std::string demo = m[1];

  auto records = [&](const std::string& name, std::vector<std::string> args) {
    std::vector<std::string> v{TELEHAND_RECORDS_BIN, "--db", db};
    v.insert(v.end(), args.begin(), args.end());
    return run(name, v);
  };
  // What a massage lesson cannot have is refused, naming it.
  const auto [take_rc, take_out] =
      records("takeover", {"lesson", "create", "--demo", demo, "--takeover"});
  EXPECT_EQ(take_rc, 2);
  EXPECT_NE(take_out.find("--takeover"), std::string::npos) << take_out;
  const auto [create_rc, create_out] =
      records("create", {"lesson", "create", "--demo", demo, "--guided", "1", "--attempts", "2",
                         "--trial-seconds", "5", "--schedule", "terminal"});
  ASSERT_EQ(create_rc, 0) << create_out;
  ASSERT_TRUE(std::regex_search(
      create_out, m,
      std::regex(
          R"(lesson (\d+) .*massage\): press ([0-9.]+) N .*circles of ([0-9.]+) mm at ([-0-9.]+) Hz)")))
      << create_out;
  const std::string lesson = m[1];
  EXPECT_NEAR(std::stod(m[2]), 10.0, 1.0);  // the clinician's 10 N
  EXPECT_NEAR(std::stod(m[3]), 6.0, 0.5);   // 6 mm circles
  EXPECT_NEAR(std::stod(m[4]), 1.5, 0.05);  // at 1.5 Hz

  // A client that would mobilize is told how to run it.
  const auto [mob_rc, mob_out] =
      run("mobilizer", cmd(TELEHAND_CLIENT_BIN, {"--lesson", lesson, "--user", "x"}));
  EXPECT_EQ(mob_rc, 2);
  EXPECT_NE(mob_out.find("--technique massage --lesson " + lesson), std::string::npos) << mob_out;

  auto student = [&](const std::string& name, std::vector<std::string> skill) {
    std::vector<std::string> args{"--technique", "massage", "--lesson", lesson,          "--user",
                                  name,          "--seed",  "9",        "--watch-speed", "2"};
    args.insert(args.end(), skill.begin(), skill.end());
    return run(name, cmd(TELEHAND_CLIENT_BIN, args));
  };
  const auto [good_rc, good_out] = student("clinician-again", {});
  ASSERT_EQ(good_rc, 0) << good_out << server.output();
  const auto [weak_rc, weak_out] =
      student("student", {"--force-bias", "1.5", "--frequency-error", "0.3"});
  ASSERT_EQ(weak_rc, 0) << weak_out << server.output();
  for (const std::string* out : {&good_out, &weak_out}) {
    EXPECT_NE(out->find("1 guided trial(s) and 2 attempt(s)"), std::string::npos) << *out;
    EXPECT_NE(out->find("trial 1: guided, the device leads (100 % authority)"), std::string::npos)
        << *out;
    EXPECT_NE(out->find("feedback: trial 1 (guided 100 %): massage: press"), std::string::npos)
        << *out;
    EXPECT_NE(out->find("feedback: trial 3 (attempt): massage: press"), std::string::npos) << *out;
    EXPECT_NE(out->find("lesson: 3 of 3 trials run"), std::string::npos) << *out;
  }
  EXPECT_EQ(server.stop(), 0) << server.output();

  // The record: both runs' trials with the massage's figures; the better hand scores higher,
  // and the student's errors are the ones put in.
  server::store::SqliteStore store(db, server::store::SqliteStore::Mode::kReadOnly);
  auto runs = [&](const std::string& user) {
    for (const auto& s : store.listSessions()) {
      if (s.user == user && s.mode == "lesson") return store.trials(s.id);
    }
    return std::vector<server::store::TrialRecord>{};
  };
  const auto good = runs("clinician-again"), weak = runs("student");
  ASSERT_EQ(good.size(), 3u);
  ASSERT_EQ(weak.size(), 3u);
  EXPECT_EQ(good[0].phase, "guided");
  EXPECT_DOUBLE_EQ(good[0].authority, 1.0);
  for (std::size_t i = 0; i < 3; ++i) {
    EXPECT_NE(good[i].figures.find("radius_m="), std::string::npos) << good[i].figures;
    EXPECT_NE(good[i].figures.find("missing=0;"), std::string::npos) << good[i].figures;
    if (i == 0) continue;  // the attempts: the student's own hand
    EXPECT_EQ(good[i].phase, "attempt");
    EXPECT_GT(good[i].overall, 85.0) << good[i].figures;
    EXPECT_LT(weak[i].overall, good[i].overall - 15.0) << weak[i].figures;
    const std::regex err(R"(normal_error_n=([-0-9.e]+);.*frequency_error_hz=([-0-9.e]+);)");
    std::smatch e;
    ASSERT_TRUE(std::regex_search(weak[i].figures, e, err)) << weak[i].figures;
    EXPECT_NEAR(std::stod(e[1]), 1.5, 0.5);
    EXPECT_NEAR(std::stod(e[2]), 0.3, 0.05);
  }

  // The report of the student's run.
  const auto [report_rc, report_out] =
      records("report", {"report", "--lesson", lesson, "-o", dir.string()});
  ASSERT_EQ(report_rc, 0) << report_out;
  ASSERT_TRUE(
      std::regex_search(report_out, m, std::regex(R"(report: (\S+\.html) \(massage, 3 trials)")))
      << report_out;
  std::ifstream page(m[1].str());
  std::stringstream html;
  html << page.rdbuf();
  for (const char* id : {"id=\"press-0\"", "id=\"path-1\"", "id=\"radius\"", "id=\"learning\""})
    EXPECT_NE(html.str().find(id), std::string::npos) << id;
  if (!HasFailure()) fs::remove_all(dir);
}

}  // namespace
}  // namespace telehand::test
