// The console's replay hand (server/apps/web/replay_hand.h): a session streamed live through the
// server's SessionManager, its HandStates kept by the sample they reflect; the gateway's replay
// of the same record must give the same hand (every dof, the spheres, the contacts) at every
// frame, on the case the session ran on; and its bounds: a record too long is cut and says so,
// a missing case or session is an error, not a crash.
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <limits>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>

#include "../support/grip_sample.h"
#include "frames.h"
#include "replay_hand.h"
#include "telehand/core/clock.h"
#include "telehand/protocol/wire.h"
#include "telehand/server/session/session_manager.h"
#include "telehand/server/sim/hand_model.h"
#include "telehand/server/store/sqlite_store.h"

namespace telehand::web {
namespace {

namespace fs = std::filesystem;
using server::store::SqliteStore;

const std::string kDeploy = TELEHAND_DEPLOY_DIR;

const server::sim::HandModel& hand() {
  static const server::sim::HandModel model =
      server::sim::HandModel::load(kDeploy + "/hand/hand24.urdf");
  return model;
}

class Outbox final : public server::session::Outbox {
 public:
  void publish(const telehand_msg_SessionStatus& s) override { statuses.push_back(s); }
  void publish(const telehand_msg_JointModel&) override {}
  void publish(const telehand_msg_HandState& h) override { hands.push_back(h); }
  void publish(const telehand_msg_SessionEvent&) override {}
  std::vector<telehand_msg_SessionStatus> statuses;
  std::vector<telehand_msg_HandState> hands;
};

/// A mobilization as the loop records it: the grip on the phalanx at the angles of the moment,
/// the push on the index pad.
struct Motion {
  double hz = 3.0, flex_deg = 20.0, flex_amp_deg = 8.0, abd_amp_deg = 0.0;
  Vec3 angles(double t) const {
    return {degToRad(flex_deg + flex_amp_deg * std::sin(2 * M_PI * hz * t - 0.3)),
            degToRad(abd_amp_deg * std::sin(2 * M_PI * 0.7 * t)), 0.0};
  }
  double force(double t) const { return 14.0 + 2.0 * std::sin(2 * M_PI * hz * t); }
};

class ReplayHandTest : public ::testing::Test {
 protected:
  void SetUp() override {
    static std::atomic<int> counter{0};
    dir_ = fs::temp_directory_path() /
           ("telehand-replay-hand-" + std::to_string(::getpid()) + "-" + std::to_string(counter++));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    config_.db_path = (dir_ / "telehand.db").string();
    config_.cases_dir = kDeploy + "/cases";
    config_.hand_state_hz = 100.0;
    store_ = std::make_unique<SqliteStore>(config_.db_path);
    manager_ = std::make_unique<server::session::SessionManager>(*store_, out_, config_, &hand());
  }
  void TearDown() override {
    manager_.reset();
    store_.reset();
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }

  telehand_msg_SessionCommand command(telehand_msg_CommandKind kind, uint64_t session = 0) {
    telehand_msg_SessionCommand c{};
    c.client_id = 7;
    c.request_seq = ++request_seq_;
    c.kind = kind;
    c.session_id = session;
    copyString(c.user, "student");
    return c;
  }

