#pragma once
/// A lesson run as both ends see it (docs/lessons.md): the plan the server sends a student's
/// client in its SessionStatus (one line of key=value pairs separated by ';'), the guide's
/// authority per guided trial and which trials the feedback schedule shows feedback after.
#include <cstdint>
#include <optional>
#include <string>

namespace telehand {

/// The feedback schedules compared in the mobilization-feedback literature (docs/facts.md
/// "Training with feedback"): concurrent (live band and frequency bars during every trial),
/// terminal (the trial's scores after each trial), faded (after every trial at first, then
/// ever fewer), self (only after the trials the student asks for).
bool validSchedule(const std::string& s) noexcept;

struct LessonPlan {
  uint64_t lesson_id = 0;
  std::string schedule = "terminal";
  int guided = 0;        ///< guided trials, 0..10
  int attempts = 0;      ///< free attempts after them, 1..20
  double trial_s = 0.0;  ///< each trial, 2..120 s
  bool assessment = false;
  double demo_s = 0.0;  ///< the demonstration's length (the watch phase), 0..600 s
  double band_min_n = 0.0, band_max_n = 0.0;  ///< the demonstration's force band, reference N
  double frequency_hz = 0.0;                  ///< its oscillation
  /// A supervisor may take over the demonstration (their live session leads the guide).
  bool takeover = false;
  /// What the lesson teaches: "mobilization" (the joint) or "massage" (the web; then the band
  /// is the pads' normal force and the frequency the circle's laps per second). A plan
  /// without it is a mobilization.
  std::string technique = "mobilization";
};
std::string encodePlan(const LessonPlan& p);
/// nullopt (and `why` names the key) for a plan that is malformed or out of range.
std::optional<LessonPlan> decodePlan(const std::string& text, std::string* why = nullptr);

/// Authority of guided trial `i` (0-based) of `n`: full, then evenly down, never zero
/// (n = 2: 1, 0.5; n = 3: 1, 0.67, 0.33). The free attempts after them have none.
double guidedAuthority(int i, int n) noexcept;

/// Whether the schedule shows terminal feedback after trial `i` (0-based over all trials of
/// the run, guided first); `requested`: the student asked (self schedule). Concurrent
/// feedback shows during the trial instead (and its summary after the last trial only).
bool feedbackAfter(const std::string& schedule, int i, int trials, bool requested) noexcept;

}  // namespace telehand
