// The session manager on the authoritative hand: patient cases at open, exploration phases
// recorded from the Bullet hand driven by scripted grips, recovery republishing the joint.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "../../support/grip_sample.h"
#include "telehand/core/clock.h"
#include "telehand/core/error.h"
#include "telehand/protocol/wire.h"
#include "telehand/server/session/recorder.h"
#include "telehand/server/session/serve_watch.h"
#include "telehand/server/session/session_manager.h"
#include "telehand/server/sim/hand_model.h"
#include "telehand/server/store/sqlite_store.h"

namespace telehand::server::session {
using store::SqliteStore;

namespace {

namespace fs = std::filesystem;
using ::testing::AllOf;
using ::testing::HasSubstr;

const std::string kDeploy = TELEHAND_DEPLOY_DIR;

/// Everything the manager publishes, in order per kind.
class RecordingOutbox : public Outbox {
 public:
  void publish(const telehand_msg_SessionStatus& s) override { statuses.push_back(s); }
  void publish(const telehand_msg_JointModel& m) override { models.push_back(m); }
  void publish(const telehand_msg_HandState& h) override { hands.push_back(h); }
  void publish(const telehand_msg_SessionEvent& e) override { events.push_back(e); }
  void retire(uint64_t session_id) override { retired.push_back(session_id); }
  void idle() override { ++idles; }
  void settle() override { ++settles; }

  std::vector<const telehand_msg_SessionEvent*> eventsOf(telehand_msg_EventKind kind) const {
    std::vector<const telehand_msg_SessionEvent*> out;
    for (const auto& e : events) {
      if (e.kind == kind) out.push_back(&e);
    }
    return out;
  }

  std::vector<telehand_msg_SessionStatus> statuses;
  std::vector<telehand_msg_JointModel> models;
  std::vector<telehand_msg_HandState> hands;
  std::vector<telehand_msg_SessionEvent> events;
  std::vector<uint64_t> retired;
  int idles = 0, settles = 0;
};

/// The 24-DoF hand, loaded once for the whole program.
const sim::HandModel& hand() {
  static const sim::HandModel model = sim::HandModel::load(kDeploy + "/hand/hand24.urdf");
  return model;
}

std::string format(const char* fmt, double a, double b = 0.0) {
  char buf[128];
  std::snprintf(buf, sizeof buf, fmt, a, b);
  return buf;
}

telehand_msg_SessionCommand command(telehand_msg_CommandKind kind, uint64_t session_id = 0) {
  telehand_msg_SessionCommand c{};
  c.client_id = 7;
  // Each command a request of its own, as a client numbers them (a repeated OPEN is
  // answered with the session it made).
  static uint32_t next_request = 0;
  c.request_seq = ++next_request;
  c.kind = kind;
  c.session_id = session_id;
  return c;
}

/// A fresh record database per test, removed afterwards.
class SessionManagerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    static std::atomic<int> counter{0};
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ =
        fs::temp_directory_path() / ("telehand-manager-" + std::string(info->name()) + "-" +
                                     std::to_string(::getpid()) + "-" + std::to_string(counter++));
    fs::remove_all(dir_);
    ASSERT_TRUE(fs::create_directories(dir_));
    config_.db_path = (dir_ / "telehand.db").string();
    config_.cases_dir = kDeploy + "/cases";
    config_.hand_state_hz = 100.0;
    store_ = std::make_unique<SqliteStore>(config_.db_path);
    manager_ = std::make_unique<SessionManager>(*store_, out_, config_, &hand());
  }
  void TearDown() override {
    manager_.reset();
    store_.reset();
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }

  /// Opens a session and returns its id (0 if none was opened).
  uint64_t open(const std::string& case_name,
                telehand_msg_SessionMode mode = telehand_msg_MODE_MOBILIZATION) {
    auto c = command(telehand_msg_CMD_OPEN);
    c.mode = mode;
    copyString(c.case_name, case_name);
    copyString(c.user, "student");
    const std::size_t before = out_.statuses.size();
    manager_->onCommand(c, now_ns_, from_);
    if (out_.statuses.size() == before) return 0;
    session_ = out_.statuses.back().session_id;
    const auto params = fromWire(out_.models.back(), nullptr);
    EXPECT_TRUE(params.has_value());
    if (params) grip_model_ = std::make_unique<JointModel>(*params);
    angles_ = Vec3::Zero();
    return session_;
  }

  /// One live sample with the thimbles pinching the phalanx at `angles`, then 1 ms passes
  /// (the hand state is due every 10 ms).
  void sample(const Vec3& angles) {
    telehand_msg_DeviceState d{};
    d.session_id = session_;
    d.seq = seq_++;
    d.source_time_ns = now_ns_;
    d.model_version = 1;
    d.flags = flags_;
    telehand::test::setGrip(d, *grip_model_, angles);
    manager_->onDeviceState(d, now_ns_, from_);
    now_ns_ += 1'000'000;
    if (now_ns_ % 10'000'000 == 0) manager_->tick(now_ns_);
    angles_ = angles;
    afterSample(angles);
  }
  /// What a client does with each sample it sent (nothing by default).
  virtual void afterSample(const Vec3& angles) { (void)angles; }

  /// Move the grip from where it is to `target` at `speed_deg_s` along a straight line.
  void moveTo(const Vec3& target, double speed_deg_s = 30.0) {
    const Vec3 from = angles_;
    const double span_deg = radToDeg((target - from).cwiseAbs().maxCoeff());
    const int steps = std::max(1, static_cast<int>(std::ceil(span_deg / speed_deg_s * 1000.0)));
    for (int i = 1; i <= steps; ++i)
      sample(from + (target - from) * (static_cast<double>(i) / steps));
  }
  void hold(int ms) {
    const Vec3 at = angles_;
    for (int i = 0; i < ms; ++i) sample(at);
  }
  void moveToDeg(double flexion, double abduction = 0.0, double axial = 0.0) {
    Vec3 a;
    a[kFlexion] = degToRad(flexion);
    a[kAbduction] = degToRad(abduction);
    a[kAxial] = degToRad(axial);
    moveTo(a);
    hold(300);
  }

  static telehand_msg_SessionCommand commandFor(telehand_msg_CommandKind kind, uint64_t id) {
    return command(kind, id);
  }

  void mark(const std::string& text) {
    auto c = command(telehand_msg_CMD_MARK, session_);
    copyString(c.text, text);
    manager_->onCommand(c, now_ns_, from_);
  }
  void close() {
    auto c = command(telehand_msg_CMD_CLOSE, session_);
    c.samples_sent = 0;  // nothing on the record stream: the session may close at once
    manager_->onCommand(c, now_ns_, from_);
    now_ns_ += 10'000'000;
    manager_->tick(now_ns_);
  }

  static const SessionStore::Reach* reach(const std::vector<SessionStore::Reach>& rs,
                                          const std::string& phase, const std::string& dir) {
    for (const auto& r : rs) {
      if (r.phase == phase && r.direction == dir) return &r;
    }
    return nullptr;
  }

  /// Sample i of a 3 Hz pinch (MCP flexion 30 +/- 15 deg, `abduction_deg` held) as the
  /// next live sample of the session at now_ns_.
  telehand_msg_DeviceState pinchSample(int i, double abduction_deg = 2.0) {
    const double t = i * 1e-3;
    const Vec3 a(degToRad(30.0 + 15.0 * std::sin(2 * kPi * 3.0 * t)), degToRad(abduction_deg), 0.0);
    telehand_msg_DeviceState d{};
    d.session_id = session_;
    d.seq = seq_++;
    d.source_time_ns = now_ns_;
    d.model_version = 1;
    telehand::test::setGrip(d, *grip_model_, a);
    return d;
  }

  fs::path dir_;
  ServerConfig config_;
  RecordingOutbox out_;
  std::unique_ptr<SqliteStore> store_;
  std::unique_ptr<SessionManager> manager_;
  /// Who open(), sample(), mark() and close() speak as (default: not known).
  Origin from_;
  uint64_t session_ = 0;
  uint64_t seq_ = 1;
  uint32_t flags_ = 0;  // the next samples' flags
  int64_t now_ns_ = 1'000'000'000;
  std::unique_ptr<JointModel> grip_model_;
  Vec3 angles_ = Vec3::Zero();
};

// A client asks again, with the same request, until it hears an answer (a server of a pool
// may not have matched its first OPEN): a repeat gets the session the request made, announced
// again, and never a second one; a new request makes a new session.
TEST_F(SessionManagerTest, ARepeatedOpenGetsTheSessionItMadeAndNoOther) {
  auto c = command(telehand_msg_CMD_OPEN);
  copyString(c.case_name, "healthy");
  copyString(c.user, "student");
  manager_->onCommand(c, now_ns_, from_);
  ASSERT_EQ(manager_->activeSessions(), 1u);
  const uint64_t first = out_.statuses.back().session_id;
  const std::size_t statuses = out_.statuses.size();
  manager_->onCommand(c, now_ns_, from_);
  manager_->onCommand(c, now_ns_, from_);
  EXPECT_EQ(manager_->activeSessions(), 1u);
  EXPECT_EQ(store_->listSessions().size(), 1u);
  ASSERT_EQ(out_.statuses.size(), statuses + 2);
  EXPECT_EQ(out_.statuses.back().session_id, first);
  EXPECT_EQ(out_.statuses.back().state, telehand_msg_SESSION_ACTIVE);
  EXPECT_EQ(out_.statuses.back().request_seq, c.request_seq);
  // The same request number from another participant is another request.
  const Origin other{13, "0000cccc", ""};
  manager_->onCommand(c, now_ns_, other);
  EXPECT_EQ(manager_->activeSessions(), 2u);
  auto again = command(telehand_msg_CMD_OPEN);
  copyString(again.case_name, "healthy");
  copyString(again.user, "student");
  manager_->onCommand(again, now_ns_, from_);
  EXPECT_EQ(manager_->activeSessions(), 3u);
}

TEST_F(SessionManagerTest, OpeningACasePublishesItsJointModel) {
  const uint64_t id = open("stiff");
  ASSERT_NE(id, 0u);
  EXPECT_EQ(manager_->activeSessions(), 1u);
  ASSERT_EQ(out_.statuses.size(), 1u);
  EXPECT_EQ(out_.statuses[0].state, telehand_msg_SESSION_ACTIVE);
  EXPECT_STREQ(out_.statuses[0].case_name, "stiff");
  ASSERT_EQ(out_.models.size(), 1u);
  EXPECT_EQ(out_.models[0].session_id, id);
  std::string why;
  const auto got = fromWire(out_.models[0], &why);
  ASSERT_TRUE(got.has_value()) << why;
  JointModelParams want = loadPatientCaseByName(config_.cases_dir, "stiff").model;
  want.version = 1;
  EXPECT_EQ(*got, want);
  EXPECT_EQ(got->axes[kFlexion].coeffs, (std::array<double, 4>{2.0e-4, -0.027, 1.739, -41.805}));
  EXPECT_EQ(got->axes[kFlexion].min_deg, 10.0);
  EXPECT_EQ(got->axes[kFlexion].max_deg, 70.0);
  EXPECT_EQ(got->damping_nms_per_rad, 0.01);
  EXPECT_STREQ(got->case_name.data(), "stiff");
  // The new fields travel too.
  const uint64_t lax = open("lax");
  ASSERT_NE(lax, 0u);
  const auto lax_params = fromWire(out_.models.back(), nullptr);
  ASSERT_TRUE(lax_params.has_value());
  EXPECT_EQ(lax_params->neutral_zone_deg, (std::array<double, 3>{10.0, 5.0, 4.0}));
  open("spasm");
  EXPECT_EQ(fromWire(out_.models.back(), nullptr)->speed_gain_s_per_rad, 1.5);
  EXPECT_EQ(manager_->activeSessions(), 3u);
  EXPECT_THAT(out_.eventsOf(telehand_msg_EVENT_INFO)[0]->text, HasSubstr("case 'stiff'"));
}

TEST_F(SessionManagerTest, UnknownCaseIsAnErrorNamingTheKnownOnesAndOpensNothing) {
  EXPECT_EQ(open("floppy"), 0u);
  EXPECT_EQ(open("../cases/healthy"), 0u);
  EXPECT_EQ(manager_->activeSessions(), 0u);
  EXPECT_TRUE(out_.statuses.empty());
  EXPECT_TRUE(out_.models.empty());
  EXPECT_TRUE(store_->listSessions().empty());
  const auto errors = out_.eventsOf(telehand_msg_EVENT_ERROR);
  ASSERT_EQ(errors.size(), 2u);
  EXPECT_THAT(errors[0]->text,
              AllOf(HasSubstr("'floppy'"),
                    HasSubstr("healthy, hypertonic, lax, oedema, recovery, scar, spasm, stiff")));
  EXPECT_EQ(errors[0]->client_id, 7u);
  EXPECT_EQ(errors[0]->session_id, 0u);
  EXPECT_THAT(errors[1]->text, HasSubstr("'../cases/healthy'"));
  EXPECT_EQ(manager_->stats().bad_commands, 2u);
  // The manager goes on serving.
  EXPECT_NE(open("healthy"), 0u);
}

TEST_F(SessionManagerTest, HandStateComesFromTheBulletHand) {
  ASSERT_NE(open("healthy"), 0u);
  moveToDeg(20.0);
  ASSERT_FALSE(out_.hands.empty());
  const telehand_msg_HandState& h = out_.hands.back();
  EXPECT_EQ(h.session_id, session_);
  EXPECT_EQ(h.source, telehand_msg_HAND_SOURCE_BULLET);
  EXPECT_EQ(h.dof_count, 25u);
  EXPECT_EQ(h.dof_count, hand().dofCount());
  EXPECT_EQ(h.bone_count, std::min<std::size_t>(hand().bones().size(), 24));
  EXPECT_EQ(h.model_version, 1u);
  EXPECT_LE(h.device_seq, seq_ - 1);  // the newest sample at the last tick (every 10 ms)
  EXPECT_GT(h.device_seq + 10, seq_ - 1);
  // The hand followed the grip, and its joint angles carry the same MCP flexion.
  EXPECT_NEAR(radToDeg(h.mcp_angles_rad[kFlexion]), 20.0, 1.0);
  const auto names = hand().dofNames();
  const auto at = std::find(names.begin(), names.end(), "index_mcp_flexion") - names.begin();
  EXPECT_NEAR(h.joint_angles_rad[at], h.mcp_angles_rad[kFlexion], 1e-6);
  // The pads press the phalanx (more than the 1 N that counts as treatment), and the
  // spheres sit where the thimbles are.
  double pressing = 0.0;
  for (int k = 0; k < 2; ++k) {
    const Vec3 f(h.contact_force_n[k][0], h.contact_force_n[k][1], h.contact_force_n[k][2]);
    const Vec3 sphere(h.sphere_m[k][0], h.sphere_m[k][1], h.sphere_m[k][2]);
    const Vec3 tip(h.fingertip_m[k][0], h.fingertip_m[k][1], h.fingertip_m[k][2]);
    EXPECT_LT((sphere - tip).norm(), 0.5e-3) << k;
    pressing += f.norm();
    // The index pad's light squeeze reads zero on a few steps: look at the last 20 states.
    int touching = 0;
    for (auto it = out_.hands.end() - std::min<std::ptrdiff_t>(20, std::ssize(out_.hands));
         it != out_.hands.end(); ++it) {
      const Vec3 fk(it->contact_force_n[k][0], it->contact_force_n[k][1],
                    it->contact_force_n[k][2]);
      touching += fk.norm() > 0.0;
    }
    EXPECT_GE(touching, 10) << k;
  }
  EXPECT_GT(pressing, 1.0);
  // About 100 Hz of them over the 0.97 s of samples.
  EXPECT_GE(out_.hands.size(), 90u);
  EXPECT_LE(out_.hands.size(), 100u);
}