  /// A session on `case_name`, `ms` samples of `m` live and into the record, closed. The
  /// server's tick comes after every tenth sample, so its HandStates reflect samples 0, 10,
  /// 20, ...: `live` keeps them by that sample.
  /// `lost_every`: every so many samples one never reaches the server (neither live nor in
  /// the record: the hand steps across the gap).
  uint64_t liveSession(const std::string& case_name, const Motion& m, int ms,
                       std::map<uint64_t, telehand_msg_HandState>& live, int lost_every = 0) {
    auto open = command(telehand_msg_CMD_OPEN);
    open.mode = telehand_msg_MODE_MOBILIZATION;
    copyString(open.case_name, case_name);
    const std::size_t before = out_.statuses.size();
    manager_->onCommand(open, now_ns_);
    if (out_.statuses.size() == before) return 0;
    const uint64_t session = out_.statuses.back().session_id;
    const JointModel joint(healthyIndexMcp());
    std::vector<telehand_msg_DeviceState> chunk;
    const int64_t t0 = now_ns_;
    for (int i = 0; i < ms; ++i) {
      const double t = i * 1e-3;
      telehand_msg_DeviceState d{};
      d.session_id = session;
      d.seq = static_cast<uint64_t>(i);
      d.source_time_ns = kDeviceT0 + i * 1'000'000LL;
      d.model_version = 1;
      const Vec3 angles = m.angles(t);
      telehand::test::setGrip(d, joint, angles);
      d.fingers[1].normal_n = static_cast<float>(m.force(t) * 0.25);
      now_ns_ = t0 + i * 1'000'000LL;
      const bool lost = lost_every > 0 && i % lost_every == lost_every / 2;
      if (!lost) manager_->onDeviceState(d, now_ns_);
      if (i % 10 == 0) manager_->tick(now_ns_);
      if (!lost) chunk.push_back(d);
      if ((chunk.size() == 100 || i + 1 == ms) && !chunk.empty()) flush(session, chunk);
    }
    auto close = command(telehand_msg_CMD_CLOSE, session);
    close.samples_sent = static_cast<uint64_t>(ms);
    close.last_seq = static_cast<uint64_t>(ms - 1);
    manager_->onCommand(close, now_ns_);
    for (int i = 0; i < 30; ++i) manager_->tick(now_ns_ += 10'000'000);
    for (const auto& h : out_.hands) {
      if (h.session_id == session) live.emplace(h.device_seq, h);
    }
    return session;
  }
  void flush(uint64_t session, std::vector<telehand_msg_DeviceState>& chunk) {
    telehand_msg_RecordChunk c{};
    c.session_id = session;
    c.chunk_seq = chunk_seq_++;
    c.samples._buffer = chunk.data();
    c.samples._length = static_cast<uint32_t>(chunk.size());
    c.samples._maximum = c.samples._length;
    manager_->onChunk(c, now_ns_);
    chunk.clear();
  }

  /// The gateway's replay hand of `session`, every frame kept.
  ReplayHandResult replay(uint64_t session, const ReplayHandOptions& o,
                          std::vector<telehand_msg_HandState>& frames) {
    return replayHand(
        config_.db_path, session, hand(), o,
        [&](const telehand_msg_HandState& h) { frames.push_back(h); }, [](double) { return true; });
  }

  /// The largest difference between each replayed frame and the live HandState of the same
  /// sample: joint angles (rad), MCP angles (rad), sphere positions (m), contact forces (N).
  struct Worst {
    double joints = 0, mcp = 0, sphere = 0, contact = 0;
    std::size_t compared = 0;
  };
  static Worst compare(const std::vector<telehand_msg_HandState>& frames,
                       const std::map<uint64_t, telehand_msg_HandState>& live) {
    Worst w;
    for (const auto& f : frames) {
      const auto it = live.find(f.device_seq);
      if (it == live.end()) continue;
      const auto& h = it->second;
      ++w.compared;
      EXPECT_EQ(f.dof_count, h.dof_count);
      for (int j = 0; j < std::min(f.dof_count, h.dof_count); ++j)
        w.joints = std::max(w.joints, std::abs(f.joint_angles_rad[j] - h.joint_angles_rad[j]));
      for (int i = 0; i < 3; ++i) {
        w.mcp = std::max(w.mcp, std::abs(f.mcp_angles_rad[i] - h.mcp_angles_rad[i]));
        for (int k = 0; k < 2; ++k) {
          w.sphere = std::max(w.sphere, std::abs(f.sphere_m[k][i] - h.sphere_m[k][i]));
          w.contact =
              std::max(w.contact, std::abs(f.contact_force_n[k][i] - h.contact_force_n[k][i]));
        }
      }
    }
    return w;
  }

