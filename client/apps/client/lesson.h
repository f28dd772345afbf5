#pragma once
// A lesson run from the student's side (docs/lessons.md): the phases the lesson's plan sets
// (exploration baseline, watching the demonstration, guided trials, free attempts,
// reassessment), announced to the server as they begin, with the feedback the plan's
// schedule gives: live band and frequency bars during trials (concurrent), or the trial's
// scores after it (terminal, faded, self-requested). With the simulated MF-2 a simulated
// student acts each phase out.
#include <atomic>
#include <functional>
#include <set>
#include <string>
#include <vector>

#include "options.h"
#include "telehand/client/link/client_link.h"
#include "telehand/client/loop/haptic_loop.h"
#include "telehand/core/technique_score.h"
#include "telehand/devices/exploration_operator.h"
#include "telehand/devices/simulated_massage_mf2.h"
#include "telehand/devices/simulated_mf2.h"
#include "telehand/protocol/lesson_plan.h"

namespace telehand::client::app {

/// What the simulated student does in a phase: rest, explore the joint's range, or perform
/// the lesson's technique (mobilize the joint, or massage the web).
enum class LessonAct : int { kRest = 0, kExplore = 1, kMobilize = 2 };

/// Who acts the phases out on a simulated MF-2 (set from the session's thread).
class LessonActor {
 public:
  virtual void set(LessonAct a) noexcept = 0;

 protected:
  ~LessonActor() = default;
};

/// The simulated student during a lesson: rests (lets the joint be), explores the six
/// directions, or mobilizes (the simulated MF-2's own push, skill included, restarted at
/// each trial). Called from the device's 1 kHz step: no allocation, no lock.
class LessonOperator final : public devices::Operator, public LessonActor {
 public:
  using Act = LessonAct;
  LessonOperator(const devices::SimulatedMf2& device, const devices::ExplorationPlan& plan,
                 const JointModelParams& geometry, double hold_n_per_m);
  /// From the session's thread: the act from the device's next step on.
  void set(Act a) noexcept override { want_.store(static_cast<int>(a), std::memory_order_release); }
  Vec3 torqueNm(double t_s, const Vec3& angles_rad, const Vec3& rates_rad_s) noexcept override;

 private:
  const devices::SimulatedMf2& device_;
  devices::ExplorationOperator explore_[2];  // baseline, reassessment
  double lever_m_, force_scale_, hold_nm_per_rad_;
  std::atomic<int> want_{0};
  int act_ = -1;
  int explorations_ = 0;
  double t0_ = 0.0;
};

/// The simulated student of a massage lesson: massages during the trials (each starts
/// afresh, skill included), rests otherwise. There is no exploration on the web.
class MassageLessonActor final : public LessonActor {
 public:
  explicit MassageLessonActor(devices::SimulatedMassageMf2& device) : device_(device) {}
  void set(LessonAct a) noexcept override { device_.setPerforming(a == LessonAct::kMobilize); }

 private:
  devices::SimulatedMassageMf2& device_;
};

/// One step of the run.
struct LessonStep {
  std::string phase;  ///< as the server knows it (PHASE command)
  double value = 0.0;
  double seconds = 0.0;
  LessonOperator::Act act = LessonOperator::Act::kRest;
  int trial = 0;  ///< 1-based for guided trials and attempts, 0 otherwise
  std::string label;
};
/// The run's steps from its plan and the client's options (exploration length, watch speed).
std::vector<LessonStep> lessonSteps(const LessonPlan& plan, const ClientOptions& o);

/// Drives the steps inside runSession: call every 50 ms with the session's elapsed time;
/// false when the run is over. Prints the phases and the feedback the schedule gives.
class LessonDriver {
 public:
  LessonDriver(const LessonPlan& plan, std::vector<LessonStep> steps, loop::HapticLoop& loop,
               link::ClientLink& link, LessonActor* op, std::set<int> requested, bool quiet);
  bool step(double t_s);
  /// Score lines that arrived after the run (the last trials'), printed per the schedule.
  void finish();
  int trialsRun() const noexcept { return trials_run_; }
  const std::vector<std::string>& scores() const noexcept { return scores_; }

 private:
  void begin(std::size_t i, double t_s);
  void showScores();
  void concurrentBars(double t_s);
  LessonPlan plan_;
  std::vector<LessonStep> steps_;
  loop::HapticLoop& loop_;
  link::ClientLink& link_;
  LessonActor* op_;
  std::set<int> requested_;
  bool quiet_;
  std::size_t current_ = 0;
  bool started_ = false;
  double step_end_s_ = 0.0;
  int trials_run_ = 0;
  int trials_total_ = 0;
  std::vector<std::string> scores_;
  // Concurrent feedback: the force as the loop renders it, sampled every call.
  technique::OscillationTracker tracker_;
  technique::Oscillation last_osc_{};
  bool have_osc_ = false;
  double next_bar_s_ = 0.0;
  // A massage's concurrent feedback: the pads' press over the last second.
  double press_min_n_ = 0.0, press_max_n_ = 0.0, press_sum_n_ = 0.0;
  int press_count_ = 0;
};

}  // namespace telehand::client::app
