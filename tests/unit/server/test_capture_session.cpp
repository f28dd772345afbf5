// Capture sessions in the session manager: live refits published only when felt and at a
// bounded rate, followers (cubic and k-nearest-neighbour) get each fit, files are kept.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>

#include "telehand/config/config.h"
#include "telehand/protocol/wire.h"
#include "telehand/server/estimate/synthetic_capture.h"
#include "telehand/server/session/session_manager.h"
#include "telehand/server/store/sqlite_store.h"

namespace telehand::server::session {
using store::SqliteStore;

namespace {

namespace fs = std::filesystem;

class Recorder final : public Outbox {
 public:
  void publish(const telehand_msg_SessionStatus& s) override { statuses.push_back(s); }
  void publish(const telehand_msg_JointModel& m) override { models.push_back({m, now}); }
  void publish(const telehand_msg_HandState&) override {}
  void publish(const telehand_msg_SessionEvent& e) override {
    events.emplace_back(e.kind, std::string(e.text));
  }
  void publish(const telehand_msg_KnnModel& k) override {
    knn.push_back({k.session_id, k.version, k.samples._length});
  }
  struct Model {
    telehand_msg_JointModel m;
    int64_t at_ns;
  };
  struct Knn {
    uint64_t session;
    uint32_t version;
    uint32_t samples;
  };
  std::vector<telehand_msg_SessionStatus> statuses;
  std::vector<Model> models;
  std::vector<Knn> knn;
  std::vector<std::pair<telehand_msg_EventKind, std::string>> events;
  int64_t now = 0;
};

telehand_msg_SessionCommand openCmd(uint64_t client, telehand_msg_SessionMode mode, uint64_t follow,
                                    telehand_msg_StiffnessKind kind) {
  telehand_msg_SessionCommand c{};
  c.client_id = client;
  // Each command a request of its own, as a client numbers them (a repeated OPEN is
  // answered with the session it made).
  static uint32_t next_request = 0;
  c.request_seq = ++next_request;
  c.kind = telehand_msg_CMD_OPEN;
  c.mode = mode;
  c.follow_session = follow;
  c.stiffness = kind;
  copyString(c.case_name, "healthy");
  copyString(c.user, "test");
  return c;
}

TEST(CaptureSession, LiveFitReachesFollowersOnlyWhenFeltAndAtABoundedRate) {
  const fs::path dir = fs::temp_directory_path() / ("telehand-capsess-" + std::to_string(getpid()));
  fs::create_directories(dir);
  SqliteStore store((dir / "r.db").string());
  Recorder out;
  ServerConfig cfg;
  cfg.cases_dir = TELEHAND_DEPLOY_DIR "/cases";
  SessionManager mgr(store, out, cfg);
  int64_t now = kNsPerS;
  mgr.onCommand(openCmd(1, telehand_msg_MODE_CAPTURE, 0, telehand_msg_STIFFNESS_CUBIC), now);
  mgr.onCommand(openCmd(2, telehand_msg_MODE_MOBILIZATION, 1, telehand_msg_STIFFNESS_KNN), now);
  mgr.onCommand(openCmd(3, telehand_msg_MODE_MOBILIZATION, 1, telehand_msg_STIFFNESS_CUBIC), now);
  mgr.onCommand(openCmd(4, telehand_msg_MODE_MOBILIZATION, 99, telehand_msg_STIFFNESS_CUBIC), now);
  ASSERT_EQ(mgr.activeSessions(), 3u);
  bool refused = false;
  for (const auto& [kind, text] : out.events)
    refused |= text.find("cannot follow session 99") != std::string::npos;
  EXPECT_TRUE(refused);

  telehand_msg_SessionFile file{};
  file.session_id = 1;
  copyString(file.name, "device/mf2.toml");
  file.content = const_cast<char*>("[device]\nname = \"x\"\n");
  mgr.onFile(file, now);
  ASSERT_EQ(store.files(1).size(), 1u);

  // The stiff case's finger, captured at 1 kHz, arriving as the client's 100-sample chunks.
  estimate::SyntheticCaptureOptions o;
  o.truth = loadPatientCase(TELEHAND_DEPLOY_DIR "/cases/stiff.toml").model;
  o.seconds_per_axis = 6.0;
  const auto cap = estimate::synthesizeCapture(o);
  std::vector<telehand_msg_DeviceState> chunk;
  uint64_t chunk_seq = 0;
  for (std::size_t i = 0; i < cap.samples.size(); i += 100) {
    chunk.clear();
    for (std::size_t j = i; j < std::min(i + 100, cap.samples.size()); ++j)
      chunk.push_back(toWire(cap.samples[j]));
    for (auto& s : chunk) s.session_id = 1;
    telehand_msg_RecordChunk c{};
    c.session_id = 1;
    c.chunk_seq = chunk_seq++;
    c.samples._buffer = chunk.data();
    c.samples._length = static_cast<uint32_t>(chunk.size());
    c.samples._maximum = c.samples._length;
    now += 100 * kNsPerMs;
    out.now = now;
    mgr.onChunk(c, now);
    mgr.tick(now);
  }
  auto versions = [&](uint64_t session) {
    std::vector<Recorder::Model> v;
    for (const auto& m : out.models) {
      if (m.m.session_id == session) v.push_back(m);
    }
    return v;
  };
  const auto capture = versions(1), knn_follower = versions(2), cubic_follower = versions(3);
  ASSERT_GE(capture.size(), 4u) << "v1 and several live fits";
  for (std::size_t i = 1; i < capture.size(); ++i) {
    EXPECT_EQ(capture[i].m.version, capture[i - 1].m.version + 1);
    if (i > 1) {
      EXPECT_GE(capture[i].at_ns - capture[i - 1].at_ns, 500 * kNsPerMs) << "rate limit";
    }
  }
  EXPECT_GT(mgr.stats().live_models, 2u);
  EXPECT_LE(mgr.stats().max_refit_latency_ns, 700 * kNsPerMs);
  // Every refit after the capture settled was one nobody would feel: not published.
  EXPECT_LT(capture.size() - 1, static_cast<std::size_t>(cap.samples.size() / 500));

  // Followers get each live fit with versions of their own; the kNN one with its samples.
  EXPECT_EQ(cubic_follower.size(), capture.size());
  EXPECT_EQ(cubic_follower.back().m.kind, telehand_msg_STIFFNESS_CUBIC);
  EXPECT_EQ(knn_follower.size(), capture.size());
  EXPECT_EQ(knn_follower.back().m.kind, telehand_msg_STIFFNESS_KNN);
  ASSERT_FALSE(out.knn.empty());
  EXPECT_EQ(out.knn.back().session, 2u);
  EXPECT_EQ(out.knn.back().version, knn_follower.back().m.version);
  EXPECT_GT(out.knn.back().samples, 100u);

  // The last fit is the stiff joint over the captured flexion range.
  std::string why;
  const auto last = fromWire(capture.back().m, &why);
  ASSERT_TRUE(last.has_value()) << why;
  const JointModel fitted(*last), truth(o.truth);
  for (double d = 25.0; d <= 60.0; d += 1.0) {
    EXPECT_NEAR(fitted.holdingForceN(kFlexion, degToRad(d)),
                truth.holdingForceN(kFlexion, degToRad(d)), 0.5)
        << d;
  }
  mgr.closeAll(now);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace telehand::server::session
