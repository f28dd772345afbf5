// Lessons on the server (docs/lessons.md): a lesson from a demonstration record, a student's
// run in phases (the guide published with the model, trials scored on the record), the
// replay of a record reproducing the live hand, and what the server refuses.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <cmath>
#include <filesystem>
#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "../../support/grip_sample.h"
#include "telehand/core/clock.h"
#include "telehand/core/error.h"
#include "telehand/protocol/lesson_plan.h"
#include "telehand/protocol/wire.h"
#include "telehand/server/lesson/lesson.h"
#include "telehand/server/session/replay.h"
#include "telehand/server/session/session.h"
#include "telehand/server/session/session_manager.h"
#include "telehand/server/sim/hand_model.h"
#include "telehand/server/store/sqlite_store.h"

namespace telehand::server::session {
namespace {

namespace fs = std::filesystem;
using store::SqliteStore;
using ::testing::HasSubstr;
using ::testing::Not;

const std::string kDeploy = TELEHAND_DEPLOY_DIR;

class Outbox final : public session::Outbox {
 public:
  void publish(const telehand_msg_SessionStatus& s) override { statuses.push_back(s); }
  void publish(const telehand_msg_JointModel& m) override { models.push_back(m); }
  void publish(const telehand_msg_HandState& h) override { hands.push_back(h); }
  void publish(const telehand_msg_SessionEvent& e) override { events.push_back(e); }
  void retire(uint64_t) override {}
  std::vector<std::string> textsOf(telehand_msg_EventKind kind, uint64_t session) const {
    std::vector<std::string> out;
    for (const auto& e : events) {
      if (e.kind == kind && e.session_id == session) out.emplace_back(e.text);
    }
    return out;
  }
  std::vector<telehand_msg_SessionStatus> statuses;
  std::vector<telehand_msg_JointModel> models;
  std::vector<telehand_msg_HandState> hands;
  std::vector<telehand_msg_SessionEvent> events;
};

const sim::HandModel& hand() {
  static const sim::HandModel model = sim::HandModel::load(kDeploy + "/hand/hand24.urdf");
  return model;
}

/// A clinician's (or student's) mobilization, as the loop would record it: the grip on the
/// phalanx at flexion angle(t), the applied force on the index pad.
struct Motion {
  double mean_n = 14.0, amp_n = 2.0, hz = 3.0;
  double flex_deg = 20.0, flex_amp_deg = 4.0;
  double force(double t) const { return mean_n + amp_n * std::sin(2 * M_PI * hz * t); }
  double flexion(double t) const {
    return degToRad(flex_deg + flex_amp_deg * std::sin(2 * M_PI * hz * t - 0.3));
  }
};

class LessonTest : public ::testing::Test {
 protected:
  void SetUp() override {
    static std::atomic<int> counter{0};
    dir_ = fs::temp_directory_path() /
           ("telehand-lesson-" + std::to_string(::getpid()) + "-" + std::to_string(counter++));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
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

  telehand_msg_SessionCommand command(telehand_msg_CommandKind kind, uint64_t session = 0) {
    telehand_msg_SessionCommand c{};
    c.client_id = 7;
    c.request_seq = ++request_seq_;
    c.kind = kind;
    c.session_id = session;
    copyString(c.case_name, "healthy");
    copyString(c.user, "student");
    copyString(c.text, "");
    return c;
  }

  /// Opens a session; 0 when the server refused it.
  uint64_t open(telehand_msg_SessionMode mode, uint64_t lesson = 0, uint64_t follow = 0) {
    auto c = command(telehand_msg_CMD_OPEN);
    c.mode = mode;
    c.lesson_id = lesson;
    c.follow_session = follow;
    const std::size_t before = out_.statuses.size();
    manager_->onCommand(c, now_ns_);
    if (out_.statuses.size() == before) return 0;
    return out_.statuses.back().session_id;
  }

  /// `ms` samples of `m` from sequence number `seq` on, live and into the record (as a
  /// client sends them), 1 ms apart; ticks every 10 ms.
  void stream(uint64_t session, const Motion& m, uint64_t seq, int ms) {
    const JointModel joint(healthyIndexMcp());
    std::vector<telehand_msg_DeviceState> chunk;
    for (int i = 0; i < ms; ++i) {
      const double t = static_cast<double>(seq + static_cast<uint64_t>(i)) * 1e-3;
      telehand_msg_DeviceState d{};
      d.session_id = session;
      d.seq = seq + static_cast<uint64_t>(i);
      d.source_time_ns = kT0 + static_cast<int64_t>(d.seq) * 1'000'000;
      d.model_version = 1;
      const Vec3 angles(m.flexion(t), 0.0, 0.0);
      telehand::test::setGrip(d, joint, angles);
      // The push on the index pad (normal force), at device scale.
      d.fingers[1].normal_n = static_cast<float>(m.force(t) * 0.25);
      manager_->onDeviceState(d, now_ns_);
      chunk.push_back(d);
      if (chunk.size() == 100) flush(session, chunk);
      now_ns_ += 1'000'000;
      if (now_ns_ % 10'000'000 == 0) manager_->tick(now_ns_);
    }
    flush(session, chunk);
  }
  void flush(uint64_t session, std::vector<telehand_msg_DeviceState>& chunk) {
    if (chunk.empty()) return;
    telehand_msg_RecordChunk c{};
    c.session_id = session;
    c.chunk_seq = chunk_seq_++;
    c.samples._buffer = chunk.data();
    c.samples._length = static_cast<uint32_t>(chunk.size());
    c.samples._maximum = c.samples._length;
    manager_->onChunk(c, now_ns_);
    chunk.clear();
  }
  void tickFor(int ms) {
    for (int i = 0; i < ms; i += 10) {
      now_ns_ += 10'000'000;
      manager_->tick(now_ns_);
    }
  }
  void phase(uint64_t session, const char* name, double value, uint64_t last_seq) {
    auto c = command(telehand_msg_CMD_PHASE, session);
    copyString(c.text, name);
    c.value = value;
    c.last_seq = last_seq;
    manager_->onCommand(c, now_ns_);
  }
  void close(uint64_t session, uint64_t sent) {
    auto c = command(telehand_msg_CMD_CLOSE, session);
    c.samples_sent = sent;
    c.last_seq = sent ? sent - 1 : 0;
    manager_->onCommand(c, now_ns_);
    tickFor(200);
  }
  /// A closed mobilization session of `ms` samples (8 deg of flexion back and forth): a record
  /// to replay; 0 if it could not be opened.
  uint64_t recordedMobilization(int ms) {
    const uint64_t live = open(telehand_msg_MODE_MOBILIZATION);
    if (live == 0) return 0;
    Motion m;
    m.flex_amp_deg = 8.0;
    stream(live, m, 0, ms);
    close(live, static_cast<uint64_t>(ms));
    return live;
  }
  /// A closed demonstration of `m` (6 s) and a lesson made from it.
  uint64_t demoLesson(const Motion& m, int guided = 1, int attempts = 2, bool takeover = false) {
    demo_ = open(telehand_msg_MODE_MOBILIZATION);
    EXPECT_NE(demo_, 0u);
    stream(demo_, m, 0, 6000);
    close(demo_, 6000);
    store::LessonInfo l;
    l.name = "test lesson";
    l.demo_session = demo_;
    l.case_name = "healthy";
    l.guided = guided;
    l.attempts = attempts;
    l.trial_s = 4.0;
    l.takeover = takeover;
    l.targets = lesson::encodeTargets(lesson::targetsFromRecord(*store_, demo_, 0.25));
    return store_->createLesson(l);
  }

  static constexpr int64_t kT0 = 1'700'000'000'000'000'000;
  fs::path dir_;
  ServerConfig config_;
  Outbox out_;
  std::unique_ptr<SqliteStore> store_;
  std::unique_ptr<SessionManager> manager_;
  uint32_t request_seq_ = 0;
  uint64_t chunk_seq_ = 0;
  uint64_t demo_ = 0;
  int64_t now_ns_ = 1'000'000'000;
};

TEST_F(LessonTest, TargetsComeFromTheDemonstrationRecord) {
  const Motion m;
  const uint64_t id = demoLesson(m);
  const auto l = store_->lesson(id);
  ASSERT_TRUE(l.has_value());
  const technique::Targets t = lesson::decodeTargets(l->targets);
  EXPECT_NEAR(t.frequency_hz, m.hz, 0.05);
  EXPECT_NEAR(t.force_peak_n, m.mean_n + m.amp_n, 0.3);
  EXPECT_NEAR(t.force_trough_n, m.mean_n - m.amp_n, 0.3);
  EXPECT_NEAR(t.path_period_s, 1.0 / m.hz, 0.01);
  ASSERT_EQ(t.path_rad.size(), static_cast<std::size_t>(GuideParams::kPoints));
  // The path spans the demonstration's flexion swing.
  double lo = 1e9, hi = -1e9;
  for (const Vec3& a : t.path_rad) {
    lo = std::min(lo, radToDeg(a[kFlexion]));
    hi = std::max(hi, radToDeg(a[kFlexion]));
  }
  EXPECT_NEAR(hi - lo, 2 * m.flex_amp_deg, 0.5);
  // The demonstration's own time in band and path error, which an attempt is scored against,
  // are kept with the rest.
  const technique::Targets derived = lesson::targetsFromRecord(*store_, demo_, 0.25);
  EXPECT_GT(derived.time_in_band, 0.5);
  EXPECT_NEAR(t.time_in_band, derived.time_in_band, 1e-9);
  EXPECT_GT(derived.path_error_deg, 0.0);
  EXPECT_NEAR(t.path_error_deg, derived.path_error_deg, 1e-9);
  // The record keeps what it was given (encode, decode, encode).
  EXPECT_EQ(lesson::encodeTargets(t), l->targets);
  // Targets without them (a damaged record) are refused, naming the key.
  for (const std::string key : {"time_in_band=", "path_error_deg="}) {
    std::string bad = l->targets;
    const auto at = bad.find(key);
    ASSERT_NE(at, std::string::npos) << key;
    bad.erase(at, bad.find(';', at) + 1 - at);
    try {
      lesson::decodeTargets(bad);
      ADD_FAILURE() << "accepted targets without " << key;
    } catch (const telehand::Error& e) {
      EXPECT_THAT(e.what(), HasSubstr(key.substr(0, key.size() - 1))) << e.what();
      EXPECT_THAT(e.what(), HasSubstr("lesson create")) << e.what();
    }
  }
}

// A student who moves on before the demonstration's end (their client's watch time ran out
// while the server replayed it slower than real time), or whose client closes mid-watch: the
// record says how much they saw, never that the demonstration ended.
TEST_F(LessonTest, AWatchPhaseEndedEarlySaysHowMuchOfTheDemonstrationWasSeen) {
  const Motion demo;
  const uint64_t lesson_id = demoLesson(demo, 1, 1);
  // A run that holds the finger, watches at `speed` for `ms`, then begins its guided trial:
  // its info events.
  auto watchFor = [&](uint64_t run, double speed, int ms) {
    stream(run, demo, 1, 200);
    phase(run, "watch", speed, 200);
    tickFor(ms);
    phase(run, "guided", 1.0, 200);
    return out_.textsOf(telehand_msg_EVENT_INFO, run);
  };
  const uint64_t run = open(telehand_msg_MODE_LESSON, lesson_id);
  ASSERT_NE(run, 0u);
  const auto infos = watchFor(run, 1.0, 1500);
  std::string cut;
  for (const auto& t : infos) {
    EXPECT_THAT(t, Not(HasSubstr("watch: the demonstration ended")));
    if (t.find("cut short") != std::string::npos) cut = t;
  }
  ASSERT_FALSE(cut.empty()) << ::testing::PrintToString(infos);
  EXPECT_THAT(cut, HasSubstr("of 6.0 s"));
  EXPECT_THAT(cut, HasSubstr("the guided phase began before it ended"));
  const double seen = std::stod(cut.substr(cut.find(" at ") + 4));
  EXPECT_GT(seen, 1.0) << cut;
  EXPECT_LT(seen, 2.0) << cut;
  // The event is in the record too, for whoever reads the run later.
  bool stored = false;
  for (const auto& e : store_->events(run)) stored = stored || e.text == cut;
  EXPECT_TRUE(stored) << cut;
  // A watch that ran to its end says so, and nothing about a cut.
  const uint64_t full = open(telehand_msg_MODE_LESSON, lesson_id);
  ASSERT_NE(full, 0u);
  const auto full_infos = watchFor(full, 2.0, 3500);
  bool ended = false;
  for (const auto& t : full_infos) {
    EXPECT_THAT(t, Not(HasSubstr("cut short")));
    ended = ended || t.find("watch: the demonstration ended") != std::string::npos;
  }
  EXPECT_TRUE(ended) << ::testing::PrintToString(full_infos);
  // A client that closes mid-watch: the record says so too, once.
  const uint64_t left = open(telehand_msg_MODE_LESSON, lesson_id);
  ASSERT_NE(left, 0u);
  stream(left, demo, 1, 200);
  phase(left, "watch", 1.0, 200);
  tickFor(1500);
  close(left, 200);
  std::vector<std::string> cuts;
  for (const auto& e : store_->events(left)) {
    EXPECT_THAT(e.text, Not(HasSubstr("watch: the demonstration ended")));
    if (e.text.find("cut short") != std::string::npos) cuts.push_back(e.text);
  }
  ASSERT_EQ(cuts.size(), 1u) << ::testing::PrintToString(cuts);
  EXPECT_THAT(cuts[0], HasSubstr("of 6.0 s"));
  EXPECT_THAT(cuts[0], HasSubstr("the session ended ("));
  EXPECT_THAT(cuts[0], HasSubstr(") before it did"));
  const double left_at = std::stod(cuts[0].substr(cuts[0].find(" at ") + 4));
  EXPECT_GT(left_at, 1.0) << cuts[0];
  EXPECT_LT(left_at, 2.0) << cuts[0];
}

TEST_F(LessonTest, ARunIsPlannedGuidedAndScoredFromTheRecord) {
  const Motion demo;
  const uint64_t lesson_id = demoLesson(demo, 1, 1);
  const uint64_t run = open(telehand_msg_MODE_LESSON, lesson_id);
  ASSERT_NE(run, 0u);
  // The plan travels with the OPEN's answer.
  std::string why;
  const auto plan = decodePlan(out_.statuses.back().lesson, &why);
  ASSERT_TRUE(plan.has_value()) << why << ": " << out_.statuses.back().lesson;
  EXPECT_EQ(plan->lesson_id, lesson_id);
  EXPECT_EQ(plan->guided, 1);
  EXPECT_EQ(plan->attempts, 1);
  EXPECT_NEAR(plan->frequency_hz, demo.hz, 0.05);
  EXPECT_NEAR(plan->demo_s, 6.0, 0.01);
  EXPECT_EQ(store_->sessionLesson(run), lesson_id);

  // The student holds the finger, then watches the demonstration (2x): its replay is this
  // session's HandState meanwhile, numbered on from the session's own.
  stream(run, demo, 1, 200);
  phase(run, "watch", 2.0, 200);
  tickFor(3500);
  EXPECT_THAT(out_.textsOf(telehand_msg_EVENT_INFO, run).back(),
              HasSubstr("watch: the demonstration ended"));
  uint64_t last_hand_seq = 0, hand_states = 0;
  bool ordered = true;
  for (const auto& h : out_.hands) {
    if (h.session_id != run) continue;
    ordered = ordered && (hand_states == 0 || h.seq > last_hand_seq);
    last_hand_seq = h.seq;
    ++hand_states;
  }
  EXPECT_TRUE(ordered) << "one sequence of HandStates across the watch phase";
  EXPECT_GT(hand_states, 300u);

  // Guided trial: the model carries the guide at full authority.
  phase(run, "guided", 1.0, 200);
  const auto guided = fromWire(out_.models.back(), nullptr);
  ASSERT_TRUE(guided.has_value());
  EXPECT_EQ(out_.models.back().session_id, run);
  EXPECT_DOUBLE_EQ(guided->guide.authority, 1.0);
  EXPECT_NEAR(guided->guide.period_s, 1.0 / demo.hz, 0.01);
  Motion worse = demo;
  worse.mean_n += 2.0;  // pushes 2 N harder, 0.5 Hz faster
  worse.hz += 0.5;
  stream(run, worse, 201, 4000);
  // The attempt: no guide; the guided trial (samples 201..4200) waits for its record.
  phase(run, "attempt", 0.0, 4200);
  EXPECT_DOUBLE_EQ(fromWire(out_.models.back(), nullptr)->guide.authority, 0.0);
  tickFor(500);
  const auto trials = store_->trials(run);
  ASSERT_EQ(trials.size(), 1u);
  EXPECT_EQ(trials[0].phase, "guided");
  EXPECT_EQ(trials[0].first_seq, 201u);
  EXPECT_EQ(trials[0].last_seq, 4200u);
  const auto fig = lesson::decodeFigures(trials[0].figures);
  EXPECT_NEAR(fig.at("peak_error_n"), 2.0, 0.2);
  EXPECT_NEAR(fig.at("frequency_error_hz"), 0.5, 0.05);
  EXPECT_EQ(fig.at("missing"), 0.0);
  const auto scores = out_.textsOf(telehand_msg_EVENT_SCORE, run);
  ASSERT_FALSE(scores.empty());
  EXPECT_THAT(scores.back(), HasSubstr("trial 1 (guided 100 %)"));
  // Every oscillation is scored too (3.5 per second over the 2 s after the settle).
  int oscillations = 0;
  for (const auto& s : scores) oscillations += s.find(" oscillation ") != std::string::npos;
  EXPECT_GE(oscillations, 5);

  // The attempt repeats the demonstration: a near-perfect score. Its trial ends with the
  // record at the close.
  stream(run, demo, 4201, 4000);
  // No more trials than the plan: a third is refused.
  phase(run, "attempt", 0.0, 8200);
  phase(run, "attempt", 0.0, 8200);
  EXPECT_THAT(out_.textsOf(telehand_msg_EVENT_ERROR, run).back(), HasSubstr("trials are done"));
  close(run, 8200);  // samples 1..8200
  const auto all = store_->trials(run);
  ASSERT_EQ(all.size(), 2u);
  EXPECT_EQ(all[1].phase, "attempt");
  EXPECT_GT(all[1].overall, all[0].overall);
  EXPECT_GT(all[1].overall, 90.0);
  EXPECT_THAT(out_.textsOf(telehand_msg_EVENT_SCORE, run).back(), HasSubstr("2 trials scored"));
}

TEST_F(LessonTest, BadLessonsAndPhasesAreRefusedWithAReason) {
  EXPECT_EQ(open(telehand_msg_MODE_LESSON, 99), 0u);
  EXPECT_THAT(out_.textsOf(telehand_msg_EVENT_ERROR, 0).back(), HasSubstr("no lesson 99"));
  // A damaged lesson row: its targets name what is wrong.
  store::LessonInfo bad;
  bad.demo_session = 1;
  bad.case_name = "healthy";
  bad.targets = "band_min_n=12;band_max_n=oops";
  const uint64_t id = store_->createLesson(bad);
  EXPECT_EQ(open(telehand_msg_MODE_LESSON, id), 0u);
  EXPECT_THAT(out_.textsOf(telehand_msg_EVENT_ERROR, 0).back(), HasSubstr("band_max_n"));

  const uint64_t plain = open(telehand_msg_MODE_MOBILIZATION);
  ASSERT_NE(plain, 0u);
  phase(plain, "guided", 1.0, 0);
  EXPECT_THAT(out_.textsOf(telehand_msg_EVENT_ERROR, plain).back(), HasSubstr("runs no lesson"));

  const uint64_t run = open(telehand_msg_MODE_LESSON, demoLesson(Motion{}));
  ASSERT_NE(run, 0u);
  phase(run, "dance", 0.0, 0);
  EXPECT_THAT(out_.textsOf(telehand_msg_EVENT_ERROR, run).back(), HasSubstr("a lesson knows"));
  phase(run, "guided", 7.0, 0);
  EXPECT_THAT(out_.textsOf(telehand_msg_EVENT_ERROR, run).back(), HasSubstr("authority"));
  phase(run, "attempt", 0.0, uint64_t{1} << 62);
  EXPECT_THAT(out_.textsOf(telehand_msg_EVENT_ERROR, run).back(), HasSubstr("beyond"));
  // Another participant's PHASE is refused (the run belongs to whoever opened it).
  {
    auto c = command(telehand_msg_CMD_OPEN);
    c.mode = telehand_msg_MODE_LESSON;
    c.lesson_id = store_->listLessons().back().id;  // the good one
    manager_->onCommand(c, now_ns_, Origin{11, "owner-guid", ""});
    const uint64_t owned = out_.statuses.back().session_id;
    auto p = command(telehand_msg_CMD_PHASE, owned);
    copyString(p.text, "guided");
    p.value = 1.0;
    const uint64_t refused = manager_->stats().refused;
    manager_->onCommand(p, now_ns_, Origin{12, "stranger-guid", ""});
    EXPECT_EQ(manager_->stats().refused, refused + 1);
    EXPECT_THAT(out_.textsOf(telehand_msg_EVENT_ERROR, owned).back(),
                HasSubstr("refused a PHASE from participant stranger-guid"));
  }
  EXPECT_EQ(open(telehand_msg_MODE_REPLAY, 0, 12345), 0u);
  EXPECT_THAT(out_.textsOf(telehand_msg_EVENT_ERROR, 0).back(), HasSubstr("no session 12345"));
}

// A lesson row whose settings no run can hold (a damaged or hostile record) is refused at the
// OPEN, naming the setting, rather than acknowledged with a plan the client refuses.
TEST_F(LessonTest, ALessonsSettingsFromTheRecordAreCheckedAtTheOpen) {
  const uint64_t good = demoLesson(Motion{});
  const auto base = store_->lesson(good);
  ASSERT_TRUE(base.has_value());
  auto refusedFor = [&](const std::function<void(store::LessonInfo&)>& spoil) {
    store::LessonInfo l = *base;
    spoil(l);
    const uint64_t id = store_->createLesson(l);
    EXPECT_EQ(open(telehand_msg_MODE_LESSON, id), 0u);
    return out_.textsOf(telehand_msg_EVENT_ERROR, 0).back();
  };
  EXPECT_THAT(refusedFor([](auto& l) { l.trial_s = 1e300; }), HasSubstr("trial_s"));
  EXPECT_THAT(refusedFor([](auto& l) { l.trial_s = -5; }), HasSubstr("trial_s"));
  EXPECT_THAT(refusedFor([](auto& l) { l.guided = 2'000'000'000; }), HasSubstr("guided"));
  EXPECT_THAT(refusedFor([](auto& l) { l.guided = -1; }), HasSubstr("guided"));
  EXPECT_THAT(refusedFor([](auto& l) { l.schedule = std::string(300, 'x'); }),
              HasSubstr("schedule"));
  EXPECT_THAT(refusedFor([](auto& l) { l.schedule = "terminal;guided=9"; }), HasSubstr("schedule"));
  // The good one still opens.
  EXPECT_NE(open(telehand_msg_MODE_LESSON, good), 0u);
}

// A trial shorter than the settling and one of the demonstration's periods has nothing to judge:
// it is not scored (an error event saying why), not recorded as a 0; nor is a trial that ended
// before any of its samples was sent.
TEST_F(LessonTest, ATrialTooShortToJudgeOrEmptyIsSaidNotScoredZero) {
  const Motion demo;  // 3 Hz: 2 s to settle and a 0.33 s period
  const uint64_t run = open(telehand_msg_MODE_LESSON, demoLesson(demo, 0, 3));
  ASSERT_NE(run, 0u);
  stream(run, demo, 0, 2200);     // samples 0..2199
  phase(run, "attempt", 0.0, 0);  // trial 1: samples 1..2200 (2.2 s)
  stream(run, demo, 2200, 1);
  phase(run, "attempt", 0.0, 2200);  // trial 1 ends; trial 2 begins at 2201
  phase(run, "attempt", 0.0, 2200);  // trial 2 ends before a sample of it: trial 3 begins
  tickFor(11000);
  const auto errors = out_.textsOf(telehand_msg_EVENT_ERROR, run);
  bool short_said = false, empty_said = false;
  for (const auto& e : errors) {
    short_said = short_said || (e.find("trial 1") != std::string::npos &&
                                e.find("not scored") != std::string::npos &&
                                e.find("needed") != std::string::npos);
    empty_said = empty_said || (e.find("trial 2") != std::string::npos &&
                                e.find("ended before a sample") != std::string::npos);
  }
  EXPECT_TRUE(short_said) << ::testing::PrintToString(errors);
  EXPECT_TRUE(empty_said) << ::testing::PrintToString(errors);
  EXPECT_TRUE(store_->trials(run).empty()) << "a trial with nothing to judge was recorded";
}

// A trial whose record lacks a stretch in its middle (samples the client never delivered) is
// scored on the stretches either side, about as the whole trial is, not 0; one with too little
// left to judge is not scored (an error event saying why), not recorded as a 0.
TEST_F(LessonTest, ATrialWithAGapIsScoredOnItsStretchesAndOneMostlyLostIsNotScored) {
  const Motion demo;  // 3 Hz: 2 s to settle and a 0.33 s period
  const uint64_t run = open(telehand_msg_MODE_LESSON, demoLesson(demo, 0, 4));
  ASSERT_NE(run, 0u);
  Motion student = demo;  // 1 N harder, 0.3 Hz faster
  student.mean_n += 1.0;
  student.hz += 0.3;
  phase(run, "attempt", 0.0, 0);
  stream(run, student, 0, 4001);
  phase(run, "attempt", 0.0, 4000);  // trial 1: samples 1..4000, whole
  stream(run, student, 4001, 1500);
  stream(run, student, 6501, 1500);  // 5501..6500 never arrive
  phase(run, "attempt", 0.0, 8000);  // trial 2: 8001 - 4001 samples, 1000 of them missing
  stream(run, student, 8001, 1900);
  stream(run, student, 11801, 200);   // 9901..11800 never arrive
  phase(run, "attempt", 0.0, 12000);  // trial 3: 1.9 s, then 0.2 s after a 1.9 s gap
  tickFor(11000);
  const auto trials = store_->trials(run);
  ASSERT_EQ(trials.size(), 2u) << "trials 1 and 2 scored, trial 3 not";
  EXPECT_EQ(trials[0].index, 1);
  EXPECT_EQ(trials[1].index, 2);
  EXPECT_EQ(lesson::decodeFigures(trials[0].figures).at("missing"), 0.0);
  EXPECT_EQ(lesson::decodeFigures(trials[1].figures).at("missing"), 1000.0);
  EXPECT_GT(trials[0].overall, 20.0);
  EXPECT_NEAR(trials[1].overall, trials[0].overall, 0.1 * trials[0].overall);
  const auto scores = out_.textsOf(telehand_msg_EVENT_SCORE, run);
  bool gap_said = false;
  for (const auto& e : scores) {
    gap_said = gap_said || (e.rfind("trial 2 (attempt): trial:", 0) == 0 &&
                            e.find("(1000 samples missing)") != std::string::npos);
  }
  EXPECT_TRUE(gap_said) << ::testing::PrintToString(scores);
  const auto errors = out_.textsOf(telehand_msg_EVENT_ERROR, run);
  bool lost_said = false;
  for (const auto& e : errors) {
    lost_said =
        lost_said || (e.rfind("trial 3 (attempt) not scored: none of its 2 stretches", 0) == 0 &&
                      e.find("(2100 of 4000 samples in the record)") != std::string::npos);
  }
  EXPECT_TRUE(lost_said) << ::testing::PrintToString(errors);
}

TEST_F(LessonTest, AMassageLessonRunsWithTheMassageOnlyAndRefusesTheJointsPhases) {
  technique::MassageTargets t;
  t.normal_mean_n = 10.0;
  t.normal_sd_n = 0.7;
  t.band_min_n = 8.6;
  t.band_max_n = 11.4;
  t.radius_m = 0.006;
  t.frequency_hz = 1.5;
  t.circularity = 1.0;
  t.laps = 12;
  store::LessonInfo l;
  l.demo_session = 1;
  l.case_name = "scar";
  l.technique = "massage";
  l.guided = 0;
  l.attempts = 2;
  l.assessment = false;
  l.targets = lesson::encodeMassageTargets(t);
  const uint64_t id = store_->createLesson(l);
  // A client that would mobilize is told how to open it.
  EXPECT_EQ(open(telehand_msg_MODE_LESSON, id), 0u);
  EXPECT_THAT(out_.textsOf(telehand_msg_EVENT_ERROR, 0).back(),
              HasSubstr("--technique massage --lesson " + std::to_string(id)));
  auto c = command(telehand_msg_CMD_OPEN);
  c.mode = telehand_msg_MODE_LESSON;
  c.lesson_id = id;
  c.technique = telehand_msg_TECHNIQUE_MASSAGE;
  manager_->onCommand(c, now_ns_);
  const auto& st = out_.statuses.back();
  ASSERT_EQ(st.state, telehand_msg_SESSION_ACTIVE);
  const uint64_t run = st.session_id;
  std::string why;
  const auto plan = decodePlan(st.lesson, &why);
  ASSERT_TRUE(plan) << why;
  EXPECT_EQ(plan->technique, "massage");
  EXPECT_EQ(plan->guided, 0);
  EXPECT_FALSE(plan->assessment);
  EXPECT_NEAR(plan->band_max_n, 11.4, 1e-3);
  // The web of the case is what the client renders.
  ASSERT_FALSE(out_.models.empty());
  EXPECT_EQ(out_.models.back().technique, telehand_msg_TECHNIQUE_MASSAGE);
  for (const char* joint_phase : {"baseline", "reassessment"}) {
    phase(run, joint_phase, 1.0, 0);
    EXPECT_THAT(out_.textsOf(telehand_msg_EVENT_ERROR, run).back(),
                HasSubstr("a massage lesson has no exploration"))
        << joint_phase;
  }
  // A guided trial leads round the demonstration's circle: the model the client gets carries a
  // guide whose path is the circle on the web, one lap per 1/1.5 s; an attempt takes it away.
  const std::size_t errors = out_.textsOf(telehand_msg_EVENT_ERROR, run).size();
  phase(run, "guided", 1.0, 0);
  EXPECT_EQ(out_.textsOf(telehand_msg_EVENT_ERROR, run).size(), errors);
  const auto& guided = out_.models.back();
  EXPECT_DOUBLE_EQ(guided.guide_authority, 1.0);
  EXPECT_NEAR(guided.guide_period_s, 1.0 / 1.5, 1e-12);
  for (int k = 0; k < GuideParams::kPoints; k += 16) {
    const double x = guided.guide_path_rad[k][0], y = guided.guide_path_rad[k][1];
    EXPECT_NEAR(std::hypot(x, y), 0.006, 1e-9) << k;
  }
  EXPECT_NEAR(guided.guide_path_rad[16][1], 0.006, 1e-9) << "counter-clockwise, as demonstrated";
  phase(run, "attempt", 0.0, 0);
  EXPECT_EQ(out_.textsOf(telehand_msg_EVENT_ERROR, run).size(), errors);
  EXPECT_DOUBLE_EQ(out_.models.back().guide_authority, 0.0);
}

TEST_F(LessonTest, AReplayReproducesTheLiveHandStates) {
  // A live session: every HandState published, by the sample it reflects.
  const uint64_t live = recordedMobilization(3000);
  ASSERT_NE(live, 0u);
  std::map<uint64_t, telehand_msg_HandState> seen;
  for (const auto& h : out_.hands) {
    if (h.session_id == live) seen[h.device_seq] = h;
  }
  ASSERT_GT(seen.size(), 200u);
  // The same record replayed by another server on the same record, publishing every
  // millisecond (so that every sample's state is seen), at half speed with a pause.
  ServerConfig every_ms = config_;
  every_ms.hand_state_hz = 1000.0;
  Outbox out;
  SessionManager other(*store_, out, every_ms, &hand());
  auto c = command(telehand_msg_CMD_OPEN);
  c.mode = telehand_msg_MODE_REPLAY;
  c.follow_session = live;
  other.onCommand(c, now_ns_);
  ASSERT_FALSE(out.statuses.empty());
  const uint64_t replay = out.statuses.back().session_id;
  auto control = [&](const char* what, double value) {
    auto p = command(telehand_msg_CMD_PHASE, replay);
    copyString(p.text, what);
    p.value = value;
    other.onCommand(p, now_ns_);
  };
  auto run = [&](int ms) {
    for (int i = 0; i < ms; ++i) {
      now_ns_ += 1'000'000;
      other.tick(now_ns_);
    }
  };
  control("speed", 0.5);
  run(1000);
  control("pause", 0.0);
  run(300);
  const std::size_t paused_at = out.hands.size();
  run(300);
  EXPECT_EQ(out.hands.size() - paused_at, 300u) << "paused: the same state again, every ms";
  control("play", 0.0);
  run(6000);
  std::size_t compared = 0;
  double worst = 0.0;
  uint64_t last_seq = 0;
  for (const auto& h : out.hands) {
    last_seq = std::max(last_seq, h.device_seq);
    const auto it = seen.find(h.device_seq);
    if (it == seen.end()) continue;
    ++compared;
    for (int i = 0; i < 3; ++i)
      worst = std::max(worst, std::abs(h.mcp_angles_rad[i] - it->second.mcp_angles_rad[i]));
    for (int j = 0; j < h.dof_count; ++j)
      worst = std::max(worst, std::abs(h.joint_angles_rad[j] - it->second.joint_angles_rad[j]));
  }
  EXPECT_GE(compared, seen.size()) << "every live state has its replayed twin";
  EXPECT_LE(worst, 1e-9) << "over " << compared << " states";
  EXPECT_EQ(last_seq, 2999u) << "the replay reached the record's end";
  // At its end the replay session closes by itself.
  EXPECT_EQ(out.statuses.back().session_id, replay);
  EXPECT_EQ(out.statuses.back().state, telehand_msg_SESSION_CLOSED);
}

/// A replay of `source` opened on a server of its own on the same record that publishes a
/// HandState every millisecond (every sample stepped is seen), driven 1 ms a tick.
class ReplayViewer {
 public:
  ReplayViewer(
      SqliteStore& store, const ServerConfig& config, uint64_t source, int64_t& now_ns,
      std::function<telehand_msg_SessionCommand(telehand_msg_CommandKind, uint64_t)> command)
      : config_(everyMs(config)),
        manager_(store, out, config_, &hand()),
        now_ns_(now_ns),
        command_(std::move(command)) {
    auto c = command_(telehand_msg_CMD_OPEN, 0);
    c.mode = telehand_msg_MODE_REPLAY;
    c.follow_session = source;
    manager_.onCommand(c, now_ns_);
    if (!out.statuses.empty()) id = out.statuses.back().session_id;
  }
  void control(const char* what, double value) {
    auto p = command_(telehand_msg_CMD_PHASE, id);
    copyString(p.text, what);
    p.value = value;
    manager_.onCommand(p, now_ns_);
  }
  void run(int ms) {
    for (int i = 0; i < ms; ++i) {
      now_ns_ += 1'000'000;
      manager_.tick(now_ns_);
    }
  }
  /// The device sample the latest HandState reflects.
  uint64_t lastDeviceSeq() const { return out.hands.empty() ? 0 : out.hands.back().device_seq; }
  bool closed() const {
    for (const auto& s : out.statuses) {
      if (s.session_id == id && s.state == telehand_msg_SESSION_CLOSED) return true;
    }
    return false;
  }
  Outbox out;
  uint64_t id = 0;

 private:
  static ServerConfig everyMs(ServerConfig c) {
    c.hand_state_hz = 1000.0;
    return c;
  }
  ServerConfig config_;
  SessionManager manager_;
  int64_t& now_ns_;
  std::function<telehand_msg_SessionCommand(telehand_msg_CommandKind, uint64_t)> command_;
};

TEST_F(LessonTest, AReplayStepsOverGapsInItsRecordAtOnce) {
  // A record whose sequence numbers lie far apart (its device's own doing: each chunk within
  // the window of the last, or chunks that came after the session ended): 100 samples, then
  // 10 more 600,000 apart and one at 2^62, a millisecond apart in time. Read a page of 1,000
  // sequence numbers at a time, the gaps would be 2^52 empty pages, a replay (or a lesson's
  // demonstration) that never ends; the replay steps over each gap at once and replays every
  // sample in the record's own time.
  const uint64_t live = recordedMobilization(100);
  ASSERT_NE(live, 0u);
  std::vector<Sample> last;
  store_->forEachSampleIn(live, 99, 99, [&](const Sample& s, bool) { last.push_back(s); });
  ASSERT_EQ(last.size(), 1u);
  std::vector<Sample> sparse;
  for (uint64_t k = 1; k <= 10; ++k) {
    Sample s = last[0];
    s.seq = 99 + k * 600'000;
    s.source_time_ns += static_cast<int64_t>(k) * 1'000'000;
    sparse.push_back(s);
  }
  Sample far = sparse.back();
  far.seq = uint64_t{1} << 62;
  far.source_time_ns += 1'000'000;
  sparse.push_back(far);
  store_->appendSamples(live, sparse, std::vector<uint8_t>(sparse.size(), 1));
  ReplayViewer v(*store_, config_, live, now_ns_,
                 [this](telehand_msg_CommandKind k, uint64_t s) { return command(k, s); });
  ASSERT_NE(v.id, 0u);
  v.run(200);  // the record's 111 ms and more
  EXPECT_TRUE(v.closed());
  EXPECT_EQ(v.lastDeviceSeq(), uint64_t{1} << 62);
  EXPECT_THAT(v.out.textsOf(telehand_msg_EVENT_INFO, v.id),
              ::testing::Contains(HasSubstr("the end of the record (111 samples replayed)")));
}

TEST_F(LessonTest, ALoopedReplayStartsOverAtItsEndWithTheSameStates) {
  const uint64_t live = recordedMobilization(2000);
  ASSERT_NE(live, 0u);
  ReplayViewer v(*store_, config_, live, now_ns_,
                 [this](telehand_msg_CommandKind k, uint64_t s) { return command(k, s); });
  ASSERT_NE(v.id, 0u);
  v.control("loop", 1.0);
  v.control("speed", 2.0);
  v.run(2500);  // 5 s of record at 2x: the 2 s record two and a half times
  EXPECT_FALSE(v.closed()) << "a looping replay does not end with its record";
  // The passes: the reflected sample runs up to the record's end, then from the start. The tick
  // that steps the last sample (1999) starts over at once, so the last state a pass shows is
  // within that tick's samples (2 at 2x) of it.
  std::vector<std::map<uint64_t, telehand_msg_HandState>> passes(1);
  uint64_t prev_seq = 0, prev_device = 0;
  bool ordered = true;
  for (const auto& h : v.out.hands) {
    if (h.session_id != v.id) continue;
    if (h.seq <= prev_seq && prev_seq != 0) ordered = false;
    prev_seq = h.seq;
    if (h.device_seq < prev_device) {
      EXPECT_GE(prev_device, 1997u) << "a pass starts over only at the record's end";
      passes.emplace_back();
    }
    prev_device = h.device_seq;
    passes.back()[h.device_seq] = h;
  }
  EXPECT_TRUE(ordered) << "the HandStates' own sequence goes on across the loops";
  ASSERT_EQ(passes.size(), 3u) << "two starts over in 5 s of a 2 s record";
  EXPECT_GE(passes[0].rbegin()->first, 1997u);
  EXPECT_GE(passes[1].rbegin()->first, 1997u);
  EXPECT_LT(passes[1].begin()->first, 5u) << "the second pass starts at the record's start";
  EXPECT_LT(passes[2].begin()->first, 5u);
  EXPECT_NEAR(static_cast<double>(passes[2].rbegin()->first), 1000.0, 10.0)
      << "half-way through the third pass";
  // Each pass on a fresh hand: the same states for the same samples.
  std::size_t compared = 0;
  double worst = 0.0;
  for (std::size_t p = 1; p < passes.size(); ++p) {
    for (const auto& [seq, h] : passes[p]) {
      const auto it = passes[0].find(seq);
      if (it == passes[0].end()) continue;
      ++compared;
      for (int i = 0; i < 3; ++i) {
        worst = std::max(worst, std::abs(h.mcp_angles_rad[i] - it->second.mcp_angles_rad[i]));
      }
      for (int j = 0; j < h.dof_count; ++j) {
        worst = std::max(worst, std::abs(h.joint_angles_rad[j] - it->second.joint_angles_rad[j]));
      }
    }
  }
  EXPECT_GT(compared, 1000u);
  EXPECT_LE(worst, 1e-9) << "over " << compared << " states";
  // Loop off: it plays to the end of the pass it is in and closes.
  v.control("loop", 0.0);
  v.run(600);
  EXPECT_TRUE(v.closed()) << "the end of the record, loop off";
  EXPECT_EQ(v.out.hands.back().device_seq, 1999u);
  // Every sample of the record stepped the hand in each of the three passes.
  EXPECT_THAT(v.out.textsOf(telehand_msg_EVENT_INFO, v.id),
              ::testing::Contains(HasSubstr("the end of the record (6000 samples replayed)")));
}

TEST_F(LessonTest, AReplaySpeedOutsideAQuarterToTwiceIsClampedAndNotANumberRefused) {
  const uint64_t live = open(telehand_msg_MODE_MOBILIZATION);
  ASSERT_NE(live, 0u);
  stream(live, Motion{}, 0, 4000);
  close(live, 4000);
  ReplayViewer v(*store_, config_, live, now_ns_,
                 [this](telehand_msg_CommandKind k, uint64_t s) { return command(k, s); });
  ASSERT_NE(v.id, 0u);
  // Record time played over `ms` of the server's time, from the samples reflected (1 ms apart).
  auto played = [&](int ms) {
    const uint64_t before = v.lastDeviceSeq();
    v.run(ms);
    return static_cast<double>(v.lastDeviceSeq() - before);
  };
  EXPECT_NEAR(played(200), 200.0, 3.0) << "1x at the start";
  v.control("speed", 10.0);
  EXPECT_NEAR(played(400), 800.0, 3.0) << "10x: 2x";
  v.control("speed", 0.5);
  EXPECT_NEAR(played(400), 200.0, 3.0) << "0.5x, within the range, as asked";
  v.control("speed", 0.01);
  EXPECT_NEAR(played(400), 100.0, 3.0) << "0.01x: 0.25x";
  v.control("speed", 0.0);
  EXPECT_NEAR(played(400), 100.0, 3.0) << "0x: 0.25x (a pause is 'pause')";
  v.control("speed", -2.0);
  EXPECT_NEAR(played(400), 100.0, 3.0) << "-2x: 0.25x (no playing backwards)";
  v.control("speed", 2.0);
  EXPECT_NEAR(played(200), 400.0, 3.0) << "2x, the top of the range";
  const std::size_t errors = v.out.textsOf(telehand_msg_EVENT_ERROR, v.id).size();
  v.control("speed", std::nan(""));
  v.control("speed", std::numeric_limits<double>::infinity());
  const auto refused = v.out.textsOf(telehand_msg_EVENT_ERROR, v.id);
  ASSERT_EQ(refused.size(), errors + 2) << "NaN and infinity refused";
  EXPECT_THAT(refused.back(), HasSubstr("the speed is not a number"));
  EXPECT_NEAR(played(200), 400.0, 3.0) << "the speed before them kept: 2x";
  EXPECT_FALSE(v.closed());
}

/// The flexion swing of a guide's path, degrees.
double pathSpanDeg(const GuideParams& g) {
  double lo = 1e9, hi = -1e9;
  for (const Vec3& a : g.path_rad) {
    lo = std::min(lo, radToDeg(a[kFlexion]));
    hi = std::max(hi, radToDeg(a[kFlexion]));
  }
  return hi - lo;
}

TEST_F(LessonTest, ATakeOverLeadsTheGuideFromTheSupervisorsLiveSession) {
  const Motion demo;  // 3 Hz, ±4 deg
  const uint64_t allowed = demoLesson(demo, 2, 1, /*takeover=*/true);
  const uint64_t run = open(telehand_msg_MODE_LESSON, allowed);
  ASSERT_NE(run, 0u);
  EXPECT_TRUE(decodePlan(out_.statuses.back().lesson)->takeover);
  // The supervisor at their own MF-2: 2 Hz, ±8 deg.
  Motion lead;
  lead.hz = 2.0;
  lead.flex_amp_deg = 8.0;
  const uint64_t sup = open(telehand_msg_MODE_MOBILIZATION);
  ASSERT_NE(sup, 0u);
  stream(sup, lead, 0, 4000);
  const Origin supervisor{21, "supervisor-guid", ""};
  auto takeover = [&](uint64_t session, uint64_t follow) {
    auto c = command(telehand_msg_CMD_TAKEOVER, session);
    c.follow_session = follow;
    manager_->onCommand(c, now_ns_, supervisor);
  };
  takeover(run, sup);
  EXPECT_THAT(out_.textsOf(telehand_msg_EVENT_INFO, run).back(),
              HasSubstr("participant supervisor-guid leads the guided trials from session " +
                        std::to_string(sup)));
  // The guided trial's guide is the supervisor's movement, not the demonstration's.
  stream(run, demo, 1, 200);
  phase(run, "guided", 1.0, 200);
  auto g = fromWire(out_.models.back(), nullptr);
  ASSERT_TRUE(g.has_value());
  EXPECT_EQ(out_.models.back().session_id, run);
  EXPECT_DOUBLE_EQ(g->guide.authority, 1.0);
  EXPECT_NEAR(g->guide.period_s, 1.0 / lead.hz, 0.01);
  EXPECT_NEAR(pathSpanDeg(g->guide), 2 * lead.flex_amp_deg, 0.8);
  EXPECT_THAT(
      out_.textsOf(telehand_msg_EVENT_INFO, run),
      ::testing::Contains(HasSubstr("the guide follows session " + std::to_string(sup) + ": 2.0")));
  // The supervisor changes rhythm; within a refresh or two the guide has followed.
  Motion faster = lead;
  faster.hz = 2.5;
  stream(sup, faster, 4000, 6000);
  g = fromWire(out_.models.back(), nullptr);
  EXPECT_NEAR(g->guide.period_s, 1.0 / faster.hz, 0.01);
  // Given back: the demonstration's path again, from the next guided trial on.
  takeover(run, 0);
  EXPECT_THAT(out_.textsOf(telehand_msg_EVENT_INFO, run).back(),
              HasSubstr("the guided trials follow the demonstration"));
  g = fromWire(out_.models.back(), nullptr);
  EXPECT_NEAR(g->guide.period_s, 1.0 / demo.hz, 0.01);
  EXPECT_NEAR(pathSpanDeg(g->guide), 2 * demo.flex_amp_deg, 0.5);

  // Refused, with the reason in the session's events.
  auto refusal = [&](uint64_t session) {
    const auto e = out_.textsOf(telehand_msg_EVENT_ERROR, session);
    return e.empty() ? std::string() : e.back();
  };
  takeover(sup, run);
  EXPECT_THAT(refusal(sup), HasSubstr("the session runs no lesson"));
  takeover(run, 424242);
  EXPECT_THAT(refusal(run), HasSubstr("session 424242 is not open"));
  takeover(run, run);
  EXPECT_THAT(refusal(run), HasSubstr("cannot lead itself"));
  const uint64_t other_run = open(telehand_msg_MODE_LESSON, allowed);
  takeover(run, other_run);
  EXPECT_THAT(refusal(run), HasSubstr("is not an open mobilization"));
  const uint64_t closed_lesson = demoLesson(demo, 1, 1, /*takeover=*/false);
  const uint64_t strict = open(telehand_msg_MODE_LESSON, closed_lesson);
  ASSERT_NE(strict, 0u);
  takeover(strict, sup);
  EXPECT_THAT(refusal(strict), HasSubstr("does not allow one"));
  // Bounded per run.
  for (int i = 0; i < 40; ++i) takeover(other_run, i % 2 ? sup : 0);
  EXPECT_THAT(refusal(other_run), HasSubstr("take-overs already"));
  // Anyone may ask: a flood of refused asks is counted, and said (and recorded) only up to a
  // bound per session, not one event and one row of the student's record per ask.
  const auto refusals = [&] {
    std::size_t n = 0;
    for (const auto& t : out_.textsOf(telehand_msg_EVENT_ERROR, strict))
      n += t.find("take-over by") != std::string::npos;
    return n;
  };
  const uint64_t bad_before = manager_->stats().bad_commands;
  for (int i = 0; i < 200; ++i) takeover(strict, sup);
  EXPECT_EQ(manager_->stats().bad_commands - bad_before, 200u);
  EXPECT_EQ(refusals(), static_cast<std::size_t>(Session::kMaxTakeoverRefusals));
  EXPECT_THAT(refusal(strict), HasSubstr("counted, not recorded"));
  std::size_t recorded = 0;
  for (const auto& e : store_->events(strict))
    recorded += e.text.find("take-over by") != std::string::npos;
  EXPECT_EQ(recorded, static_cast<std::size_t>(Session::kMaxTakeoverRefusals));
}

TEST(LessonPlan, RoundTripsAndRefusesWhatIsOutOfRange) {
  LessonPlan p;
  p.lesson_id = 12;
  p.schedule = "faded";
  p.guided = 2;
  p.attempts = 3;
  p.trial_s = 8;
  p.assessment = true;
  p.demo_s = 10.5;
  p.band_min_n = 12.1;
  p.band_max_n = 15.9;
  p.frequency_hz = 3.02;
  const auto q = decodePlan(encodePlan(p));
  ASSERT_TRUE(q.has_value());
  EXPECT_EQ(q->schedule, "faded");
  EXPECT_EQ(q->attempts, 3);
  EXPECT_NEAR(q->frequency_hz, 3.02, 1e-4);
  EXPECT_FALSE(q->takeover);
  p.takeover = true;
  EXPECT_TRUE(decodePlan(encodePlan(p))->takeover);
  std::string why;
  // A plan of an older server has no take-over key: none allowed.
  std::string old = encodePlan(p);
  old.erase(old.find(";takeover=1"));
  ASSERT_TRUE(decodePlan(old, &why).has_value()) << why;
  EXPECT_FALSE(decodePlan(old)->takeover);
  EXPECT_FALSE(decodePlan("lesson=1;schedule=loud", &why));
  EXPECT_THAT(why, HasSubstr("schedule"));
  // A band ending at 0 N would divide the client's progress by zero.
  LessonPlan zero = p;
  zero.band_min_n = zero.band_max_n = 0.0;
  EXPECT_FALSE(decodePlan(encodePlan(zero), &why));
  EXPECT_THAT(why, HasSubstr("ending at 0 N"));
  std::string text = encodePlan(p);
  text.replace(text.find("trial_s=8.000"), 13, "trial_s=1e9");
  EXPECT_FALSE(decodePlan(text, &why));
  EXPECT_THAT(why, HasSubstr("trial_s"));
  // A key given twice (a setting smuggled in through another's value) is refused.
  EXPECT_FALSE(decodePlan(encodePlan(p) + ";guided=9", &why));
  EXPECT_THAT(why, HasSubstr("'guided' is given twice"));
  // Authority fades from full over the guided trials, never zero while guided.
  EXPECT_DOUBLE_EQ(guidedAuthority(0, 2), 1.0);
  EXPECT_DOUBLE_EQ(guidedAuthority(1, 2), 0.5);
  EXPECT_NEAR(guidedAuthority(2, 3), 1.0 / 3.0, 1e-12);
  EXPECT_DOUBLE_EQ(guidedAuthority(3, 3), 0.0);
  // Schedules: terminal always, self when asked, faded ever fewer, concurrent at the end.
  int faded = 0;
  for (int i = 0; i < 9; ++i) {
    EXPECT_TRUE(feedbackAfter("terminal", i, 9, false));
    EXPECT_EQ(feedbackAfter("self", i, 9, i == 4), i == 4);
    faded += feedbackAfter("faded", i, 9, false);
  }
  EXPECT_GT(faded, 2);
  EXPECT_LT(faded, 9);
  EXPECT_TRUE(feedbackAfter("faded", 0, 9, false));
  EXPECT_FALSE(feedbackAfter("faded", 7, 9, false));
  EXPECT_FALSE(feedbackAfter("concurrent", 0, 9, false));
  // The technique: a mobilization unless the plan says massage; nothing else is taken.
  EXPECT_EQ(decodePlan(encodePlan(p))->technique, "mobilization");
  p.technique = "massage";
  EXPECT_EQ(decodePlan(encodePlan(p))->technique, "massage");
  EXPECT_EQ(decodePlan(old)->technique, "mobilization");  // an older server's plan
  text = encodePlan(p);
  text.replace(text.find("technique=massage"), 17, "technique=tapping");
  EXPECT_FALSE(decodePlan(text, &why));
  EXPECT_THAT(why, HasSubstr("technique"));
}

TEST(MassageLesson, TargetsRoundTripAndDamagedOnesAreRefusedNamingTheKey) {
  technique::MassageTargets t;
  t.normal_mean_n = 10.2;
  t.normal_sd_n = 0.7;
  t.band_min_n = 8.8;
  t.band_max_n = 11.6;
  t.time_in_band = 0.97;
  t.tangential_ratio = 0.29;
  t.centre_w = Vec3(0.0004, -0.0002, 0.0);
  t.radius_m = 0.006;
  t.frequency_hz = -1.5;  // clockwise
  t.circularity = 0.98;
  t.radial_rms_m = 0.0003;
  t.laps = 13;
  const std::string text = lesson::encodeMassageTargets(t);
  const technique::MassageTargets u = lesson::decodeMassageTargets(text);
  EXPECT_DOUBLE_EQ(u.normal_mean_n, 10.2);
  EXPECT_DOUBLE_EQ(u.band_max_n, 11.6);
  EXPECT_DOUBLE_EQ(u.frequency_hz, -1.5);
  EXPECT_DOUBLE_EQ(u.radius_m, 0.006);
  EXPECT_DOUBLE_EQ(u.centre_w.y(), -0.0002);
  EXPECT_DOUBLE_EQ(u.laps, 13);
  // A mobilization's targets are not a massage's, nor the other way round.
  EXPECT_THROW(lesson::decodeTargets(text), telehand::Error);
  auto refused = [&](const std::string& from, const std::string& to) {
    std::string bad = text;
    bad.replace(bad.find(from), from.size(), to);
    try {
      lesson::decodeMassageTargets(bad);
    } catch (const telehand::Error& e) {
      return std::string(e.what());
    }
    return std::string("accepted");
  };
  EXPECT_THAT(refused("technique=massage;", ""), HasSubstr("technique=massage"));
  EXPECT_THAT(refused("radius_m=0.006", "radius_m=0"), HasSubstr("'radius_m'"));
  EXPECT_THAT(refused("frequency_hz=-1.5", "frequency_hz=0.01"), HasSubstr("frequency_hz"));
  EXPECT_THAT(refused("frequency_hz=-1.5", "frequency_hz=nan"), HasSubstr("frequency_hz"));
  EXPECT_THAT(refused("band_max_n=11.6", "band_max_n=3"), HasSubstr("band_max_n"));
  EXPECT_THAT(refused("laps=13;", ""), HasSubstr("'laps' is missing"));
  // The plan of a massage lesson: its band and laps per second, no exploration, no take-over.
  store::LessonInfo l;
  l.id = 4;
  l.technique = "massage";
  l.guided = 2;
  l.assessment = true;
  l.takeover = true;
  const LessonPlan p = lesson::planOf(l, u, 12.0);
  EXPECT_EQ(p.technique, "massage");
  EXPECT_EQ(p.guided, 2);
  EXPECT_FALSE(p.assessment);
  EXPECT_FALSE(p.takeover);
  EXPECT_DOUBLE_EQ(p.frequency_hz, 1.5);
  EXPECT_DOUBLE_EQ(p.band_min_n, 8.8);
}

}  // namespace
}  // namespace telehand::server::session
