#pragma once
/// A student's run of a lesson (docs/lessons.md): the lesson and its targets, the trial under
/// way, and the trials waiting to be scored. A trial is scored on the 1 kHz record (read back
/// from the store once every sample up to its last has arrived, or once its wait is over) and
/// its scores go into the record (a trial row and score events) and out as events.
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "telehand/core/massage_score.h"
#include "telehand/core/technique_score.h"
#include "telehand/protocol/lesson_plan.h"
#include "telehand/server/session/session_context.h"
#include "telehand/server/store/store.h"

namespace telehand::server::session {

class LessonRun {
 public:
  /// How long a finished trial waits for the rest of its record before it is scored on what
  /// arrived (and says how much is missing).
  static constexpr int64_t kScoreWaitNs = 10'000'000'000;
  /// A trial is scored over at most its planned length plus this.
  static constexpr double kTrialMarginS = 30.0;
  /// How often a waiting trial's record is counted.
  static constexpr int64_t kCheckEveryNs = 250'000'000;
  /// Oscillation score events per trial at most (the trial's own always goes out).
  static constexpr int kMaxOscillationEvents = 64;

  LessonRun(store::LessonInfo lesson, technique::Targets goals, LessonPlan run_plan)
      : info(std::move(lesson)), targets(std::move(goals)), plan(std::move(run_plan)) {}
  /// A massage lesson: its trials are scored as circles on `web` (technique::scoreMassage).
  LessonRun(store::LessonInfo lesson, technique::MassageTargets goals, const TissueParams& on,
            LessonPlan run_plan)
      : info(std::move(lesson)), plan(std::move(run_plan)), massage(std::move(goals)), web(on) {}

  /// A trial begins with sample `first_seq` (phase guided or attempt).
  void begin(const std::string& phase, double authority, uint64_t first_seq);
  /// The trial under way (if any) ended with sample `last_seq`: it waits to be scored.
  void end(uint64_t last_seq, int64_t now_ns);
  bool inTrial() const noexcept { return in_trial_; }
  /// Score the waiting trials whose record is complete (all of them when `final`).
  void scoreDue(SessionContext& ctx, uint64_t session_id, uint64_t client_id, double force_scale,
                int64_t now_ns, bool final);
  /// The run's summary line (trials scored, mean and best overall), for the closing event.
  std::string summary() const;
  int trialsBegun() const noexcept { return begun_; }
  const std::vector<double>& overall() const noexcept { return overall_; }

  const store::LessonInfo info;
  const technique::Targets targets;  ///< a mobilization's (empty for a massage)
  const LessonPlan plan;
  const std::optional<technique::MassageTargets> massage;  ///< a massage's targets
  const TissueParams web;                                  ///< and the web it is done on

 private:
  struct Trial {
    int index = 0;
    std::string phase;
    double authority = 0.0;
    uint64_t first_seq = 0, last_seq = 0;
    int64_t deadline_ns = 0;
    int64_t next_check_ns = 0;
    bool cut = false;    // longer than planned: scored over its first part
    bool empty = false;  // ended before a sample of it was sent: said, not scored
  };
  void score(SessionContext& ctx, uint64_t session_id, uint64_t client_id, double force_scale,
             const Trial& t, int64_t now_ns);
  bool in_trial_ = false;
  Trial current_;
  int begun_ = 0;
  std::vector<Trial> waiting_;
  std::vector<double> overall_;
};

}  // namespace telehand::server::session