  static constexpr int64_t kDeviceT0 = 1'700'000'000'000'000'000;
  fs::path dir_;
  ServerConfig config_;
  Outbox out_;
  std::unique_ptr<SqliteStore> store_;
  std::unique_ptr<server::session::SessionManager> manager_;
  uint32_t request_seq_ = 0;
  uint64_t chunk_seq_ = 0;
  int64_t now_ns_ = 5'000'000'000;
};

TEST_F(ReplayHandTest, TheReplayedHandIsTheLiveHandOnEveryDof) {
  // Two cases the hand renders differently, and motions on one and two axes.
  const std::pair<std::string, Motion> runs[] = {
      {"healthy", Motion{}},
      {"stiff", Motion{2.0, 15.0, 10.0, 6.0}},
  };
  std::vector<std::vector<telehand_msg_HandState>> replays;
  for (const auto& [case_name, motion] : runs) {
    std::map<uint64_t, telehand_msg_HandState> live;
    const uint64_t session = liveSession(case_name, motion, 3000, live);
    ASSERT_NE(session, 0u) << case_name;
    ASSERT_GE(live.size(), 290u) << case_name;
    ASSERT_EQ(live.begin()->second.source, telehand_msg_HAND_SOURCE_BULLET);
    ASSERT_EQ(live.begin()->second.dof_count, 25);
    std::vector<telehand_msg_HandState> frames;
    ReplayHandOptions o;
    o.cases_dir = config_.cases_dir;
    o.hz = 50.0;
    const ReplayHandResult r = replay(session, o, frames);
    ASSERT_TRUE(r.ok) << r.error;
    EXPECT_FALSE(r.cut);
    EXPECT_EQ(r.case_name, case_name);
    EXPECT_EQ(r.samples, 3000u);
    EXPECT_NEAR(r.duration_s, 2.999, 1e-9);
    EXPECT_DOUBLE_EQ(r.hz, 50.0);
    // One frame every 20 ms of record, from the first sample to the last.
    ASSERT_EQ(frames.size(), 151u);
    ASSERT_EQ(r.frames, frames.size());
    for (std::size_t i = 0; i + 1 < frames.size(); ++i) {
      EXPECT_EQ(frames[i].device_seq, 20 * i) << i;
      EXPECT_EQ(frames[i].source_time_ns, frames[i].device_time_ns);
    }
    EXPECT_EQ(frames.back().device_seq, 2999u);
    const Worst w = compare(frames, live);
    // Every frame has its live twin (the last too: the server published sample 2999's state
    // as the session closed).
    EXPECT_EQ(w.compared, frames.size()) << case_name;
    std::cout << case_name << ": " << w.compared << " frames, worst |replay - live|: joints "
              << w.joints << " rad, mcp " << w.mcp << " rad, spheres " << w.sphere
              << " m, contacts " << w.contact << " N\n";
    EXPECT_LE(w.joints, 1e-6) << case_name;
    EXPECT_LE(w.mcp, 1e-6) << case_name;
    EXPECT_LE(w.sphere, 1e-9) << case_name;
    EXPECT_LE(w.contact, 1e-6) << case_name;
    // The hand moved: a replay that posed a still hand would compare with nothing live.
    double range = 0;
    for (const auto& f : frames)
      range = std::max(range, std::abs(f.joint_angles_rad[0] - frames[0].joint_angles_rad[0]) +
                                  std::abs(f.mcp_angles_rad[0] - frames[0].mcp_angles_rad[0]));
    EXPECT_GT(range, degToRad(5.0)) << case_name;
    // The frame the page receives is the live frame's shape: joints, spheres, contacts.
    const std::string json = handFrame(frames[10], frames[10].device_time_ns);
    for (const char* key : {"\"joints\":[", "\"sphere\":[[", "\"contact\":[[", "\"bone0\":[",
                            "\"mcp\":[", "\"dev_seq\":200,"}) {
      EXPECT_NE(json.find(key), std::string::npos) << key << " in " << json;
    }
    replays.push_back(std::move(frames));
  }
  // The case matters: the stiff joint's replay is not the healthy one's.
  double diff = 0;
  for (std::size_t i = 0; i < replays[0].size(); ++i)
    diff =
        std::max(diff, std::abs(replays[0][i].mcp_angles_rad[0] - replays[1][i].mcp_angles_rad[0]));
  EXPECT_GT(diff, degToRad(1.0));
}

// A massage's HandState carries the web to the page: each pad's depth and force and the 8x8
// surface, in order; a mobilization's frame has no web.
TEST(HandFrame, AMassageFrameCarriesTheWebAndAMobilizationsDoesNot) {
  telehand_msg_HandState h{};
  h.session_id = 7;
  h.source = telehand_msg_HAND_SOURCE_SHARED_JOINT_MODEL;
  const auto plain = nlohmann::json::parse(handFrame(h, 0));
  EXPECT_FALSE(plain.contains("web"));
  h.technique = telehand_msg_TECHNIQUE_MASSAGE;
  h.web_depth_m[0] = 0.0061;
  h.web_depth_m[1] = 0.0058;
  h.web_force_n[1][2] = -10.4;
  for (int r = 0; r < 8; ++r)
    for (int c = 0; c < 8; ++c) h.web_grid_m[r][c] = 0.001 * r + 0.0001 * c;
  h.web_grid_m[2][3] = std::numeric_limits<double>::quiet_NaN();  // sent as null, not NaN
  const auto j = nlohmann::json::parse(handFrame(h, 0));
  ASSERT_TRUE(j.contains("web"));
  EXPECT_DOUBLE_EQ(j["web"]["depth"][0].get<double>(), 0.0061);
  EXPECT_DOUBLE_EQ(j["web"]["depth"][1].get<double>(), 0.0058);
  EXPECT_DOUBLE_EQ(j["web"]["force"][1][2].get<double>(), -10.4);
  ASSERT_EQ(j["web"]["grid"].size(), 8u);
  ASSERT_EQ(j["web"]["grid"][7].size(), 8u);
  EXPECT_NEAR(j["web"]["grid"][7][5].get<double>(), 0.0075, 1e-9);
  EXPECT_TRUE(j["web"]["grid"][2][3].is_null());
}

TEST_F(ReplayHandTest, ALongRecordIsCutAtTheBoundsAndSaysSo) {
  std::map<uint64_t, telehand_msg_HandState> live;
  const uint64_t session = liveSession("healthy", Motion{}, 3000, live);
  ASSERT_NE(session, 0u);
  ReplayHandOptions o;
  o.cases_dir = config_.cases_dir;
  {  // at most 1 s of record
    o.max_s = 1.0;
    std::vector<telehand_msg_HandState> frames;
    const ReplayHandResult r = replay(session, o, frames);
    ASSERT_TRUE(r.ok) << r.error;
    EXPECT_TRUE(r.cut);
    EXPECT_NEAR(r.simulated_s, 1.0, 1e-9);
    EXPECT_EQ(frames.size(), 51u);
    EXPECT_EQ(frames.back().device_seq, 1000u);
    EXPECT_LE(compare(frames, live).joints, 1e-6);
  }
  {  // at most 40 frames: the rate drops (to 1 per 75 ms) and the hand stops at frame 40
    o.max_s = 600.0;
    o.max_frames = 40;
    std::vector<telehand_msg_HandState> frames;
    const ReplayHandResult r = replay(session, o, frames);
    ASSERT_TRUE(r.ok) << r.error;
    EXPECT_NEAR(r.hz, 1000.0 / 75.0, 1e-9);
    EXPECT_TRUE(r.cut);
    EXPECT_LE(frames.size(), 40u);
    EXPECT_GT(r.simulated_s, 2.5);
    // At that rate too, every frame whose sample the live hand was published at is the live
    // state (samples 0, 150, 300, ...).
    const Worst w = compare(frames, live);
    EXPECT_GE(w.compared, 19u);
    EXPECT_LE(w.joints, 1e-6);
    EXPECT_LE(w.mcp, 1e-6);
  }
  {  // the browser left: stopped between frames
    o.max_frames = 9000;
    int asked = 0;
    std::size_t got = 0;
    const ReplayHandResult r = replayHand(
        config_.db_path, session, hand(), o, [&](const telehand_msg_HandState&) { ++got; },
        [&](double) { return ++asked < 10; });
    EXPECT_TRUE(r.cancelled);
    EXPECT_EQ(got, 10u);
  }
}

TEST_F(ReplayHandTest, AMissingCaseOrSessionIsAnErrorNotACrash) {
  std::map<uint64_t, telehand_msg_HandState> live;
  const uint64_t session = liveSession("stiff", Motion{}, 200, live);
  ASSERT_NE(session, 0u);
  std::vector<telehand_msg_HandState> frames;
  ReplayHandOptions o;  // no cases directory: the built-in healthy case only, as the server
  ReplayHandResult r = replay(session, o, frames);
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.error.find("unknown patient case 'stiff'"), std::string::npos) << r.error;
  o.cases_dir = (dir_ / "no-cases").string();
  r = replay(session, o, frames);
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.error.find("stiff"), std::string::npos) << r.error;
  o.cases_dir = config_.cases_dir;
  r = replay(987654, o, frames);
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.error.find("no session 987654"), std::string::npos) << r.error;
  // A record whose sample numbers leave a gap of a hundred million for two samples (the server
  // writes none such): refused at once, not read page after empty page.
  {
    server::store::SessionInfo info;
    info.user = "student";
    info.case_name = "healthy";
    info.mode = "mobilization";
    info.state = "closed";
    const uint64_t odd = store_->createSession(info);
    Sample a, b;
    a.session_id = b.session_id = odd;
    b.seq = 100'000'000;
    b.source_time_ns = 100'000'000'000;
    const Sample both[] = {a, b};
    const uint8_t valid[] = {1, 1};
    store_->appendSamples(odd, both, valid);
    r = replay(odd, o, frames);
    EXPECT_FALSE(r.ok);
    EXPECT_NE(r.error.find("span 100000001 for 2 samples"), std::string::npos) << r.error;
  }
  r = replayHand((dir_ / "absent.db").string(), session, hand(), o,
                 [](const telehand_msg_HandState&) {}, [](double) { return true; });
  EXPECT_FALSE(r.ok);
  EXPECT_FALSE(r.error.empty());
  EXPECT_TRUE(frames.empty());
}

TEST_F(ReplayHandTest, SamplesLostOnTheWayAreSteppedAcrossAsLive) {
  // One sample in 37 never arrives, in bursts the hand catches up on by interpolation.
  std::map<uint64_t, telehand_msg_HandState> live;
  const uint64_t session = liveSession("lax", Motion{2.5, 25.0, 12.0, 4.0}, 4000, live, 37);
  ASSERT_NE(session, 0u);
  std::vector<telehand_msg_HandState> frames;
  ReplayHandOptions o;
  o.cases_dir = config_.cases_dir;
  o.hz = 25.0;
  const ReplayHandResult r = replay(session, o, frames);
  ASSERT_TRUE(r.ok) << r.error;
  EXPECT_EQ(r.samples, 4000u - 108u);  // samples 18, 55, ..., 3981 never arrived
  const Worst w = compare(frames, live);
  EXPECT_GE(w.compared, 90u);
  EXPECT_LE(w.joints, 1e-6);
  EXPECT_LE(w.mcp, 1e-6);
  EXPECT_LE(w.contact, 1e-6);
  std::cout << "lax, 1 in 37 lost: " << w.compared << " frames, worst joints " << w.joints
            << " rad\n";
}

}  // namespace
}  // namespace telehand::web
