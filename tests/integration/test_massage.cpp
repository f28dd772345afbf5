// A massage session on loopback: the server, a client whose simulated clinician circles on
// the web of the case, and a watcher; the record holds every sample with each pad's depth and
// the web's force, the force stays at the paper's 10 ± 2 N, the device's under its 4 N, and
// the watcher draws the web. Processes in a partition of their own, stopped by PID.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>

#include "process.h"
#include "telehand/core/clock.h"
#include "telehand/server/store/sqlite_store.h"

namespace telehand::test {
namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;

class MassageTest : public ::testing::TestWithParam<const char*> {};

TEST_P(MassageTest, ATwentySecondMassageStaysInBandUnderTheDeviceLimitAndIsRecordedWhole) {
  const std::string web = GetParam();
  char tmpl[] = "/tmp/telehand-massage-XXXXXX";
  const fs::path dir = mkdtemp(tmpl);
  const std::string partition = "it-" + std::to_string(getpid()) + "-massage-" + web;
  auto cmd = [&](std::string bin, std::vector<std::string> args) {
    std::vector<std::string> v{std::move(bin)};
    v.insert(v.end(), args.begin(), args.end());
    for (const char* a : {"--dds-config", TELEHAND_LOOPBACK_XML, "--insecure", "--partition"})
      v.push_back(a);
    v.push_back(partition);
    return v;
  };
  const std::string db = (dir / "records.db").string();
  Process server(cmd(TELEHAND_SERVER_BIN, {"--db", db, "--seconds", "90"}),
                 (dir / "server.log").string());
  Process watcher(cmd(TELEHAND_WATCH_BIN, {"--plain", "--exit-on-close", "--wait", "20"}),
                  (dir / "watch.log").string());
  Process client(cmd(TELEHAND_CLIENT_BIN, {"--technique", "massage", "--case", web, "--seconds",
                                           "20", "-q", "--seed", "5"}),
                 (dir / "client.log").string());
  const auto rc = client.wait(60s);
  ASSERT_TRUE(rc) << client.output();
  EXPECT_EQ(*rc, 0) << client.output() << server.output();
  const std::string out = client.output();
  std::smatch m;
  ASSERT_TRUE(std::regex_search(out, m, std::regex(R"(session (\d+) open: massage)"))) << out;
  const uint64_t id = std::stoull(m[1]);
  EXPECT_TRUE(std::regex_search(out, std::regex(R"(record: \d+ samples recorded, 0 missing)")))
      << out;
  watcher.wait(30s);
  EXPECT_EQ(server.stop(), 0) << server.output();

  server::store::SqliteStore store(db, server::store::SqliteStore::Mode::kReadOnly);
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
  const std::string w = watcher.output();
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
  Process exported({TELEHAND_RECORDS_BIN, "--db", db, "export", std::to_string(id), "--output",
                    (dir / "m.csv").string()},
                   (dir / "export.log").string());
  const auto erc = exported.wait(60s);
  ASSERT_TRUE(erc && *erc == 0) << exported.output();
  std::ifstream csv(dir / "m.csv");
  std::string header;
  std::getline(csv, header);
  for (const char* col : {"thumb_depth_m", "index_depth_m", "thumb_tissuez_n", "index_tissuez_n"})
    EXPECT_NE(header.find(col), std::string::npos) << col << " in " << header;
  if (!HasFailure()) fs::remove_all(dir);
}

INSTANTIATE_TEST_SUITE_P(Webs, MassageTest, ::testing::Values("healthy", "hypertonic", "oedema"));

}  // namespace
}  // namespace telehand::test