TEST_F(SessionManagerTest, WithoutAHandModelHandStateComesFromTheSharedJointModel) {
  manager_ = std::make_unique<SessionManager>(*store_, out_, config_, nullptr);
  ASSERT_NE(open("healthy"), 0u);
  moveToDeg(20.0);
  ASSERT_FALSE(out_.hands.empty());
  EXPECT_EQ(out_.hands.back().source, telehand_msg_HAND_SOURCE_SHARED_JOINT_MODEL);
  EXPECT_EQ(out_.hands.back().dof_count, 0u);
  EXPECT_NEAR(radToDeg(out_.hands.back().mcp_angles_rad[kFlexion]), 20.0, 1e-6);
}

TEST_F(SessionManagerTest, ExplorationRecordsBaselineAndReassessment) {
  ASSERT_NE(open("healthy", telehand_msg_MODE_EXPLORATION), 0u);
  // Baseline: a scripted student takes the joint to known angles in all six directions
  // (abduction and axial rotation from 20 deg of flexion), back to neutral in between.
  moveToDeg(60.0);
  moveToDeg(-30.0);
  moveToDeg(20.0, 15.0);
  moveToDeg(20.0, -15.0);
  moveToDeg(20.0);
  moveToDeg(20.0, 0.0, 12.0);
  moveToDeg(20.0, 0.0, -8.0);
  moveToDeg(0.0);
  EXPECT_TRUE(store_->reaches(session_).empty());  // recorded when the phase ends
  mark("reassessment");
  {
    // The baseline ends here: its six reaches are stored and scored.
    const auto rs = store_->reaches(session_);
    ASSERT_EQ(rs.size(), 6u);
    const auto scores = out_.eventsOf(telehand_msg_EVENT_SCORE);
    ASSERT_EQ(scores.size(), 1u);
    EXPECT_THAT(
        scores[0]->text,
        AllOf(::testing::StartsWith("baseline: "),
              HasSubstr(format("flexion %.1f deg", reach(rs, "baseline", "flexion")->angle_deg)),
              HasSubstr(
                  format("extension %.1f deg", reach(rs, "baseline", "extension")->angle_deg))));
    EXPECT_THAT(scores[0]->text, ::testing::Not(HasSubstr("vs baseline")));
    EXPECT_THAT(scores[0]->text, ::testing::Not(HasSubstr("stepped over")));
    EXPECT_EQ(out_.eventsOf(telehand_msg_EVENT_MARK).size(), 1u);
  }
  // Reassessment: more flexion than before.
  moveToDeg(70.0);
  moveToDeg(0.0);
  close();
  EXPECT_EQ(manager_->activeSessions(), 0u);
  ASSERT_FALSE(out_.statuses.empty());
  EXPECT_EQ(out_.statuses.back().state, telehand_msg_SESSION_CLOSED);

  const auto rs = store_->reaches(session_);
  // The reassessment went only into flexion (back to 0 deg is not past the 17 deg of extension
  // the joint rests in): its other directions were not reached and have no row.
  ASSERT_EQ(rs.size(), 7u);
  for (const char* dir : Exploration::kDirections) {
    EXPECT_NE(reach(rs, "baseline", dir), nullptr) << "baseline " << dir;
    EXPECT_EQ(reach(rs, "reassessment", dir) != nullptr, dir == std::string("flexion"))
        << "reassessment " << dir;
  }
  ASSERT_NE(reach(rs, "baseline", "flexion"), nullptr);
  EXPECT_NEAR(reach(rs, "baseline", "flexion")->angle_deg, 60.0, 1.0);
  EXPECT_NEAR(reach(rs, "baseline", "extension")->angle_deg, -30.0, 1.0);
  EXPECT_NEAR(reach(rs, "baseline", "abduction")->angle_deg, 15.0, 1.0);
  EXPECT_NEAR(reach(rs, "baseline", "adduction")->angle_deg, -15.0, 1.0);
  EXPECT_NEAR(reach(rs, "baseline", "supination")->angle_deg, 12.0, 1.0);
  EXPECT_NEAR(reach(rs, "baseline", "pronation")->angle_deg, -8.0, 1.0);
  EXPECT_NEAR(reach(rs, "reassessment", "flexion")->angle_deg, 70.0, 1.0);
  // The force at the reach is what holds the joint there (N at the lever arm, the squeeze
  // cancelled): at the flexion reach, the joint model's own holding force within 10 %.
  for (const char* phase : {"baseline", "reassessment"}) {
    Vec3 at = Vec3::Zero();
    at[kFlexion] = degToRad(reach(rs, phase, "flexion")->angle_deg);
    const double want = std::abs(grip_model_->passiveTorqueNm(at, Vec3::Zero())[kFlexion]) /
                        grip_model_->params().lever_arm_m;
    EXPECT_NEAR(reach(rs, phase, "flexion")->force_n, want, 0.1 * want) << phase;
  }
  EXPECT_GT(reach(rs, "baseline", "flexion")->force_n, reach(rs, "baseline", "extension")->force_n);
  EXPECT_GT(reach(rs, "reassessment", "flexion")->force_n, 5.0);
  // Baseline rows first, then reassessment.
  EXPECT_EQ(rs.front().phase, "baseline");
  EXPECT_EQ(rs.back().phase, "reassessment");

  const auto scores = out_.eventsOf(telehand_msg_EVENT_SCORE);
  ASSERT_EQ(scores.size(), 2u);
  EXPECT_EQ(scores[1]->session_id, session_);
  const double gained =
      reach(rs, "reassessment", "flexion")->angle_deg - reach(rs, "baseline", "flexion")->angle_deg;
  EXPECT_NEAR(gained, 10.0, 2.0);
  EXPECT_THAT(scores[1]->text,
              AllOf(::testing::StartsWith("reassessment: flexion "),
                    HasSubstr(format("flexion %.1f deg (%+.1f vs baseline)",
                                     reach(rs, "reassessment", "flexion")->angle_deg, gained))));
  // The scores are in the session's record too.
  int stored_scores = 0;
  for (const auto& e : store_->events(session_)) stored_scores += e.kind == "score";
  EXPECT_EQ(stored_scores, 2);
}

TEST_F(SessionManagerTest, MobilizationSessionRecordsNoReaches) {
  ASSERT_NE(open("healthy"), 0u);
  moveToDeg(30.0);
  close();
  EXPECT_TRUE(store_->reaches(session_).empty());
  EXPECT_TRUE(out_.eventsOf(telehand_msg_EVENT_SCORE).empty());
}

TEST_F(SessionManagerTest, RecoveryRepublishesTheJointAsItsRangeGrows) {
  ASSERT_NE(open("recovery"), 0u);
  const PatientCase pc = loadPatientCaseByName(config_.cases_dir, "recovery");
  ASSERT_EQ(out_.models.size(), 1u);
  EXPECT_EQ(out_.models[0].version, 1u);
  EXPECT_EQ(out_.models[0].axes[kFlexion].max_deg, pc.model.axes[kFlexion].max_deg);
  // Pinch the joint and mobilise it gently inside its starting range: the pads press it
  // (> 1 N together), which is what counts as treatment.
  const int seconds = 20;
  for (int i = 0; i < seconds; ++i) {
    moveToDeg(i % 2 == 0 ? 20.0 : 5.0);  // 0.5 s move (the first 0.67 s) + 0.3 s hold...
    hold(200);                           // ...+ 0.2 s: about one second
  }
  // 0.5 deg of range takes 7.5 s of treatment (flexion max grows 40 deg in 600 s): versions
  // 2 and 3 within 20 s, and never a 4th (that needs 22.5 s of treatment).
  ASSERT_EQ(out_.models.size(), 3u);
  double prev_max = out_.models[0].axes[kFlexion].max_deg;
  double prev_min = out_.models[0].axes[kFlexion].min_deg;
  for (std::size_t i = 1; i < out_.models.size(); ++i) {
    const auto& m = out_.models[i];
    EXPECT_EQ(m.version, i + 1);
    EXPECT_EQ(m.session_id, session_);
    EXPECT_GE(m.axes[kFlexion].max_deg, prev_max + SessionManager::kRecoveryStepDeg);
    EXPECT_LT(m.axes[kFlexion].min_deg, prev_min);
    EXPECT_LE(m.axes[kFlexion].max_deg, pc.final_max_deg[kFlexion]);
    // Only the range changes.
    for (int c = 0; c < 4; ++c) {
      EXPECT_EQ(m.axes[kFlexion].coeffs[c], out_.models[0].axes[kFlexion].coeffs[c]);
    }
    std::string why;
    EXPECT_TRUE(fromWire(m, &why).has_value()) << why;
    prev_max = m.axes[kFlexion].max_deg;
    prev_min = m.axes[kFlexion].min_deg;
  }
  // No more range than the elapsed time could have earned, and at least 15 s worth.
  EXPECT_LE(out_.models.back().axes[kFlexion].max_deg, pc.at(seconds + 1.0).axes[kFlexion].max_deg);
  EXPECT_GE(out_.models.back().axes[kFlexion].max_deg, pc.at(15.0).axes[kFlexion].max_deg);
  // People are told, and the hand state carries the new version.
  const auto infos = out_.eventsOf(telehand_msg_EVENT_INFO);
  int recovery_events = 0;
  for (const auto* e : infos) {
    if (std::string(e->text).find("recovery:") == 0) {
      ++recovery_events;
      EXPECT_THAT(e->text, HasSubstr("flexion range"));
    }
  }
  EXPECT_EQ(recovery_events, 2);
  EXPECT_EQ(out_.hands.back().model_version, 3u);
}

TEST_F(SessionManagerTest, RecoveryNeedsTreatment) {
  ASSERT_NE(open("recovery"), 0u);
  // Ten seconds of ticks with nobody touching the joint: no treatment, no new version.
  for (int i = 0; i < 1000; ++i) {
    now_ns_ += 10'000'000;
    manager_->tick(now_ns_);
  }
  EXPECT_EQ(out_.models.size(), 1u);
  EXPECT_EQ(manager_->activeSessions(), 1u);
}

TEST_F(SessionManagerTest, CasesThatDoNotRecoverAreNeverRepublished) {
  ASSERT_NE(open("healthy"), 0u);
  for (int i = 0; i < 3; ++i) moveToDeg(i % 2 == 0 ? 20.0 : 5.0);
  EXPECT_EQ(out_.models.size(), 1u);
}

TEST_F(SessionManagerTest, CloseEndsTheBaselineWhenThereIsNoReassessment) {
  ASSERT_NE(open("healthy", telehand_msg_MODE_EXPLORATION), 0u);
  moveToDeg(40.0);
  moveToDeg(-30.0);
  close();
  const auto rs = store_->reaches(session_);
  ASSERT_EQ(rs.size(), 2u);  // abduction and axial rotation were not explored
  for (const auto& r : rs) EXPECT_EQ(r.phase, "baseline");
  EXPECT_NEAR(reach(rs, "baseline", "flexion")->angle_deg, 40.0, 1.0);
  EXPECT_NEAR(reach(rs, "baseline", "extension")->angle_deg, -30.0, 1.0);
  const auto scores = out_.eventsOf(telehand_msg_EVENT_SCORE);
  ASSERT_EQ(scores.size(), 1u);
  EXPECT_THAT(scores[0]->text, ::testing::StartsWith("baseline: flexion "));
}

TEST_F(SessionManagerTest, AFloodOfUnknownSessionIdsIsCountedButReportedOnlyUpToTheCap) {
  telehand_msg_DeviceState d{};
  const std::size_t before = out_.events.size();
  for (uint64_t id = 0; id < 5000; ++id) {
    d.session_id = 1'000'000 + id;
    manager_->onDeviceState(d, now_ns_);
  }
  EXPECT_EQ(manager_->stats().unknown_session_samples, 5000u);
  EXPECT_EQ(out_.events.size() - before, SessionManager::kMaxUnknownIds);
  // Once the old ids are forgotten, a new one is reported again.
  now_ns_ += 6'000'000'000;
  d.session_id = 42;
  manager_->onDeviceState(d, now_ns_);
  ASSERT_EQ(out_.events.size() - before, SessionManager::kMaxUnknownIds + 1);
  EXPECT_THAT(out_.events.back().text, HasSubstr("unknown session 42"));
}

TEST_F(SessionManagerTest, MarkForAnUnknownSessionIsAnError) {
  session_ = 999;
  mark("reassessment");
  ASSERT_EQ(out_.eventsOf(telehand_msg_EVENT_ERROR).size(), 1u);
  EXPECT_THAT(out_.eventsOf(telehand_msg_EVENT_ERROR)[0]->text, HasSubstr("999"));
  EXPECT_EQ(manager_->stats().bad_commands, 1u);
}

TEST_F(SessionManagerTest, TheClientsLoopOverrunsReachHandState) {
  ASSERT_NE(open("healthy"), 0u);
  hold(100);
  EXPECT_EQ(out_.hands.back().device_overruns, 0u);
  for (int i = 0; i < 7; ++i) {
    flags_ = sample_flags::kLoopOverrun;  // the tick before this sample ran late
    hold(1);
    flags_ = 0;
    hold(19);
  }
  // A flagged sample received twice (live and again, as a retransmission would) counts once.
  --seq_;
  flags_ = sample_flags::kLoopOverrun;
  hold(1);
  flags_ = 0;
  hold(30);
  EXPECT_EQ(out_.hands.back().device_overruns, 7u);
}

TEST_F(SessionManagerTest, LostSamplesAreSteppedAlongTheWayOnDeviceTime) {
  // A 3 Hz mobilization sent whole, then with 9 of every 10 samples lost: the server steps
  // its hand through the gaps with the thimbles moving in a straight line, so the hand follows
  // the thimbles as closely as when nothing is lost.
  auto lag = [&](int keep_every) {
    EXPECT_NE(open("healthy"), 0u);
    const std::size_t first_hand = out_.hands.size();
    const uint64_t first_seq = seq_;
    std::vector<double> thimbles_deg;
    for (int i = 0; i < 3000; ++i) {
      const double t = i * 1e-3;
      const Vec3 a(degToRad(30.0 + 15.0 * std::sin(2 * kPi * 3.0 * t)), 0.0, 0.0);
      thimbles_deg.push_back(radToDeg(a[kFlexion]));
      if (i % keep_every == 0) {
        sample(a);
      } else {
        ++seq_;  // lost on the way
        now_ns_ += 1'000'000;
        if (now_ns_ % 10'000'000 == 0) manager_->tick(now_ns_);
      }
    }
    double worst = 0.0;
    int compared = 0;
    for (std::size_t h = first_hand; h < out_.hands.size(); ++h) {
      const auto& hs = out_.hands[h];
      const std::size_t i = hs.device_seq - first_seq;
      if (i < 1000 || i >= thimbles_deg.size()) continue;  // past the first second
      worst = std::max(worst, std::abs(radToDeg(hs.mcp_angles_rad[kFlexion]) - thimbles_deg[i]));
      ++compared;
    }
    EXPECT_GT(compared, 150);
    close();
    return worst;
  };
  const double whole = lag(1);
  const double lossy = lag(10);
  EXPECT_LT(lossy, whole + 0.1) << "whole stream " << whole << " deg";
}

TEST_F(SessionManagerTest, ADeferredHandStepsInTheTickAsItDoesWithEachSample) {
  // A second server on a record of its own whose hands step in the tick (setHandSlice, with a
  // slice long enough for every sample waiting): its HandStates are the same, bit for bit.
  SqliteStore store2((dir_ / "deferred.db").string());
  RecordingOutbox out2;
  SessionManager deferred(store2, out2, config_, &hand());
  deferred.setHandSlice(1'000'000'000);
  deferred.setHandShare(1.0);  // no budget: every sample waiting steps in the tick
  ASSERT_NE(open("healthy"), 0u);
  auto c = command(telehand_msg_CMD_OPEN);
  c.mode = telehand_msg_MODE_MOBILIZATION;
  copyString(c.case_name, "healthy");
  copyString(c.user, "student");
  deferred.onCommand(c, now_ns_, from_);
  ASSERT_EQ(out2.statuses.size(), 1u);
  ASSERT_EQ(out2.statuses.back().session_id, session_);
  for (int i = 0; i < 2000; ++i) {
    const telehand_msg_DeviceState d = pinchSample(i);
    manager_->onDeviceState(d, now_ns_, from_);
    deferred.onDeviceState(d, now_ns_, from_);
    now_ns_ += 1'000'000;
    if (now_ns_ % 10'000'000 == 0) {
      EXPECT_TRUE(deferred.handPending());
      manager_->tick(now_ns_);
      deferred.tick(now_ns_);
      EXPECT_FALSE(deferred.handPending());
    }
  }
  ASSERT_GT(out_.hands.size(), 150u);
  ASSERT_EQ(out2.hands.size(), out_.hands.size());
  for (std::size_t k = 0; k < out_.hands.size(); ++k) {
    const auto &inline_hand = out_.hands[k], &deferred_hand = out2.hands[k];
    ASSERT_EQ(deferred_hand.device_seq, inline_hand.device_seq) << k;
    for (int j = 0; j < 3; ++j) {
      EXPECT_EQ(deferred_hand.mcp_angles_rad[j], inline_hand.mcp_angles_rad[j]) << k;
    }
    for (int j = 0; j < inline_hand.dof_count; ++j) {
      EXPECT_EQ(deferred_hand.joint_angles_rad[j], inline_hand.joint_angles_rad[j]) << k;
    }
  }
  EXPECT_EQ(deferred.stats().hand_steps, manager_->stats().hand_steps);
  EXPECT_EQ(deferred.stats().hand_samples_skipped, 0u);
}

TEST_F(SessionManagerTest, HandsShortOfCpuStepOverLiveSamplesButTheRecordKeepsEveryOne) {
  // A slice of 1 ns: one live sample stepped per tick while ten arrive. The hand falls 100
  // samples behind, then steps over every other one waiting; the record has every sample and
  // the close says what the hand missed.
  manager_->setHandSlice(1);
  manager_->setHandShare(1.0);
  ASSERT_NE(open("healthy"), 0u);
  constexpr int kSamples = 2000;
  std::vector<telehand_msg_DeviceState> chunk;
  uint64_t chunk_seq = 0;
  for (int i = 0; i < kSamples; ++i) {
    const telehand_msg_DeviceState d = pinchSample(i, 0.0);
    manager_->onDeviceState(d, now_ns_, from_);
    chunk.push_back(d);
    if (chunk.size() == 100) {
      telehand_msg_RecordChunk rc{};
      rc.session_id = session_;
      rc.chunk_seq = chunk_seq++;
      rc.samples._buffer = chunk.data();
      rc.samples._length = static_cast<uint32_t>(chunk.size());
      rc.samples._maximum = rc.samples._length;
      manager_->onChunk(rc, now_ns_, from_);
      chunk.clear();
    }
    now_ns_ += 1'000'000;
    if (now_ns_ % 10'000'000 == 0) manager_->tick(now_ns_);
  }
  const auto& stats = manager_->stats();
  EXPECT_EQ(stats.recorded_samples, static_cast<uint64_t>(kSamples));
  EXPECT_GT(stats.hand_samples_skipped, 0u);
  EXPECT_LT(stats.hand_steps, static_cast<uint64_t>(kSamples));
  EXPECT_TRUE(manager_->handPending());
  // The HandStates went on at their rate, the hand behind the live stream and still moving
  // along it (a tenth of the samples stepped: up to half a second behind).
  ASSERT_EQ(out_.hands.size(), static_cast<std::size_t>(kSamples / 10));
  const auto& last = out_.hands.back();
  EXPECT_LT(last.device_seq, seq_ - 50);
  EXPECT_GT(last.device_seq, seq_ - 500);
  EXPECT_GT(last.device_seq, out_.hands[out_.hands.size() - 50].device_seq + 200);
  auto c = command(telehand_msg_CMD_CLOSE, session_);
  c.samples_sent = kSamples;
  manager_->onCommand(c, now_ns_, from_);
  EXPECT_FALSE(manager_->handPending());  // a command waits for the hand to step to its samples
  now_ns_ += 10'000'000;
  manager_->tick(now_ns_);
  EXPECT_EQ(manager_->activeSessions(), 0u);
  EXPECT_EQ(store_->session(session_)->samples, static_cast<uint64_t>(kSamples));
  bool said = false;
  for (const auto* e : out_.eventsOf(telehand_msg_EVENT_INFO)) {
    said = said || std::string(e->text).find("the hand stepped over " +
                                             std::to_string(stats.hand_samples_skipped) +
                                             " live samples") != std::string::npos;
  }
  EXPECT_TRUE(said);
}

// An exploration scored by a hand that stepped over some of its samples (a server short of
// CPU) says how many with the score: a reach among them is not in it.
TEST_F(SessionManagerTest, AnExplorationsScoreSaysHowManySamplesTheHandSteppedOver) {
  manager_->setHandSlice(1);
  manager_->setHandShare(1.0);
  ASSERT_NE(open("healthy", telehand_msg_MODE_EXPLORATION), 0u);
  constexpr int kSamples = 1000;
  for (int i = 0; i < kSamples; ++i) {
    manager_->onDeviceState(pinchSample(i, 0.0), now_ns_, from_);
    now_ns_ += 1'000'000;
    if (now_ns_ % 10'000'000 == 0) manager_->tick(now_ns_);
  }
  const uint64_t skipped = manager_->stats().hand_samples_skipped;
  ASSERT_GT(skipped, 0u);
  mark("reassessment");  // the baseline ends and is scored
  const auto scores = out_.eventsOf(telehand_msg_EVENT_SCORE);
  ASSERT_EQ(scores.size(), 1u);
  EXPECT_THAT(scores[0]->text,
              AllOf(::testing::StartsWith("baseline: "),
                    HasSubstr("(the hand stepped over " + std::to_string(skipped) +
                              " of the phase's live samples, the server short of CPU")));
  // The next phase counts its own.
  for (int i = kSamples; i < 2 * kSamples; ++i) {
    manager_->onDeviceState(pinchSample(i, 0.0), now_ns_, from_);
    now_ns_ += 1'000'000;
    if (now_ns_ % 10'000'000 == 0) manager_->tick(now_ns_);
  }
  const uint64_t again = manager_->stats().hand_samples_skipped - skipped;
  ASSERT_GT(again, 0u);
  mark("reassessment");
  const auto later = out_.eventsOf(telehand_msg_EVENT_SCORE);
  ASSERT_EQ(later.size(), 2u);
  EXPECT_THAT(later[1]->text,
              AllOf(::testing::StartsWith("reassessment: "),
                    HasSubstr("(the hand stepped over " + std::to_string(again) + " of")));
}

// --- Drift between the hand and the client's proxy ---------------------------------------------

/// A client proxy that renders every sample with the models the server publishes. With
/// lightGrip() the student's pads slip: the squeeze does not rise with the load, so 12 deg of
/// supination turns the finger only part of the way (HandSim's friction limit).
class DriftTest : public SessionManagerTest {
 protected:
  void lightGrip() {
    sim::HandSimConfig light;
    light.max_pinch_n = light.pinch_preload_n;
    manager_->setHandConfig(light);
  }

  /// Renders every sample on a client proxy that adopts each model the server publishes.
  void afterSample(const Vec3& a) override {
    if (!client_) return;
    while (seen_ < out_.models.size()) {
      const auto p = fromWire(out_.models[seen_++], nullptr);
      EXPECT_TRUE(p.has_value());
      if (p) client_->setModel(*p);
    }
    const ProxyOutput out = client_->render(grip_model_->gripFromAngles(a, 0.008), now_ns_);
    double f = 0.0;
    for (int k = 0; k < 2; ++k) f = std::max(f, out.force_device_n[k].norm());
    worst_step_ = std::max(worst_step_, out.update_step_n / JointProxy::updateStepBoundN(f));
    last_rendered_ = out.angles_rad;
  }

  /// Moves to `target` and holds it; returns the largest update step / bound seen so far.
  double renderTo(const Vec3& target, int hold_ms) {
    moveTo(target);
    hold(hold_ms);
    return worst_step_;
  }

  uint64_t openWithClient(const std::string& case_name) {
    const uint64_t id = open(case_name);
    seen_ = out_.models.size();
    client_ = std::make_unique<JointProxy>(*fromWire(out_.models.back(), nullptr));
    return id;
  }

  Vec3 latestOffsetDeg() const {
    const auto p = fromWire(out_.models.back(), nullptr);
    return p ? Vec3(radToDeg(1.0) * p->grip_offset_rad) : Vec3::Zero();
  }

  std::unique_ptr<JointProxy> client_;
  std::size_t seen_ = 0;
  Vec3 last_rendered_ = Vec3::Zero();
  double worst_step_ = 0.0;
};

TEST_F(DriftTest, ASlipIsCorrectedAndTheClientFollowsWithoutAStep) {
  lightGrip();
  ASSERT_NE(openWithClient("healthy"), 0u);
  const Vec3 pinch(degToRad(20.0), 0.0, 0.0);
  double worst = renderTo(pinch, 500);
  EXPECT_EQ(manager_->stats().drift_corrections, 0u) << "no slip yet, nothing to correct";
  const Vec3 supinated(degToRad(20.0), 0.0, degToRad(12.0));
  worst = std::max(worst, renderTo(supinated, 3000));

  // The hand stopped short of the thimbles in axial rotation.
  ASSERT_FALSE(out_.hands.empty());
  const auto& h = out_.hands.back();
  const Vec3 hand(h.mcp_angles_rad[0], h.mcp_angles_rad[1], h.mcp_angles_rad[2]);
  const double slip_deg = radToDeg(supinated[kAxial] - hand[kAxial]);
  ASSERT_GT(slip_deg, 2.0) << "the pads must have slipped for this test to mean anything";

  // The server folded the slip into the model, the client rendered it, and nothing stepped.
  EXPECT_GE(manager_->stats().drift_corrections, 1u);
  EXPECT_NEAR(latestOffsetDeg()[kAxial], -slip_deg, 0.5);
  EXPECT_LT(radToDeg((last_rendered_ - hand).cwiseAbs().maxCoeff()), 0.5)
      << "the proxy renders where the authoritative hand is";
  EXPECT_LE(worst, 1.0);
  EXPECT_LE(manager_->stats().drift_corrections, 10u);
  bool told = false;
  for (const auto* e : out_.eventsOf(telehand_msg_EVENT_INFO)) {
    told = told || std::string(e->text).find("grip slipped") != std::string::npos;
  }
  EXPECT_TRUE(told) << "a slip this large is reported to the record and the supervisors";
}

TEST_F(DriftTest, PushingIntoTheEndOfRangeWallIsNotDrift) {
  // The thimbles press 1.5 deg past the end of flexion: the proxy renders the wall, the hand
  // rests on its hard limit. The gap is the wall's give, which must stay felt.
  ASSERT_NE(openWithClient("healthy"), 0u);
  const double max_deg = healthyIndexMcp().axes[kFlexion].max_deg;
  renderTo(Vec3(degToRad(max_deg + 1.5), 0.0, 0.0), 2000);
  EXPECT_LT(std::abs(latestOffsetDeg()[kFlexion]), 0.25);
  EXPECT_GT(radToDeg(last_rendered_[kFlexion]), max_deg + 1.0);
}

TEST_F(DriftTest, OffByConfigurationNothingIsCorrected) {
  config_.drift_correction = false;
  manager_ = std::make_unique<SessionManager>(*store_, out_, config_, &hand());
  lightGrip();
  ASSERT_NE(openWithClient("healthy"), 0u);
  renderTo(Vec3(degToRad(20.0), 0.0, degToRad(12.0)), 2000);
  EXPECT_EQ(manager_->stats().drift_corrections, 0u);
  EXPECT_EQ(latestOffsetDeg(), Vec3::Zero());
}

// --- Ownership and bounds ---------------------------------------------------------------------

/// Two participants: A opens the session, B (a rogue on the same partition) tries to act on it.
class OwnershipTest : public SessionManagerTest {
 protected:
  void SetUp() override {
    SessionManagerTest::SetUp();
    from_ = kA;
  }

  /// With ended sessions kept 2 s for late joiners: opens a "healthy" and a "stiff" session
  /// and closes the first; their ids (0 where an OPEN failed).
  std::pair<uint64_t, uint64_t> twoOpenedTheFirstClosed() {
    config_.status_keep_s = 2.0;
    manager_ = std::make_unique<SessionManager>(*store_, out_, config_, &hand());
    const uint64_t first = open("healthy");
    const uint64_t second = open("stiff");
    session_ = first;
    if (first != 0) close();
    return {first, second};
  }

  /// A plausible sample of `session` (thimbles 16 mm apart, unit quaternions).
  static telehand_msg_DeviceState wireSample(uint64_t session, uint64_t seq,
                                             uint32_t model_version = 1) {
    telehand_msg_DeviceState s{};
    s.session_id = session;
    s.seq = seq;
    s.source_time_ns = 1;
    s.model_version = model_version;
    for (int k = 0; k < 2; ++k) {
      s.fingers[k].position_m[0] = 0.01;
      s.fingers[k].position_m[2] = k == 0 ? 0.008 : -0.008;
      s.fingers[k].orientation_q[0] = 1.0;
    }
    return s;
  }

  /// One RecordChunk of `samples` for `session`, as `from` sends it.
  void sendChunk(uint64_t session, std::vector<telehand_msg_DeviceState> samples,
                 const Origin& from) {
    telehand_msg_RecordChunk c{};
    c.session_id = session;
    c.chunk_seq = chunk_seq_++;
    c.samples._buffer = samples.data();
    c.samples._length = c.samples._maximum = static_cast<uint32_t>(samples.size());
    c.samples._release = false;
    manager_->onChunk(c, now_ns_, from);
    manager_->tick(now_ns_);  // the serve loop's round ends: what it took is stored
  }
  /// Sequence numbers [first, first + n) of `session` with `model_version`, in chunks of 200.
  void sendRange(uint64_t session, uint64_t first, uint64_t n, const Origin& from,
                 uint32_t model_version = 1) {
    for (uint64_t at = first; at < first + n; at += 200) {
      std::vector<telehand_msg_DeviceState> v;
      for (uint64_t q = at; q < std::min(first + n, at + 200); ++q)
        v.push_back(wireSample(session, q, model_version));
      sendChunk(session, std::move(v), from);
    }
  }

  void command(telehand_msg_CommandKind kind, const Origin& from, uint64_t samples_sent = 0,
               const std::string& text = "") {
    auto c = SessionManagerTest::commandFor(kind, session_);
    c.samples_sent = samples_sent;
    copyString(c.text, text);
    manager_->onCommand(c, now_ns_, from);
  }
  void file(const Origin& from, const std::string& name, std::size_t bytes) {
    std::string content(bytes, 'x');
    telehand_msg_SessionFile f{};
    f.session_id = session_;
    copyString(f.name, name);
    f.content = content.data();
    manager_->onFile(f, now_ns_, from);
  }
  void tickFor(int64_t ns) {
    const int64_t until = now_ns_ + ns;
    while (now_ns_ < until) {
      now_ns_ += 10'000'000;
      manager_->tick(now_ns_);
    }
  }

  /// The security events published so far.
  std::vector<std::string> securityEvents() const {
    std::vector<std::string> out;
    for (const auto* e : out_.eventsOf(telehand_msg_EVENT_ERROR)) {
      if (std::string(e->text).starts_with("security: refused")) out.emplace_back(e->text);
    }
    return out;
  }
  struct Stored {
    uint64_t rows = 0, invalid = 0, from_rogue = 0, lowest = UINT64_MAX, highest = 0;
  };
  int64_t closeGraceNs() const { return static_cast<int64_t>(config_.close_grace_s * 1e9); }
  /// Opens a session, moves, CLOSEs it with every sample sent, then calls send() and ticks
  /// `step` later until the session has ended or `limit` has passed: how long it stayed open.
  int64_t closeWhileSending(const std::function<void()>& send, int64_t step, int64_t limit) {
    EXPECT_NE(open("healthy"), 0u);
    moveToDeg(5.0);
    command(telehand_msg_CMD_CLOSE, kA, seq_ - 1);
    int64_t waited = 0;
    while (manager_->activeSessions() > 0 && waited < limit) {
      send();
      now_ns_ += step;
      waited += step;
      manager_->tick(now_ns_);
    }
    return waited;
  }

  Stored stored(uint64_t session) {
    Stored r;
    store_->forEachSample(session, [&](const Sample& s, bool valid) {
      ++r.rows;
      r.invalid += !valid;
      r.from_rogue += s.model_version == kRogueVersion;
      r.lowest = std::min(r.lowest, s.seq);
      r.highest = std::max(r.highest, s.seq);
    });
    return r;
  }

  /// A session that ends incomplete (its last 100 samples not sent before the CLOSE's grace
  /// ran out); `restarted`: then served by a server started afresh, which does not remember
  /// it. A stranger's late chunk of the missing 100 is refused, naming the owner; the
  /// owner's is stored.
  void lateChunksAreTakenFromTheOwnerOnly(bool restarted) {
    ASSERT_NE(open("healthy"), 0u);
    moveToDeg(5.0);
    const uint64_t sent = seq_ - 1;
    sendRange(session_, 1, sent - 100, kA);
    command(telehand_msg_CMD_CLOSE, kA, sent);
    now_ns_ += static_cast<int64_t>(config_.close_grace_s * 1e9) + 10'000'000;
    manager_->tick(now_ns_);
    ASSERT_EQ(manager_->activeSessions(), 0u);
    ASSERT_EQ(store_->session(session_)->state, "incomplete");
    ASSERT_EQ(store_->session(session_)->owner, kA.guid);
    if (restarted) manager_ = std::make_unique<SessionManager>(*store_, out_, config_, &hand());
    sendRange(session_, sent - 99, 100, kB, kRogueVersion);
    EXPECT_EQ(manager_->stats().refused, 100u);
    ASSERT_EQ(securityEvents().size(), 1u);
    EXPECT_THAT(securityEvents()[0],
                AllOf(HasSubstr("a late RecordChunk from participant " + kB.guid),
                      HasSubstr("belongs to " + kA.guid)));
    EXPECT_EQ(stored(session_).rows, sent - 100);
    sendRange(session_, sent - 99, 100, kA);
    const Stored st = stored(session_);
    EXPECT_EQ(st.rows, sent);
    EXPECT_EQ(st.from_rogue, 0u);
    EXPECT_EQ(manager_->stats().refused, 100u);
  }

  static constexpr uint32_t kRogueVersion = 999;
  const Origin kA{11, "0110a0a0a0a0a0a0a0a0a0a0000001c1", ""};
  const Origin kB{22, "0110b0b0b0b0b0b0b0b0b0b0000001c1", ""};
  uint64_t chunk_seq_ = 0;
};

TEST_F(OwnershipTest, AnotherParticipantIsRefusedAllButMarksAndTheOwnerIsServed) {
  ASSERT_NE(open("healthy", telehand_msg_MODE_CAPTURE), 0u);
  EXPECT_EQ(store_->session(session_)->owner, kA.guid);
  moveToDeg(10.0);  // A's live stream
  const uint64_t a_sent = seq_ - 1;
  const std::size_t statuses = out_.statuses.size();
  const std::size_t hands = out_.hands.size();

  // B: a live sample, a chunk over A's sequence numbers, a file, a MARK and a CLOSE. The MARK
  // is kept (a supervisor marks sessions it did not open), attributed to B, and inert: the
  // owner's "reassessment" would start a phase, B's does not.
  manager_->onDeviceState(wireSample(session_, seq_, kRogueVersion), now_ns_, kB);
  sendRange(session_, 1, 150, kB, kRogueVersion);
  file(kB, "rogue.toml", 100);
  command(telehand_msg_CMD_MARK, kB, 0, "reassessment");
  command(telehand_msg_CMD_CLOSE, kB, 0);
  tickFor(100'000'000);

  EXPECT_EQ(manager_->stats().refused, 1u + 150u + 1u + 1u);
  EXPECT_EQ(manager_->activeSessions(), 1u);
  for (std::size_t i = statuses; i < out_.statuses.size(); ++i)
    EXPECT_EQ(out_.statuses[i].state, telehand_msg_SESSION_ACTIVE);
  EXPECT_EQ(stored(session_).rows, 0u);
  EXPECT_TRUE(store_->files(session_).empty());
  ASSERT_EQ(out_.eventsOf(telehand_msg_EVENT_MARK).size(), 1u);
  EXPECT_THAT(std::string(out_.eventsOf(telehand_msg_EVENT_MARK)[0]->text),
              AllOf(HasSubstr("reassessment"), HasSubstr("(from participant " + kB.guid + ")")));
  // The hand took nothing of B's: no new HandState names B's sequence number.
  for (std::size_t i = hands; i < out_.hands.size(); ++i) EXPECT_LT(out_.hands[i].device_seq, seq_);
  // One event for the lot (at most one per 5 s per session), naming the first refusal, the
  // sender and the owner; it is in the session's record too.
  auto refused = securityEvents();
  ASSERT_EQ(refused.size(), 1u);
  EXPECT_THAT(refused[0],
              AllOf(HasSubstr("DeviceState from participant " + kB.guid),
                    HasSubstr("session " + std::to_string(session_) + " belongs to " + kA.guid)));
  bool in_record = false;
  for (const auto& e : store_->events(session_))
    in_record = in_record || e.text.find("security: refused") != std::string::npos;
  EXPECT_TRUE(in_record);
  // 5 s later the next refusal is reported again, naming what it was.
  now_ns_ += 5'000'000'000;
  command(telehand_msg_CMD_CLOSE, kB, 0);
  refused = securityEvents();
  ASSERT_EQ(refused.size(), 2u);
  EXPECT_THAT(refused[1], HasSubstr("a CLOSE from participant " + kB.guid));
  now_ns_ += 5'000'000'000;
  file(kB, "rogue.toml", 100);
  now_ns_ += 5'000'000'000;
  sendRange(session_, 1, 10, kB, kRogueVersion);
  now_ns_ += 5'000'000'000;
  command(telehand_msg_CMD_MARK, kB, 0, "x");
  refused = securityEvents();
  ASSERT_EQ(refused.size(), 4u);
  EXPECT_THAT(refused[2], HasSubstr("a SessionFile from participant " + kB.guid));
  EXPECT_THAT(refused[3], HasSubstr("a RecordChunk from participant " + kB.guid));
  EXPECT_EQ(manager_->activeSessions(), 1u);

  // A's own are taken: its record, its file, its mark, its CLOSE.
  sample(angles_);
  sendRange(session_, 0, a_sent + 1, kA);  // sequence numbers 0 .. a_sent, as a client's
  file(kA, "device.toml", 100);
  command(telehand_msg_CMD_MARK, kA, 0, "mid-point");
  command(telehand_msg_CMD_CLOSE, kA, a_sent + 1);
  tickFor(100'000'000);
  EXPECT_EQ(manager_->activeSessions(), 0u);
  EXPECT_EQ(out_.statuses.back().state, telehand_msg_SESSION_CLOSED);
  EXPECT_EQ(out_.statuses.back().samples_missing, 0u);
  const auto info = store_->session(session_);
  EXPECT_EQ(info->state, "closed");
  EXPECT_EQ(info->samples, a_sent + 1);
  const Stored s = stored(session_);
  EXPECT_EQ(s.rows, a_sent + 1);
  EXPECT_EQ(s.from_rogue, 0u);
  EXPECT_EQ(s.invalid, 0u);
  ASSERT_EQ(store_->files(session_).size(), 1u);
  EXPECT_EQ(store_->files(session_)[0].name, "device.toml");
  EXPECT_EQ(out_.eventsOf(telehand_msg_EVENT_MARK).size(), 3u);  // B's two, A's one
  EXPECT_EQ(manager_->stats().refused, 153u + 1u + 1u + 10u);
}

TEST_F(OwnershipTest, MarksFromOtherParticipantsAreBoundedPerSession) {
  ASSERT_NE(open("healthy"), 0u);
  const auto cap = static_cast<std::size_t>(SessionManager::kMaxForeignMarks);
  for (std::size_t i = 0; i < cap + 3; ++i) command(telehand_msg_CMD_MARK, kB, 0, "note");
  EXPECT_EQ(out_.eventsOf(telehand_msg_EVENT_MARK).size(), cap);
  EXPECT_EQ(manager_->stats().refused, 3u);
  command(telehand_msg_CMD_MARK, kA, 0, "own");  // the owner's marks are not counted
  EXPECT_EQ(out_.eventsOf(telehand_msg_EVENT_MARK).size(), cap + 1);
  EXPECT_EQ(std::string(out_.eventsOf(telehand_msg_EVENT_MARK).back()->text), "own");
}

TEST_F(OwnershipTest, AnUnknownSenderIsNotRefused) {
  // Callers without DDS (participant 0) act on anyone's session, as before ownership.
  ASSERT_NE(open("healthy"), 0u);
  moveToDeg(5.0);
  const uint64_t sent = seq_ - 1;
  const Origin nobody{};
  manager_->onDeviceState(wireSample(session_, seq_), now_ns_, nobody);
  sendRange(session_, 0, sent + 1, nobody);
  command(telehand_msg_CMD_MARK, nobody, 0, "note");
  command(telehand_msg_CMD_CLOSE, nobody, sent + 1);
  tickFor(50'000'000);
  EXPECT_EQ(manager_->stats().refused, 0u);
  EXPECT_TRUE(securityEvents().empty());
  EXPECT_EQ(manager_->activeSessions(), 0u);
  EXPECT_EQ(store_->session(session_)->state, "closed");
  EXPECT_EQ(stored(session_).rows, sent + 1);
  // And a session whose opener is not known takes anyone's.
  from_ = nobody;
  ASSERT_NE(open("healthy"), 0u);
  EXPECT_EQ(store_->session(session_)->owner, "");
  sendRange(session_, 0, 100, kB);
  command(telehand_msg_CMD_CLOSE, kB, 100);
  tickFor(50'000'000);
  EXPECT_EQ(manager_->stats().refused, 0u);
  EXPECT_EQ(store_->session(session_)->state, "closed");
  EXPECT_EQ(stored(session_).rows, 100u);
}

TEST_F(OwnershipTest, ASenderTheLinkCouldNotNameIsRefused) {
  // A writer deleted (or its participant gone) before the server read its sample: Cyclone no
  // longer knows who sent it, so it could be anyone's. Nothing of it is taken: not its OPEN
  // (a session of nobody's would take anyone's CLOSE), not its samples, chunks, files, marks
  // or CLOSE for the owner's session.
  ASSERT_NE(open("healthy"), 0u);
  const uint64_t owned = session_;
  moveToDeg(5.0);
  const uint64_t sent = seq_ - 1;
  Origin gone;
  gone.unknown = true;
  sendRange(session_, sent + 1, 1000, gone, kRogueVersion);  // just ahead of the owner's
  sendRange(session_, 1, 300, gone, kRogueVersion);          // over the owner's own
  manager_->onDeviceState(wireSample(session_, seq_), now_ns_, gone);
  command(telehand_msg_CMD_MARK, gone, 0, "note");
  command(telehand_msg_CMD_CLOSE, gone, 0);
  telehand_msg_SessionFile f{};
  f.session_id = session_;
  copyString(f.name, "calibration.toml");
  std::string content = "x = 1\n";
  f.content = content.data();
  manager_->onFile(f, now_ns_, gone);
  tickFor(50'000'000);
  EXPECT_EQ(manager_->activeSessions(), 1u) << "the CLOSE was not taken";
  EXPECT_EQ(out_.eventsOf(telehand_msg_EVENT_MARK).size(), 0u);
  EXPECT_EQ(manager_->stats().refused, 1000u + 300u + 1u + 1u + 1u + 1u);
  ASSERT_FALSE(securityEvents().empty());
  EXPECT_THAT(securityEvents()[0], HasSubstr("a participant that had left before it was read"));
  from_ = gone;
  EXPECT_EQ(open("healthy"), 0u) << "an OPEN from nobody";
  EXPECT_EQ(manager_->activeSessions(), 1u);
  // The owner's record is whole and holds nothing of the stranger's.
  session_ = owned;
  sendRange(session_, 0, sent, kA);
  command(telehand_msg_CMD_CLOSE, kA, sent);
  tickFor(50'000'000);
  EXPECT_EQ(manager_->activeSessions(), 0u);
  EXPECT_EQ(store_->session(session_)->state, "closed");
  const Stored st = stored(session_);
  EXPECT_EQ(st.rows, sent);
  EXPECT_EQ(st.from_rogue, 0u);
  EXPECT_EQ(st.highest, sent - 1);
  // Nor does it reach the record once the session has ended.
  const uint64_t refused = manager_->stats().refused;
  sendRange(session_, sent + 1, 100, gone, kRogueVersion);
  EXPECT_EQ(manager_->stats().refused, refused + 100u);
  EXPECT_EQ(stored(session_).rows, sent);
}

TEST_F(OwnershipTest, RowsPastWhatWasSentDoNotMakeUpForMissingOnes) {
  // "closed, 0 missing" means every sequence number below what the client says it sent is in
  // the record, not that as many rows arrived: 100 of them missing and 100 past the end is
  // incomplete, 100 missing.
  ASSERT_NE(open("healthy"), 0u);
  const uint64_t sent = 1000;
  sendRange(session_, 0, 900, kA);
  sendRange(session_, 1000, 100, kA);
  command(telehand_msg_CMD_CLOSE, kA, sent);
  now_ns_ += closeGraceNs() + 10'000'000;
  manager_->tick(now_ns_);
  ASSERT_EQ(manager_->activeSessions(), 0u);
  EXPECT_EQ(stored(session_).rows, sent);
  EXPECT_EQ(store_->session(session_)->state, "incomplete");
  EXPECT_EQ(out_.statuses.back().state, telehand_msg_SESSION_CLOSED);
  EXPECT_EQ(out_.statuses.back().samples_missing, 100u);
  // The record says so too, as read back later (telehand-records, a status query).
  EXPECT_EQ(store_->session(session_)->missing(), 100u);
}

TEST_F(OwnershipTest, BadCommandsFromOneParticipantAreSaidAFewTimesAndCounted) {
  // Each bad command's event is published and logged: a flood of them from one participant is
  // said kBadCommandEvents times per 5 s and counted; another participant is still answered.
  const auto errors = [&] { return out_.eventsOf(telehand_msg_EVENT_ERROR).size(); };
  const std::size_t before = errors();
  const uint64_t bad_before = manager_->stats().bad_commands;
  session_ = 424242;  // no such session
  for (int i = 0; i < 50; ++i) {
    command(telehand_msg_CMD_MARK, kB, 0, "note");
    now_ns_ += 1'000'000;
  }
  const auto limit = static_cast<std::size_t>(SessionManager::kBadCommandEvents);
  EXPECT_EQ(errors() - before, limit);
  EXPECT_EQ(manager_->stats().bad_commands - bad_before, 50u);
  command(telehand_msg_CMD_CLOSE, kA, 0);
  EXPECT_EQ(errors() - before, limit + 1) << "another participant is answered";
  now_ns_ += 5'000'000'000;
  command(telehand_msg_CMD_PHASE, kB, 0);
  EXPECT_EQ(errors() - before, limit + 2) << "and the first again after 5 s";
  EXPECT_THAT(std::string(out_.eventsOf(telehand_msg_EVENT_ERROR).back()->text),
              HasSubstr("PHASE for unknown session 424242"));
}

TEST_F(OwnershipTest, LateChunksOfASessionThisServerNeverRanAreTakenFromItsOwnerOnly) {
  // The session ended under a server before this one (or so long ago that this one no longer
  // remembers it): its owner is the record's.
  lateChunksAreTakenFromTheOwnerOnly(true);
}

TEST_F(OwnershipTest, ASuspendedSessionTakesChunksFromItsOwnerOnly) {
  // The server stopped; the next one holds the session for its client to resume. Meanwhile
  // a stranger's chunks would fill the record's gaps (the store keeps the first copy of a
  // sequence number) and its high sequence numbers would shut the owner out.
  ASSERT_NE(open("healthy"), 0u);
  sendRange(session_, 1, 400, kA);
  manager_->closeAll(now_ns_);
  ASSERT_EQ(store_->session(session_)->state, "suspended");
  manager_ = std::make_unique<SessionManager>(*store_, out_, config_, &hand());
  ASSERT_EQ(manager_->recoverFromStore(now_ns_), 1u);
  ASSERT_EQ(manager_->suspendedSessions(), 1u);
  sendRange(session_, 401, 200, kB, kRogueVersion);
  sendRange(session_, 1u << 30, 10, kB, kRogueVersion);
  EXPECT_EQ(manager_->stats().refused, 210u);
  ASSERT_FALSE(securityEvents().empty());
  EXPECT_THAT(securityEvents()[0], HasSubstr("belongs to " + kA.guid));
  sendRange(session_, 401, 200, kA);  // the owner's backlog while it waits
  const Stored st = stored(session_);
  EXPECT_EQ(st.rows, 600u);
  EXPECT_EQ(st.from_rogue, 0u);
  EXPECT_EQ(st.highest, 600u);
}

TEST_F(OwnershipTest, ASuspendedSessionKeepsItsOwnerWhenTheRememberedOnesAreFlooded) {
  // The server remembers the owners of kMaxEndedOwners sessions not running here. A stranger
  // whose chunks name that many other sessions of the record pushes the suspended session's
  // owner out of that ring; its chunks for the suspended session are still refused (the
  // record says whose it is).
  ASSERT_NE(open("healthy"), 0u);
  const uint64_t suspended = session_;
  sendRange(suspended, 1, 400, kA);
  manager_->closeAll(now_ns_);
  ASSERT_EQ(store_->session(suspended)->state, "suspended");
  manager_ = std::make_unique<SessionManager>(*store_, out_, config_, &hand());
  ASSERT_EQ(manager_->recoverFromStore(now_ns_), 1u);
  std::vector<uint64_t> others;
  for (std::size_t i = 0; i < SessionManager::kMaxEndedOwners + 8; ++i) {
    SessionInfo info;
    info.user = "other";
    info.case_name = "healthy";
    info.mode = "mobilization";
    info.state = "closed";
    info.owner = kA.guid;
    others.push_back(store_->createSession(info));
  }
  for (const uint64_t id : others) sendChunk(id, {}, kB);
  const uint64_t refused = manager_->stats().refused;
  sendRange(suspended, 401, 200, kB, kRogueVersion);
  EXPECT_EQ(manager_->stats().refused, refused + 200u);
  const Stored st = stored(suspended);
  EXPECT_EQ(st.rows, 400u);
  EXPECT_EQ(st.from_rogue, 0u);
  sendRange(suspended, 401, 200, kA);  // the owner's are still taken
  EXPECT_EQ(stored(suspended).rows, 600u);
}

TEST_F(OwnershipTest, RefusalsForSessionsNotHereAreNotPublishedUnderTheirIds) {
  // A SessionEvent's session id is its DDS instance (transient-local, kept until retired):
  // refusals for ids no session here has (made up by the sender) go under session 0, the id
  // named in the text, so that a flood of made-up ids leaves no instance behind.
  ASSERT_NE(open("healthy"), 0u);
  const std::size_t before = out_.events.size();
  for (uint64_t id = 900'000; id < 900'050; ++id) {
    telehand_msg_DeviceState far = wireSample(id, uint64_t{1} << 63, kRogueVersion);
    sendChunk(id, {far}, kB);  // each id its own report
  }
  std::size_t refusals = 0;
  for (std::size_t i = before; i < out_.events.size(); ++i) {
    const auto& e = out_.events[i];
    if (!std::string(e.text).starts_with("security: refused")) continue;
    ++refusals;
    EXPECT_EQ(e.session_id, 0u) << e.text;
    EXPECT_THAT(std::string(e.text), HasSubstr("(for session 9000"));
  }
  EXPECT_EQ(refusals, 50u);
  // One for the session running here still goes under its id.
  sendRange(session_, uint64_t{1} << 62, 1, kB, kRogueVersion);
  ASSERT_FALSE(out_.events.empty());
  EXPECT_EQ(out_.events.back().session_id, session_);
  EXPECT_THAT(std::string(out_.events.back().text), HasSubstr("belongs to"));
}

TEST_F(OwnershipTest, UnderSecurityTheLimitCountsTheIdentityNotItsParticipants) {
  // Two participants of one certificate (their GUIDs share the subject's 48-bit hash) and
  // one of another: the limit per participant holds for the identity.
  config_.max_sessions_per_participant = 2;
  manager_ = std::make_unique<SessionManager>(*store_, out_, config_, &hand());
  const Origin one{31, "d9e01656ff1acb63b2659309000001c1", "d9e01656ff1a"};
  const Origin same{32, "d9e01656ff1a62f3bd8594ce000001c1", "d9e01656ff1a"};
  const Origin other{33, "953d9ad09f1f8cea4e891935000001c1", "953d9ad09f1f"};
  from_ = one;
  ASSERT_NE(open("healthy"), 0u);
  from_ = same;
  ASSERT_NE(open("healthy"), 0u);
  EXPECT_EQ(open("healthy"), 0u) << "a third session of the same identity";
  from_ = one;
  EXPECT_EQ(open("stiff"), 0u);
  EXPECT_EQ(manager_->stats().refused, 2u);
  const auto refused = securityEvents();
  ASSERT_FALSE(refused.empty());
  EXPECT_THAT(refused[0], HasSubstr("its identity d9e01656ff1a has 2 sessions open"));
  from_ = other;
  EXPECT_NE(open("healthy"), 0u);
  EXPECT_EQ(manager_->activeSessions(), 3u);
}

TEST_F(OwnershipTest, OpensBeyondTheLimitsAreRefusedAndTheOpenSessionsGoOn) {
  config_.max_sessions = 3;
  config_.max_sessions_per_participant = 2;
  manager_ = std::make_unique<SessionManager>(*store_, out_, config_, &hand());
  const uint64_t a1 = open("healthy");
  ASSERT_NE(a1, 0u);
  ASSERT_NE(open("stiff"), 0u);
  // A's third: over the limit per participant.
  EXPECT_EQ(open("healthy"), 0u);
  EXPECT_EQ(manager_->stats().refused, 1u);
  auto refused = securityEvents();
  ASSERT_EQ(refused.size(), 1u);
  EXPECT_THAT(refused[0], AllOf(HasSubstr("an OPEN from participant " + kA.guid),
                                HasSubstr("it has 2 sessions open"),
                                HasSubstr("max_sessions_per_participant")));
  // B may still open one; then the server is full, for B and for callers without DDS.
  from_ = kB;
  ASSERT_NE(open("healthy"), 0u);
  EXPECT_EQ(manager_->activeSessions(), 3u);
  now_ns_ += 6'000'000'000;
  EXPECT_EQ(open("healthy"), 0u);
  from_ = Origin{};
  EXPECT_EQ(open("healthy"), 0u);
  EXPECT_EQ(manager_->stats().refused, 3u);
  refused = securityEvents();
  ASSERT_EQ(refused.size(), 3u) << "each sender hears of its own refused OPEN";
  EXPECT_THAT(refused[1], AllOf(HasSubstr("an OPEN from participant " + kB.guid),
                                HasSubstr("3 sessions open"), HasSubstr("(server.max_sessions)")));
  EXPECT_THAT(refused[2], HasSubstr("an OPEN from participant ?"));
  EXPECT_EQ(store_->listSessions().size(), 3u);
  EXPECT_EQ(manager_->activeSessions(), 3u);
  // A flood of refused OPENs leaves the open sessions working: A's first still runs its hand;
  // the flood's refusals within 5 s are counted, not each reported.
  from_ = kB;
  for (int i = 0; i < 2000; ++i) open("healthy");
  EXPECT_EQ(manager_->stats().refused, 2003u);
  EXPECT_EQ(securityEvents().size(), 3u);
  session_ = a1;
  from_ = kA;
  const std::size_t hands = out_.hands.size();
  moveToDeg(15.0);
  std::size_t a1_hands = 0;
  for (std::size_t i = hands; i < out_.hands.size(); ++i)
    a1_hands += out_.hands[i].session_id == a1;
  EXPECT_GT(a1_hands, 50u);
  // Once a session ends, its owner may open again.
  close();
  ASSERT_NE(open("healthy"), 0u);
}

TEST_F(OwnershipTest, FilesAreKeptOnlyForCapturesWithinTheirLimits) {
  config_.max_file_bytes = 4096;
  config_.max_files_per_session = 2;
  manager_ = std::make_unique<SessionManager>(*store_, out_, config_, &hand());
  ASSERT_NE(open("healthy"), 0u);  // mobilization
  file(kA, "device.toml", 100);
  EXPECT_TRUE(store_->files(session_).empty());
  EXPECT_EQ(manager_->stats().refused, 1u);
  ASSERT_EQ(securityEvents().size(), 1u);
  EXPECT_THAT(securityEvents()[0], HasSubstr("only capture sessions keep files"));

  ASSERT_NE(open("healthy", telehand_msg_MODE_CAPTURE), 0u);
  file(kA, "huge.bin", 4097);
  EXPECT_EQ(manager_->stats().refused, 2u);
  ASSERT_EQ(securityEvents().size(), 2u);
  EXPECT_THAT(securityEvents()[1], AllOf(HasSubstr("'huge.bin' (4097 bytes)"),
                                         HasSubstr("larger than server.max_file_bytes = 4096")));
  file(kA, "device.toml", 4096);
  file(kA, "thimbles.toml", 10);
  file(kA, "third.toml", 10);
  EXPECT_EQ(manager_->stats().refused, 3u);
  now_ns_ += 6'000'000'000;
  file(kA, "fourth.toml", 10);
  EXPECT_EQ(manager_->stats().refused, 4u);
  ASSERT_EQ(securityEvents().size(), 3u);
  EXPECT_THAT(securityEvents()[2],
              AllOf(HasSubstr("'fourth.toml'"), HasSubstr("already keeps 2 files")));
  const auto files = store_->files(session_);
  ASSERT_EQ(files.size(), 2u);
  std::vector<std::string> names{files[0].name, files[1].name};
  std::sort(names.begin(), names.end());
  EXPECT_EQ(names, (std::vector<std::string>{"device.toml", "thimbles.toml"}));
  for (const auto& f : files) EXPECT_EQ(f.content.size(), f.name == "device.toml" ? 4096u : 10u);
}

TEST_F(OwnershipTest, SamplesOutsideTheSequenceWindowAreRefusedAndNotStored) {
  ASSERT_NE(open("healthy"), 0u);
  moveToDeg(5.0);
  const uint64_t high = seq_ - 1;  // the client's highest so far
  sendRange(session_, 1, high, kA);
  EXPECT_EQ(manager_->stats().refused, 0u);
  // 1,000 samples just ahead of the client: within the window, taken.
  sendRange(session_, high + 1, 1000, kA);
  EXPECT_EQ(manager_->stats().refused, 0u);
  uint64_t top = high + 1000;
  EXPECT_EQ(stored(session_).highest, top);
  // One beyond the window of the new highest: refused, not stored.
  sendChunk(session_, {wireSample(session_, top + SessionManager::kSeqWindow + 1)}, kA);
  EXPECT_EQ(manager_->stats().refused, 1u);
  EXPECT_EQ(stored(session_).highest, top);
  // The window's edge is still in.
  sendChunk(session_, {wireSample(session_, top + SessionManager::kSeqWindow)}, kA);
  EXPECT_EQ(manager_->stats().refused, 1u);
  top += SessionManager::kSeqWindow;
  EXPECT_EQ(stored(session_).highest, top);
  // Now the client's first samples lie behind the window.
  sendChunk(session_, {wireSample(session_, top - SessionManager::kSeqWindow - 1)}, kA);
  EXPECT_EQ(manager_->stats().refused, 2u);
  // Sequence numbers from 2^63 on are never taken, live or recorded, whatever the window.
  const uint64_t huge = sample_bounds::kMaxSeq;
  sendChunk(session_, {wireSample(session_, huge), wireSample(session_, UINT64_MAX)}, kA);
  manager_->onDeviceState(wireSample(session_, huge), now_ns_, kA);
  EXPECT_EQ(manager_->stats().refused, 5u);
  const Stored s = stored(session_);
  EXPECT_EQ(s.rows, high + 1000 + 1);
  EXPECT_EQ(s.highest, top);
  const auto refused = securityEvents();
  ASSERT_EQ(refused.size(), 1u);
  EXPECT_THAT(refused[0], HasSubstr("1 RecordChunk samples outside the sequence window"));
  // A fresh session: 2^63 as the very first sample does not set its window.
  ASSERT_NE(open("healthy"), 0u);
  sendChunk(session_, {wireSample(session_, huge)}, kA);
  EXPECT_EQ(manager_->stats().refused, 6u);
  sendRange(session_, 0, 10, kA);
  EXPECT_EQ(manager_->stats().refused, 6u);
  EXPECT_EQ(stored(session_).rows, 10u);
  // One chunk cannot walk the window along by itself: each of its samples is judged against
  // the highest number before the chunk (here 9), not the chunk's own last one.
  const uint64_t half = SessionManager::kSeqWindow / 2;
  sendChunk(session_,
            {wireSample(session_, 9 + half), wireSample(session_, 9 + 2 * half),
             wireSample(session_, 9 + 3 * half), wireSample(session_, 9 + 4 * half)},
            kA);
  EXPECT_EQ(manager_->stats().refused, 8u);
  EXPECT_EQ(stored(session_).rows, 12u);
  EXPECT_EQ(stored(session_).highest, 9 + 2 * half);
}

TEST_F(OwnershipTest, ImplausibleSamplesAreStoredFlaggedAndKeptFromTheHand) {
  ASSERT_NE(open("healthy"), 0u);
  moveToDeg(10.0);
  auto huge_position = wireSample(session_, seq_);
  huge_position.fingers[0].position_m[1] = 1e308;
  auto long_quaternion = wireSample(session_, seq_ + 1);
  long_quaternion.fingers[1].orientation_q[0] = 5.0;
  auto fsr = wireSample(session_, seq_ + 2);
  fsr.fingers[1].fsr_n[2] = 1e6f;
  const uint64_t bad_first = seq_;
  std::vector<telehand_msg_DeviceState> chunk;
  for (uint64_t q = 1; q < seq_; ++q) chunk.push_back(wireSample(session_, q));
  for (const auto& bad : {huge_position, long_quaternion, fsr}) {
    manager_->onDeviceState(bad, now_ns_, kA);
    chunk.push_back(bad);
  }
  seq_ += 3;
  const std::size_t hands = out_.hands.size();
  const Vec3 before(out_.hands.back().mcp_angles_rad[0], out_.hands.back().mcp_angles_rad[1],
                    out_.hands.back().mcp_angles_rad[2]);
  for (std::size_t at = 0; at < chunk.size(); at += 200) {
    sendChunk(session_,
              {chunk.begin() + static_cast<std::ptrdiff_t>(at),
               chunk.begin() + static_cast<std::ptrdiff_t>(std::min(chunk.size(), at + 200))},
              kA);
  }
  EXPECT_EQ(manager_->stats().nonfinite_samples, 3u);
  EXPECT_EQ(manager_->stats().refused, 0u) << "implausible is not refused: it is kept, flagged";
  // The hand goes on with the next good samples and never took the bad ones.
  moveToDeg(20.0);
  ASSERT_GT(out_.hands.size(), hands + 50);
  for (std::size_t i = hands; i < out_.hands.size(); ++i) {
    const auto& h = out_.hands[i];
    EXPECT_TRUE(h.device_seq < bad_first || h.device_seq >= bad_first + 3) << h.device_seq;
    for (int k = 0; k < 2; ++k) {
      for (int j = 0; j < 3; ++j) EXPECT_LT(std::abs(h.sphere_m[k][j]), 0.5);
    }
  }
  EXPECT_NEAR(radToDeg(before[kFlexion]), 10.0, 1.0);
  EXPECT_NEAR(radToDeg(out_.hands.back().mcp_angles_rad[kFlexion]), 20.0, 1.0);
  // Stored as they came, flagged invalid, and named.
  const Stored s = stored(session_);
  EXPECT_EQ(s.rows, bad_first + 2);
  EXPECT_EQ(s.invalid, 3u);
  EXPECT_EQ(store_->session(session_)->rejected, 3u);
  std::string named;
  for (const auto* e : out_.eventsOf(telehand_msg_EVENT_ERROR))
    named += std::string(e->text) + "\n";
  EXPECT_THAT(named, HasSubstr("implausible fingers[0] (thumb).position_m[1] = 1e+308"));
}

TEST_F(OwnershipTest, EndedSessionsAreRetiredAfterStatusKeep) {
  const auto [first, second] = twoOpenedTheFirstClosed();
  ASSERT_NE(first, 0u);
  ASSERT_NE(second, 0u);
  EXPECT_EQ(manager_->activeSessions(), 1u);
  tickFor(1'900'000'000);
  EXPECT_TRUE(out_.retired.empty()) << "late joiners still see how it ended";
  tickFor(200'000'000);
  EXPECT_EQ(out_.retired, std::vector<uint64_t>{first});
  EXPECT_EQ(manager_->stats().retired_sessions, 1u);
  // The other session, left without data, is abandoned after 30 s and retired 2 s later.
  tickFor(SessionManager::kIdleTimeoutNs);
  EXPECT_EQ(manager_->activeSessions(), 0u);
  EXPECT_EQ(store_->session(second)->state, "abandoned");
  tickFor(2'100'000'000);
  EXPECT_EQ(out_.retired, (std::vector<uint64_t>{first, second}));
  EXPECT_EQ(manager_->stats().retired_sessions, 2u);
  tickFor(5'000'000'000);
  EXPECT_EQ(out_.retired.size(), 2u) << "each once";
}

#if defined(__GLIBC__)
// When the last session has been retired, what the link keeps for reuse (Cyclone's pooled
// samples and spare history nodes) is given back, and half a second later, once Cyclone's
// collector has freed what that let go, what came back since: not while a session is open
// or waiting to be retired, and once.
TEST_F(OwnershipTest, WhatTheLinkKeepsForReuseIsGivenBackOnceTheLastSessionIsRetired) {
  const auto [first, second] = twoOpenedTheFirstClosed();
  ASSERT_NE(first, 0u);
  ASSERT_NE(second, 0u);
  tickFor(2'100'000'000);
  ASSERT_EQ(out_.retired, std::vector<uint64_t>{first});
  EXPECT_EQ(out_.idles, 0) << "a session is still open";
  session_ = second;
  close();
  for (int i = 0; i < 1000 && out_.retired.size() < 2; ++i) tickFor(10'000'000);
  ASSERT_EQ(out_.retired, (std::vector<uint64_t>{first, second}));
  EXPECT_EQ(out_.idles, 1);
  EXPECT_EQ(out_.settles, 0);
  tickFor(400'000'000);
  EXPECT_EQ(out_.settles, 0) << "the collector's half second has not passed";
  tickFor(200'000'000);
  EXPECT_EQ(out_.settles, 1);
  tickFor(5'000'000'000);
  EXPECT_EQ(out_.idles, 1) << "once";
  EXPECT_EQ(out_.settles, 1) << "once";
}
#endif

// A client's backlog that comes after its CLOSE a chunk at a time, each within a grace of
// the one before (a resume on a loaded server), is waited for past the first grace.
TEST_F(OwnershipTest, AClosingSessionWaitsWhileItsBacklogKeepsComing) {
  ASSERT_NE(open("healthy"), 0u);
  moveToDeg(5.0);
  const uint64_t sent = seq_ - 1;
  ASSERT_GT(sent, 300u);
  command(telehand_msg_CMD_CLOSE, kA, sent);
  const auto grace = static_cast<int64_t>(config_.close_grace_s * 1e9);
  int64_t waited = 0;
  for (uint64_t next = 0; next < sent; next += 100) {
    now_ns_ += grace * 4 / 5;
    waited += grace * 4 / 5;
    manager_->tick(now_ns_);
    ASSERT_EQ(manager_->activeSessions(), 1u)
        << "closed after " << static_cast<double>(waited) * 1e-9 << " s";
    sendRange(session_, next, std::min<uint64_t>(100, sent - next), kA);
  }
  ASSERT_GT(waited, 2 * grace);
  manager_->tick(now_ns_);
  ASSERT_EQ(manager_->activeSessions(), 0u);
  EXPECT_EQ(store_->session(session_)->state, "closed");
  EXPECT_EQ(stored(session_).rows, sent);
}

// While it waits, a closing session goes on acknowledging what its record holds (as
// CLOSING), at least once a second: its client neither takes the silence for a server that
// went away nor gives up on a close that progresses.
TEST_F(OwnershipTest, AClosingSessionAcknowledgesItsBacklogAsItComes) {
  ASSERT_NE(open("healthy"), 0u);
  moveToDeg(5.0);
  const uint64_t sent = seq_ - 1;
  command(telehand_msg_CMD_CLOSE, kA, sent);
  const auto closing = [&] {
    std::vector<telehand_msg_SessionStatus> v;
    for (const auto& st : out_.statuses) {
      if (st.session_id == session_ && st.state == telehand_msg_SESSION_CLOSING) v.push_back(st);
    }
    return v;
  };
  ASSERT_EQ(closing().size(), 1u) << "the CLOSE's own";
  for (int i = 0; i < 30; ++i) {  // 3 s of nothing: heartbeats
    now_ns_ += 100'000'000;
    manager_->tick(now_ns_);
  }
  ASSERT_EQ(manager_->activeSessions(), 1u);
  EXPECT_GE(closing().size(), 3u);
  EXPECT_LE(closing().size(), 5u);
  EXPECT_EQ(closing().back().stored_below, 0u);
  sendRange(session_, 1, 100, kA);  // sequence numbers from 1: 0 was never sent
  sendRange(session_, 0, 1, kA);
  now_ns_ += 600'000'000;
  manager_->tick(now_ns_);
  ASSERT_EQ(manager_->activeSessions(), 1u);
  EXPECT_EQ(closing().back().stored_below, 101u);
  EXPECT_EQ(closing().back().samples_recorded, 101u);
}

// A client that keeps sending (the same samples over and over) cannot hold its session open
// for ever: it closes kMaxCloseGraces graces after the CLOSE, incomplete.
TEST_F(OwnershipTest, AClosingSessionsWaitForItsBacklogIsBounded) {
  const int64_t grace = closeGraceNs();
  const int64_t waited =
      closeWhileSending([&] { sendRange(session_, 1, 1, kA); }, grace / 2, 100 * grace);
  EXPECT_EQ(manager_->activeSessions(), 0u);
  EXPECT_GT(waited, grace);
  EXPECT_LE(waited, SessionManager::kMaxCloseGraces * grace + grace / 2);
  EXPECT_EQ(store_->session(session_)->state, "incomplete");
}

// Chunks from someone else do not put a closing session's end off.
TEST_F(OwnershipTest, ARoguesChunksDoNotHoldAClosingSessionOpen) {
  const int64_t grace = closeGraceNs();
  const int64_t waited = closeWhileSending([&] { sendRange(session_, 1, 100, kB, kRogueVersion); },
                                           grace / 4, 4 * grace);
  EXPECT_EQ(manager_->activeSessions(), 0u);
  EXPECT_LE(waited, grace + grace / 4);
  EXPECT_EQ(store_->session(session_)->state, "incomplete");
  EXPECT_EQ(stored(session_).from_rogue, 0u);
}

TEST_F(OwnershipTest, LateChunksOfAnEndedSessionAreTakenFromItsOwnerOnly) {
  lateChunksAreTakenFromTheOwnerOnly(false);
}

}  // namespace
}  // namespace telehand::server::session

namespace telehand::server::session {
namespace {

// Recovery (docs/recovery.md): the record's stored prefix acknowledged to the client, a
// session suspended by a server that stops, recovered by the next one and resumed by its
// owner (no one else) under the same id, and one nobody resumes closed as interrupted with
// `missing` counting what the record lacks.
class RecoveryManagerTest : public SessionManagerTest {
 protected:
  void chunk(uint64_t first, uint64_t count) {
    std::vector<telehand_msg_DeviceState> samples(count);
    for (uint64_t i = 0; i < count; ++i) {
      samples[i].session_id = session_;
      samples[i].seq = first + i;
      samples[i].source_time_ns = now_ns_ + static_cast<int64_t>(i) * 1'000'000;
      telehand::test::setGrip(samples[i], *grip_model_, Vec3::Zero());
    }
    telehand_msg_RecordChunk c{};
    c.session_id = session_;
    borrowSamples(c, samples);
    manager_->onChunk(c, now_ns_, from_);
  }
  void pass(int64_t ms) {
    for (int64_t i = 0; i < ms; i += 10) {
      now_ns_ += 10'000'000;
      manager_->tick(now_ns_);
    }
  }
  uint64_t lastStoredBelow() const {
    for (auto it = out_.statuses.rbegin(); it != out_.statuses.rend(); ++it) {
      if (it->session_id == session_) return it->stored_below;
    }
    return 0;
  }
  /// The same record, served by a server started afresh.
  void restartServer() {
    manager_.reset();
    manager_ = std::make_unique<SessionManager>(*store_, out_, config_, &hand());
  }
};

TEST_F(RecoveryManagerTest, ASuspendedSessionIsResumedByItsOwnerWithWhatTheRecordHolds) {
  from_.participant = 11;
  from_.guid = "0000aaaa";
  ASSERT_NE(open("healthy"), 0u);
  chunk(0, 100);
  chunk(200, 100);  // a chunk still on its way: the prefix stops at the gap
  pass(600);
  EXPECT_EQ(lastStoredBelow(), 100u);
  chunk(100, 100);
  pass(600);
  EXPECT_EQ(lastStoredBelow(), 300u);

  // The server stops: nothing is closed, the session waits in the record.
  manager_->closeAll(now_ns_);
  EXPECT_EQ(out_.statuses.back().state, telehand_msg_SESSION_SUSPENDED);
  EXPECT_EQ(store_->session(session_)->state, "suspended");

  restartServer();
  EXPECT_EQ(manager_->recoverFromStore(now_ns_), 1u);
  EXPECT_EQ(manager_->suspendedSessions(), 1u);
  EXPECT_EQ(out_.statuses.back().state, telehand_msg_SESSION_SUSPENDED);

  // Someone else asks to resume it: refused, counted.
  auto c = command(telehand_msg_CMD_OPEN, session_);
  c.request_seq = 9;
  const Origin stranger{12, "0000bbbb", ""};
  const std::size_t before = out_.statuses.size();
  manager_->onCommand(c, now_ns_, stranger);
  EXPECT_EQ(out_.statuses.size(), before);
  EXPECT_EQ(manager_->stats().refused, 1u);
  EXPECT_EQ(manager_->activeSessions(), 0u);

  // Its owner does: the same id, answered with what the record holds, and a model.
  const std::size_t models = out_.models.size();
  manager_->onCommand(c, now_ns_, from_);
  ASSERT_EQ(manager_->activeSessions(), 1u);
  const auto& st = out_.statuses.back();
  EXPECT_EQ(st.session_id, session_);
  EXPECT_EQ(st.state, telehand_msg_SESSION_ACTIVE);
  EXPECT_EQ(st.client_id, c.client_id);
  EXPECT_EQ(st.request_seq, 9u);
  EXPECT_EQ(st.stored_below, 300u);
  EXPECT_EQ(st.samples_recorded, 300u);
  EXPECT_GT(out_.models.size(), models);
  EXPECT_EQ(manager_->suspendedSessions(), 0u);
  EXPECT_EQ(store_->session(session_)->state, "active");

  // The client sends what it kept (again, in part) and the rest; it closes: whole.
  chunk(250, 150);
  auto close = command(telehand_msg_CMD_CLOSE, session_);
  close.samples_sent = 400;
  manager_->onCommand(close, now_ns_, from_);
  pass(20);
  const auto info = store_->session(session_);
  EXPECT_EQ(info->state, "closed");
  EXPECT_EQ(info->samples, 400u);
  EXPECT_EQ(out_.statuses.back().samples_missing, 0u);
  bool resumed = false;
  for (const auto& e : store_->events(session_)) resumed |= e.text.starts_with("resumed: ");
  EXPECT_TRUE(resumed);
}

TEST_F(RecoveryManagerTest, ASessionNobodyResumesIsClosedAsInterruptedCountingWhatIsMissing) {
  ASSERT_NE(open("healthy"), 0u);
  chunk(0, 100);
  chunk(150, 50);  // 100..149 never arrive
  pass(20);
  config_.resume_wait_s = 1.0;
  restartServer();  // the server died: the record still says active
  // On a record shared by several servers an active session may be another's: left alone.
  EXPECT_EQ(manager_->recoverFromStore(now_ns_, false), 0u);
  EXPECT_EQ(store_->session(session_)->state, "active");
  EXPECT_EQ(manager_->recoverFromStore(now_ns_), 1u);
  pass(900);
  EXPECT_EQ(store_->session(session_)->state, "suspended");
  pass(200);
  const auto info = store_->session(session_);
  EXPECT_EQ(info->state, "interrupted");
  EXPECT_EQ(info->samples, 150u);
  EXPECT_EQ(info->samples_expected, 200u);  // 50 below the last stored one are missing
  EXPECT_EQ(out_.statuses.back().state, telehand_msg_SESSION_CLOSED);
  EXPECT_EQ(out_.statuses.back().samples_missing, 50u);
  // Too late now: a resume is refused by name.
  manager_->onCommand(command(telehand_msg_CMD_OPEN, session_), now_ns_, from_);
  EXPECT_EQ(manager_->activeSessions(), 0u);
  const auto errors = out_.eventsOf(telehand_msg_EVENT_ERROR);
  ASSERT_FALSE(errors.empty());
  EXPECT_THAT(std::string(errors.back()->text),
              AllOf(HasSubstr("cannot resume session " + std::to_string(session_)),
                    HasSubstr("interrupted")));
}

TEST_F(SessionManagerTest, TheHandsStepWithinTheirShareOfTheServingThread) {
  // A 1 ms slice within a quarter of the thread, a hand that cannot keep up: once the hands
  // have spent their budget the loop is told to sleep, a tick before then steps nothing, and
  // after it the hands step again.
  manager_->setHandSlice(1'000'000);
  manager_->setHandShare(0.25);
  EXPECT_THROW(manager_->setHandShare(0.0), telehand::ConfigError);
  EXPECT_THROW(manager_->setHandShare(1.5), telehand::ConfigError);
  EXPECT_EQ(manager_->handWaitNs(SteadyClock{}.nowNs()), -1);  // no session, no hand waiting
  ASSERT_NE(open("healthy"), 0u);
  int i = 0;
  auto feed = [&](int n) {
    for (int k = 0; k < n; ++k, ++i) {
      const telehand_msg_DeviceState d = pinchSample(i);
      manager_->onDeviceState(d, now_ns_, from_);
      now_ns_ += 1'000'000;
    }
  };
  SteadyClock clock;
  feed(100);
  EXPECT_EQ(manager_->handWaitNs(clock.nowNs()), 0);  // a whole slice before the first
  // Ticks back to back with samples arriving faster than the hand steps them.
  int64_t wait = 0;
  int ticks = 0;
  for (; ticks < 1000 && wait <= 0; ++ticks) {
    feed(50);
    manager_->tick(now_ns_);
    wait = manager_->handWaitNs(clock.nowNs());
  }
  ASSERT_GT(wait, 0) << "the budget never ran out in " << ticks << " ticks";
  EXPECT_LT(wait, 100'000'000);  // at most the slice and one sample over it, times 4
  const uint64_t steps = manager_->stats().hand_steps;
  EXPECT_GT(steps, 0u);
  EXPECT_GT(manager_->stats().hand_samples_skipped, 0u);  // the hand stepped over samples
  const int64_t asked = clock.nowNs();
  const int64_t held = manager_->handWaitNs(asked);
  manager_->tick(now_ns_);
  if (clock.nowNs() < asked + held) {
    EXPECT_EQ(manager_->stats().hand_steps, steps);
  }
  std::this_thread::sleep_for(std::chrono::nanoseconds(held));
  EXPECT_EQ(manager_->handWaitNs(clock.nowNs()), 0);
  manager_->tick(now_ns_);
  EXPECT_GT(manager_->stats().hand_steps, steps);
}

}  // namespace
}  // namespace telehand::server::session

namespace telehand::server::session {
namespace {

TEST(ServeWatchTest, ALoopThatHandlesNothingForTheStallTimeIsWedged) {
  // The pool's lease is renewed while the serve loop gets on (docs/pool.md): a counter that
  // stands still for longer than the stall time stops the renewals; one that moves again
  // starts them again.
  ServeWatch watch(5'000'000'000);
  EXPECT_TRUE(watch.alive(7, 1'000'000'000));
  EXPECT_TRUE(watch.alive(7, 6'000'000'000));  // 5 s still: not yet
  EXPECT_EQ(watch.idleNs(6'000'000'000), 5'000'000'000);
  EXPECT_FALSE(watch.alive(7, 6'000'000'001));
  EXPECT_FALSE(watch.alive(7, 60'000'000'000));
  EXPECT_TRUE(watch.alive(8, 60'000'000'001));  // handled something: alive again
  EXPECT_EQ(watch.idleNs(60'000'000'001), 0);
  EXPECT_TRUE(watch.alive(9, 64'000'000'000));
  EXPECT_FALSE(watch.alive(9, 69'000'000'001));
}

// A server of a pool that stops writes its sessions' state (suspended, for their clients
// to resume elsewhere), but not over a session another server took over while this one's
// lease had run out and before its next heartbeat told it so: that session is the other
// server's, and stays as that server holds it.
TEST_F(SessionManagerTest, AStoppingPoolServerLeavesWhatAnotherServerTookOver) {
  manager_->joinPool("a");
  const uint64_t kept = open("healthy");
  ASSERT_NE(kept, 0u);
  hold(20);
  const uint64_t taken = open("stiff");
  ASSERT_NE(taken, 0u);
  ASSERT_NE(taken, kept);
  hold(20);
  // The lease runs on the record's clock (the host's for SQLite): let it run out.
  std::this_thread::sleep_for(std::chrono::nanoseconds(SessionManager::kPoolLeaseNs) +
                              std::chrono::milliseconds(200));
  SqliteStore other(config_.db_path);
  other.poolHeartbeat("b", 0, SessionManager::kPoolLeaseNs);
  ASSERT_TRUE(other.poolClaim(taken, "b").won);
  manager_->closeAll(now_ns_);
  EXPECT_EQ(store_->poolOwner(taken), "b");
  EXPECT_EQ(store_->session(taken)->state, "active") << "not written over";
  EXPECT_EQ(store_->poolOwner(kept), "a");
  EXPECT_EQ(store_->session(kept)->state, "suspended");
}

// Server a's lease lapsed while it finished a session: b took the session over (suspended,
// waiting for its client), then a's close landed. When nobody resumes it, b leaves a's close
// and its client's count as they are, rather than closing the record as interrupted.
TEST_F(SessionManagerTest, ASessionClosedByItsPoolServerAfterATakeOverStaysClosed) {
  SqliteStore a(config_.db_path);
  a.poolHeartbeat("a", 1, SessionManager::kPoolLeaseNs);
  SessionInfo info;
  info.user = "student";
  info.case_name = "healthy";
  info.mode = "mobilization";
  info.state = "active";
  info.started_ns = wallNs();
  const uint64_t x = a.createSession(info);
  ASSERT_TRUE(a.poolClaim(x, "a").won);
  std::this_thread::sleep_for(std::chrono::nanoseconds(SessionManager::kPoolLeaseNs) +
                              std::chrono::milliseconds(200));
  manager_->joinPool("b");
  manager_->tick(now_ns_);  // b's beat: a's lease ran out, x is b's
  ASSERT_EQ(store_->poolOwner(x), "b");
  ASSERT_EQ(store_->session(x)->state, "suspended");
  a.closeSession(x, wallNs(), 5, "closed");
  now_ns_ += 3600 * kNsPerS;  // nobody resumes it
  manager_->tick(now_ns_);
  const auto after = store_->session(x);
  ASSERT_TRUE(after.has_value());
  EXPECT_EQ(after->state, "closed");
  EXPECT_EQ(after->samples_expected, 5u);
}

// Server a's lease lapsed and b took a running session over: a resume that reaches a first is
// not answered by a (it lets the session go), so the client binds to b alone.
TEST_F(SessionManagerTest, AResumeOfASessionAnotherPoolServerTookOverIsNotAnsweredHere) {
  manager_->joinPool("a");
  const uint64_t x = open("healthy");
  ASSERT_NE(x, 0u);
  hold(20);
  std::this_thread::sleep_for(std::chrono::nanoseconds(SessionManager::kPoolLeaseNs) +
                              std::chrono::milliseconds(200));
  SqliteStore b(config_.db_path);
  b.poolHeartbeat("b", 0, SessionManager::kPoolLeaseNs);
  ASSERT_TRUE(b.poolClaim(x, "b").won);
  const std::size_t before = out_.statuses.size();
  auto resume = command(telehand_msg_CMD_OPEN, x);
  manager_->onCommand(resume, now_ns_, from_);
  for (std::size_t i = before; i < out_.statuses.size(); ++i) {
    EXPECT_NE(out_.statuses[i].state, telehand_msg_SESSION_ACTIVE) << "answered for b's session";
  }
  EXPECT_EQ(manager_->activeSessions(), 0u);
  EXPECT_EQ(store_->poolOwner(x), "b");
}

TEST_F(SessionManagerTest, TheServeLoopsProgressCountsRoundsCommandsAndChunks) {
  const uint64_t p0 = manager_->progress();
  manager_->tick(now_ns_);
  EXPECT_EQ(manager_->progress(), p0 + 1);
  const uint64_t id = open("healthy");
  ASSERT_NE(id, 0u);
  EXPECT_GT(manager_->progress(), p0 + 1);
  const uint64_t p1 = manager_->progress();
  telehand_msg_RecordChunk chunk{};
  chunk.session_id = id;
  manager_->onChunk(chunk, now_ns_, from_);
  EXPECT_EQ(manager_->progress(), p1 + 1);
  // A live sample is no progress of its own: the round that took it counts.
  manager_->onDeviceState(pinchSample(0), now_ns_, from_);
  EXPECT_EQ(manager_->progress(), p1 + 1);
}

}  // namespace
}  // namespace telehand::server::session

namespace telehand::server::session {
namespace {

/// An SQLite record that counts the rows it is asked to write.
class CountingStore : public SqliteStore {
 public:
  using SqliteStore::SqliteStore;
  uint64_t appendSamples(uint64_t session_id, std::span<const Sample> samples,
                         std::span<const uint8_t> valid) override {
    written += samples.size();
    return SqliteStore::appendSamples(session_id, samples, valid);
  }
  uint64_t written = 0;
};

std::vector<Sample> run(uint64_t session_id, uint64_t first, uint64_t end) {
  std::vector<Sample> v;
  for (uint64_t q = first; q < end; ++q) {
    Sample s{};
    s.session_id = session_id;
    s.seq = q;
    s.source_time_ns = static_cast<int64_t>(q) * 1'000'000;
    v.push_back(s);
  }
  return v;
}

/// A recorder's world: an SQLite record in a directory of the test's own, counting rows.
class RecorderTest : public ::testing::Test {
 protected:
  RecorderTest()
      : dir_(fs::path(::testing::TempDir()) /
             ("recorder-" + std::to_string(getpid()) + "-" +
              ::testing::UnitTest::GetInstance()->current_test_info()->name())),
        store_((fs::create_directories(dir_), (dir_ / "records.db").string())),
        id_(store_.createSession([] {
          store::SessionInfo info;
          info.user = "student";
          info.mode = "mobilization";
          info.state = "active";
          return info;
        }())),
        ctx_{store_, out_, config_, stats_,
             [](uint64_t, uint64_t, telehand_msg_EventKind, const std::string&, int64_t) {}} {}
  ~RecorderTest() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  fs::path dir_;
  CountingStore store_;
  uint64_t id_;
  RecordingOutbox out_;
  ServerConfig config_;
  ManagerStats stats_;
  SessionContext ctx_;
};

// A client sends again what was not acknowledged in time (its server stalled, or it resumed):
// what the record holds is not written again, what it lacks is, and every count stays right.
TEST_F(RecorderTest, WhatTheRecordHoldsIsNotWrittenAgain) {
  auto& store = store_;
  auto& ctx = ctx_;
  auto& stats = stats_;
  const uint64_t id = id_;
  Recorder r(id);
  const auto add = [&](uint64_t first, uint64_t end) {
    auto s = run(id, first, end);
    std::vector<uint8_t> valid(s.size(), 1);
    r.add(std::move(s), std::move(valid));
  };
  add(0, 100);
  r.flush(ctx);
  EXPECT_EQ(store.written, 100u);
  add(50, 150);  // half of it sent before
  r.flush(ctx);
  EXPECT_EQ(store.written, 150u);
  add(300, 310);  // beyond a gap
  r.flush(ctx);
  EXPECT_EQ(store.written, 160u);
  EXPECT_EQ(r.storedBelow(), 150u);
  add(300, 310);  // again, with the gap's samples
  add(150, 300);
  r.flush(ctx);
  EXPECT_EQ(store.written, 310u);
  EXPECT_EQ(r.recorded(), 310u);
  EXPECT_EQ(r.storedBelow(), 310u);
  EXPECT_EQ(stats.recorded_samples, 310u);
  EXPECT_EQ(store.session(id)->samples, 310u);
  // Taken on from the record (a resume): what it holds is known without a write.
  Recorder resumed(id);
  resumed.resumeFrom(310, 310);
  auto again = run(id, 290, 320);
  std::vector<uint8_t> valid(again.size(), 1);
  resumed.add(std::move(again), std::move(valid));
  resumed.flush(ctx);
  EXPECT_EQ(store.written, 320u);
  EXPECT_EQ(resumed.recorded(), 320u);
  EXPECT_EQ(store.session(id)->samples, 320u);
}

// Chunks with and without validity flags queued together: each sample keeps its own (a chunk
// without flags is all valid), and the one flagged invalid is the record's one rejected.
TEST_F(RecorderTest, ChunksWithAndWithoutFlagsKeepEachSamplesOwn) {
  auto& store = store_;
  auto& ctx = ctx_;
  const uint64_t id = id_;
  Recorder r(id);
  r.add(run(id, 0, 10), {});
  std::vector<uint8_t> valid(10, 1);
  valid[3] = 0;  // seq 13
  r.add(run(id, 10, 20), std::move(valid));
  r.add(run(id, 20, 30), {});
  r.flush(ctx);
  EXPECT_EQ(r.recorded(), 30u);
  EXPECT_EQ(store.session(id)->rejected, 1u);
  std::vector<uint64_t> invalid;
  store.forEachSample(id, [&](const Sample& s, bool ok) {
    if (!ok) invalid.push_back(s.seq);
  });
  EXPECT_EQ(invalid, std::vector<uint64_t>{13});
}

}  // namespace
}  // namespace telehand::server::session

namespace telehand::server::session {
namespace {

/// A writer's connection to the test's record that waits at a gate before each write, and
/// fails the writes it is told to.
struct WriteGate {
  std::mutex m;
  std::condition_variable cv;
  bool open = false;
  int fail_next = 0;
  int entered = 0;  // writes that reached the store
  int done = 0;     // writes that returned
};

class GatedWriter : public SqliteStore {
 public:
  GatedWriter(const std::string& path, std::shared_ptr<WriteGate> gate)
      : SqliteStore(path), gate_(std::move(gate)) {}
  std::vector<BatchResult> appendSampleBatches(std::span<const SampleBatch> batches) override {
    std::unique_lock lock(gate_->m);
    ++gate_->entered;
    gate_->cv.notify_all();
    gate_->cv.wait(lock, [&] { return gate_->open; });
    std::vector<BatchResult> out;
    if (gate_->fail_next > 0) {
      --gate_->fail_next;
      out.assign(batches.size(), {false, 0, "the record refused the write (test)"});
    } else {
      lock.unlock();
      out = SqliteStore::appendSampleBatches(batches);
      lock.lock();
    }
    ++gate_->done;
    gate_->cv.notify_all();
    return out;
  }

 private:
  std::shared_ptr<WriteGate> gate_;
};

/// A record whose samples a writer thread stores through a GatedWriter.
class GatedStore : public SqliteStore {
 public:
  GatedStore(const std::string& path, std::shared_ptr<WriteGate> gate)
      : SqliteStore(path), path_(path), gate_(std::move(gate)) {}
  std::unique_ptr<SessionStore> openWriter() override {
    return std::make_unique<GatedWriter>(path_, gate_);
  }

 private:
  std::string path_;
  std::shared_ptr<WriteGate> gate_;
};

/// A record that refuses every write of samples.
class RefusingStore : public SqliteStore {
 public:
  using SqliteStore::SqliteStore;
  std::vector<BatchResult> appendSampleBatches(std::span<const SampleBatch> batches) override {
    return std::vector<BatchResult>(batches.size(),
                                    {false, 0, "the record refused the write (test)"});
  }
};

class RefusingStoreTest : public RecoveryManagerTest {
 protected:
  void SetUp() override {
    RecoveryManagerTest::SetUp();
    manager_.reset();
    store_ = std::make_unique<RefusingStore>(config_.db_path);
    manager_ = std::make_unique<SessionManager>(*store_, out_, config_, &hand());
  }
};

// A client that does not say what it sent (samples_sent 0) gets no "closed" while samples it
// sent are held back from the record: the record refuses every write until the close's grace
// runs out, and the session ends incomplete.
TEST_F(RefusingStoreTest, ACloseWithoutACountIsNotCompleteWhileSamplesAreHeldBack) {
  ASSERT_NE(open("healthy"), 0u);
  chunk(0, 100);
  pass(10);
  ASSERT_GE(manager_->stats().store_errors, 1u);
  auto c = command(telehand_msg_CMD_CLOSE, session_);
  c.samples_sent = 0;
  manager_->onCommand(c, now_ns_, from_);
  pass(static_cast<int64_t>(config_.close_grace_s * 1000) + 1000);  // past the grace
  ASSERT_EQ(manager_->activeSessions(), 0u);
  const auto info = store_->session(session_);
  EXPECT_EQ(info->state, "incomplete");
  EXPECT_EQ(info->samples, 0u);
}

/// A record that refuses the first `refusals` closes of a session (an end time given).
class ClosingLateStore : public SqliteStore {
 public:
  using SqliteStore::SqliteStore;
  void closeSession(uint64_t session_id, int64_t ended_ns, uint64_t samples_expected,
                    const std::string& state) override {
    if (ended_ns != 0 && refusals > 0) {
      --refusals;
      throw StoreError("the record refused the close (test)");
    }
    SqliteStore::closeSession(session_id, ended_ns, samples_expected, state);
  }
  int refusals = 3;
};

class ClosingLateTest : public RecoveryManagerTest {
 protected:
  void SetUp() override {
    RecoveryManagerTest::SetUp();
    manager_.reset();
    store_ = std::make_unique<ClosingLateStore>(config_.db_path);
    manager_ = std::make_unique<SessionManager>(*store_, out_, config_, &hand());
  }
  /// A session of 100 samples, closed by its client (who says it sent 100).
  void recordAndClose() {
    ASSERT_NE(open("healthy"), 0u);
    chunk(0, 100);
    pass(600);
    manager_->onCommand(closeCommand(), now_ns_, from_);
  }
  telehand_msg_SessionCommand closeCommand() const {
    auto c = command(telehand_msg_CMD_CLOSE, session_);
    c.samples_sent = 100;
    c.last_seq = 99;
    return c;
  }
  bool closedPublished() const {
    return std::any_of(out_.statuses.begin(), out_.statuses.end(), [&](const auto& st) {
      return st.session_id == session_ && st.state == telehand_msg_SESSION_CLOSED;
    });
  }
};

// The record would not take the close: the client is not told CLOSED while the record still
// says active, the close (with the client's count) is tried again until the record takes it,
// and the client's CLOSE and resume meanwhile are not taken for a session unknown or lost.
TEST_F(ClosingLateTest, AFailedCloseIsTriedAgainAndClosedIsSaidOnlyOnceTheRecordHoldsIt) {
  ASSERT_NO_FATAL_FAILURE(recordAndClose());
  pass(100);
  ASSERT_EQ(manager_->activeSessions(), 0u);
  EXPECT_FALSE(closedPublished());
  EXPECT_EQ(store_->session(session_)->state, "active");
  const std::size_t errors = out_.events.size();
  manager_->onCommand(closeCommand(), now_ns_, from_);  // asked again: not "unknown session"
  for (std::size_t i = errors; i < out_.events.size(); ++i) {
    EXPECT_EQ(std::string(out_.events[i].text).find("unknown session"), std::string::npos)
        << out_.events[i].text;
  }
  auto again = command(telehand_msg_CMD_OPEN, session_);  // nor taken on again
  manager_->onCommand(again, now_ns_, from_);
  EXPECT_EQ(manager_->activeSessions(), 0u);
  EXPECT_EQ(store_->session(session_)->state, "active");
  pass(3500);  // three more refusals, a second apart, then the record takes it
  EXPECT_TRUE(closedPublished());
  const auto info = store_->session(session_);
  EXPECT_EQ(info->state, "closed");
  EXPECT_EQ(info->samples_expected, 100u);
  EXPECT_EQ(info->samples, 100u);
  EXPECT_EQ(out_.statuses.back().state, telehand_msg_SESSION_CLOSED);
  EXPECT_EQ(out_.statuses.back().samples_missing, 0u);
}

// While this server could not close the record, another closed it (a pool server that took
// the session over, its client resumed there): the owed close is dropped, not written over it.
TEST_F(ClosingLateTest, AnOwedCloseDoesNotOverwriteACloseMadeElsewhere) {
  static_cast<ClosingLateStore&>(*store_).refusals = 1'000'000;
  ASSERT_NO_FATAL_FAILURE(recordAndClose());
  pass(1500);
  ASSERT_EQ(manager_->activeSessions(), 0u);
  ASSERT_EQ(store_->session(session_)->state, "active");
  {
    SqliteStore elsewhere(config_.db_path);
    elsewhere.closeSession(session_, wallNs(), 140, "closed");
  }
  const std::size_t errors = manager_->stats().store_errors;
  pass(1500);
  EXPECT_EQ(manager_->stats().store_errors, errors) << "still trying to close it";
  const auto info = store_->session(session_);
  EXPECT_EQ(info->state, "closed");
  EXPECT_EQ(info->samples_expected, 140u);
  EXPECT_EQ(out_.statuses.back().state, telehand_msg_SESSION_CLOSED);
}

class WriterThreadTest : public RecoveryManagerTest {
 protected:
  void SetUp() override {
    RecoveryManagerTest::SetUp();
    manager_.reset();
    store_ = std::make_unique<GatedStore>(config_.db_path, gate_);
    manager_ = std::make_unique<SessionManager>(*store_, out_, config_, &hand());
    ASSERT_TRUE(manager_->writeSamplesOnThread());
  }
  void setGate(bool open) {
    std::lock_guard lock(gate_->m);
    gate_->open = open;
    gate_->cv.notify_all();
  }
  /// Waits (at most 10 s) until `pred` holds for the gate.
  template <class Pred>
  bool waitGate(Pred pred) {
    std::unique_lock lock(gate_->m);
    return gate_->cv.wait_for(lock, std::chrono::seconds(10), [&] { return pred(*gate_); });
  }
  /// Rounds of the serve loop, 10 ms of session time each, until `pred` or 10 s of wall time.
  template <class Pred>
  bool passUntil(Pred pred) {
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    while (!pred()) {
      if (std::chrono::steady_clock::now() > deadline) return false;
      pass(10);
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
    return true;
  }
  std::shared_ptr<WriteGate> gate_ = std::make_shared<WriteGate>();
};

// A record that takes its time (PostgreSQL shared by a pool on a busy machine): the serve loop
// goes on while the samples wait for it, they are acknowledged only once stored, a refused
// write is tried again with what came meanwhile, and the session closes complete.
TEST_F(WriterThreadTest, ASlowRecordHoldsUpTheAcknowledgementNotTheLoop) {
  ASSERT_NE(open("healthy"), 0u);
  chunk(0, 100);
  pass(10);  // handed over: the writer waits at the gate
  ASSERT_TRUE(waitGate([](const WriteGate& g) { return g.entered == 1; }));
  chunk(100, 100);
  const uint64_t progress = manager_->progress();
  pass(1000);  // a second of rounds, none of them held up by the write
  EXPECT_GE(manager_->progress(), progress + 100);
  EXPECT_EQ(lastStoredBelow(), 0u);
  EXPECT_EQ(store_->session(session_)->samples, 0u);
  {
    std::lock_guard lock(gate_->m);
    EXPECT_EQ(gate_->entered, 1);  // one write under way at a time
  }
  setGate(true);
  ASSERT_TRUE(passUntil([&] { return lastStoredBelow() == 200; }));
  EXPECT_EQ(store_->session(session_)->samples, 200u);
  EXPECT_EQ(manager_->stats().recorded_samples, 200u);

  {
    std::lock_guard lock(gate_->m);
    gate_->fail_next = 1;
  }
  chunk(200, 100);
  ASSERT_TRUE(passUntil([&] { return manager_->stats().store_errors == 1; }));
  chunk(300, 100);
  ASSERT_TRUE(passUntil([&] { return lastStoredBelow() == 400; }));
  EXPECT_EQ(store_->session(session_)->samples, 400u);
  EXPECT_EQ(manager_->stats().recorded_samples, 400u);

  auto c = command(telehand_msg_CMD_CLOSE, session_);
  c.samples_sent = 400;
  manager_->onCommand(c, now_ns_, from_);
  ASSERT_TRUE(passUntil([&] { return manager_->activeSessions() == 0; }));
  const auto info = store_->session(session_);
  EXPECT_EQ(info->state, "closed");
  EXPECT_EQ(info->samples, 400u);
}

// A close whose grace runs out while the record is still writing the session's last samples
// waits for that write: the session closes complete, not incomplete with samples on the way.
TEST_F(WriterThreadTest, ACloseWaitsForTheWriteOfItsLastSamples) {
  ASSERT_NE(open("healthy"), 0u);
  chunk(0, 100);
  auto c = command(telehand_msg_CMD_CLOSE, session_);
  c.samples_sent = 100;
  manager_->onCommand(c, now_ns_, from_);
  pass(10);
  ASSERT_TRUE(waitGate([](const WriteGate& g) { return g.entered == 1; }));
  pass(static_cast<int64_t>(config_.close_grace_s * 1000) + 1000);  // past the grace
  EXPECT_EQ(manager_->activeSessions(), 1u);
  setGate(true);
  ASSERT_TRUE(passUntil([&] { return manager_->activeSessions() == 0; }));
  const auto info = store_->session(session_);
  EXPECT_EQ(info->state, "closed");
  EXPECT_EQ(info->samples, 100u);
}

// A server that stops while a write is under way waits for it, stores what came meanwhile,
// and suspends the session with all of it in the record.
TEST_F(WriterThreadTest, AServerStoppingWaitsForTheWriteUnderWay) {
  ASSERT_NE(open("healthy"), 0u);
  chunk(0, 100);
  pass(10);
  ASSERT_TRUE(waitGate([](const WriteGate& g) { return g.entered == 1; }));
  chunk(100, 100);  // queued behind the write
  std::thread opener([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    setGate(true);
  });
  manager_->closeAll(now_ns_);
  opener.join();
  const auto info = store_->session(session_);
  EXPECT_EQ(info->samples, 200u);
  EXPECT_EQ(info->state, "suspended");
}

}  // namespace
}  // namespace telehand::server::session
