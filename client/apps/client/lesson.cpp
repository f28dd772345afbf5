#include "lesson.h"

#include <spdlog/fmt/fmt.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iostream>

namespace telehand::client::app {

LessonOperator::LessonOperator(const devices::SimulatedMf2& device,
                               const devices::ExplorationPlan& plan,
                               const JointModelParams& geometry, double hold_n_per_m)
    : device_(device),
      explore_{devices::ExplorationOperator(plan), devices::ExplorationOperator(plan)},
      lever_m_(geometry.lever_arm_m),
      force_scale_(geometry.force_scale),
      hold_nm_per_rad_(hold_n_per_m * geometry.lever_arm_m * geometry.lever_arm_m) {}

Vec3 LessonOperator::torqueNm(double t_s, const Vec3& angles_rad,
                              const Vec3& rates_rad_s) noexcept {
  const int want = want_.load(std::memory_order_acquire);
  if (want != act_) {
    act_ = want;
    t0_ = t_s;
    if (act_ == static_cast<int>(Act::kExplore)) ++explorations_;
  }
  const double t = t_s - t0_;
  Vec3 tau(0.0, -hold_nm_per_rad_ * angles_rad[kAbduction], -hold_nm_per_rad_ * angles_rad[kAxial]);
  switch (static_cast<Act>(act_)) {
    case Act::kExplore:
      return explore_[explorations_ > 1 ? 1 : 0].torqueNm(t, angles_rad, rates_rad_s);
    case Act::kMobilize:
      // The simulated MF-2's own mobilization (its operator's band, frequency and skill),
      // built up again from zero at each trial.
      tau[kFlexion] = (device_.targetForceN(t) + device_.tremorN()) * force_scale_ * lever_m_;
      return tau;
    case Act::kRest:
      break;
  }
  return tau;
}

std::vector<LessonStep> lessonSteps(const LessonPlan& plan, const ClientOptions& o) {
  using Act = LessonOperator::Act;
  std::vector<LessonStep> s;
  if (plan.assessment) {
    s.push_back({"baseline", 0.0, o.explore_seconds, Act::kExplore, 0,
                 "exploration baseline (the joint's range in each direction)"});
  }
  if (plan.demo_s > 0.0) {
    s.push_back(
        {"watch", o.watch_speed, plan.demo_s / o.watch_speed + 0.5, Act::kRest, 0,
         fmt::format("watch the demonstration ({:.1f} s at {:.2g}x)", plan.demo_s, o.watch_speed)});
  }
  int trial = 0;
  for (int i = 0; i < plan.guided; ++i) {
    const double a = guidedAuthority(i, plan.guided);
    ++trial;
    s.push_back(
        {"guided", a, plan.trial_s, Act::kMobilize, trial,
         fmt::format("trial {}: guided, the device leads ({:.0f} % authority)", trial, 100.0 * a)});
  }
  for (int i = 0; i < plan.attempts; ++i) {
    ++trial;
    s.push_back(
        {"attempt", 0.0, plan.trial_s, Act::kMobilize, trial,
         fmt::format("trial {}: attempt {} of {} on your own", trial, i + 1, plan.attempts)});
  }
  if (plan.assessment) {
    // The finger back at rest first: an exploration judges each direction from where it
    // starts, and the last trial leaves the joint flexed.
    s.push_back({"rest", 0.0, 1.5, Act::kRest, 0, "rest (the finger back at rest)"});
    s.push_back({"reassessment", 0.0, o.explore_seconds, Act::kExplore, 0,
                 "reassessment (the range again, after treatment)"});
  } else {
    s.push_back({"rest", 0.0, 0.5, Act::kRest, 0, "rest"});
  }
  return s;
}

LessonDriver::LessonDriver(const LessonPlan& plan, std::vector<LessonStep> steps,
                           loop::HapticLoop& loop, link::ClientLink& link, LessonActor* op,
                           std::set<int> requested, bool quiet)
    : plan_(plan),
      steps_(std::move(steps)),
      loop_(loop),
      link_(link),
      op_(op),
      requested_(std::move(requested)),
      quiet_(quiet),
      trials_total_(plan.guided + plan.attempts) {}

void LessonDriver::begin(std::size_t i, double t_s) {
  const LessonStep& st = steps_[i];
  const uint64_t next = loop_.nextSeq();
  link_.phase(st.phase, st.value, next == 0 ? 0 : next - 1);
  if (op_) op_->set(st.act);
  step_end_s_ = t_s + st.seconds;
  if (st.trial > 0) {
    ++trials_run_;
    tracker_.reset();
    have_osc_ = false;
    press_count_ = 0;
    press_sum_n_ = 0.0;
    if (plan_.technique == "massage") next_bar_s_ = t_s + 1.0;  // a whole second per bar
  }
  std::printf("\nphase %zu/%zu: %s\n", i + 1, steps_.size(), st.label.c_str());
  if (st.trial > 0 && plan_.schedule == "concurrent") {
    if (plan_.technique == "massage") {
      std::printf("  aim: press %.1f-%.1f N, circles at %.2f Hz (the demonstration's)\n",
                  plan_.band_min_n, plan_.band_max_n, plan_.frequency_hz);
    } else {
      std::printf("  aim: %.1f-%.1f N at %.2f Hz (the demonstration's)\n", plan_.band_min_n,
                  plan_.band_max_n, plan_.frequency_hz);
    }
  }
  std::fflush(stdout);
}

void LessonDriver::showScores() {
  for (std::string& s : link_.takeScores()) {
    // "trial N (...): ..." or the run's "lesson ...".
    int n = 0;
    const bool trial = std::sscanf(s.c_str(), "trial %d", &n) == 1;
    const bool show =
        !trial || feedbackAfter(plan_.schedule, n - 1, trials_total_, requested_.count(n) > 0);
    if (show) std::printf("  feedback: %s\n", s.c_str());
    scores_.push_back(std::move(s));
  }
  std::fflush(stdout);
}

void LessonDriver::concurrentBars(double t_s) {
  const auto& h = loop_.health();
  constexpr int kWidth = 30;
  if (plan_.technique == "massage") {
    // The pads' press (the firmer pad's, as the loop renders it) over the last second against
    // the band: '[' the band ']', '.' the least, '|' the most, '*' the mean.
    const double n = h.web_normal_ref_n.load();
    if (press_count_ == 0) press_min_n_ = press_max_n_ = n;
    press_min_n_ = std::min(press_min_n_, n);
    press_max_n_ = std::max(press_max_n_, n);
    press_sum_n_ += n;
    ++press_count_;
    if (t_s < next_bar_s_) return;
    next_bar_s_ = t_s + 1.0;
    const double full = 1.5 * plan_.band_max_n;
    auto col = [&](double f) {
      return static_cast<std::size_t>(
          std::clamp(static_cast<int>(f / full * kWidth), 0, kWidth - 1));
    };
    const double mean = press_sum_n_ / press_count_;
    std::string bar(kWidth, '-');
    bar[col(plan_.band_min_n)] = '[';
    bar[col(plan_.band_max_n)] = ']';
    bar[col(press_min_n_)] = '.';
    bar[col(press_max_n_)] = '|';
    bar[col(mean)] = '*';
    std::printf("  press %s %4.1f N (%4.1f-%4.1f)\n", bar.c_str(), mean, press_min_n_,
                press_max_n_);
    std::fflush(stdout);
    press_count_ = 0;
    press_sum_n_ = 0.0;
    return;
  }
  technique::Oscillation o;
  if (tracker_.add(t_s, h.applied_ref_n.load(), Vec3::Zero(), o)) {
    last_osc_ = o;
    have_osc_ = true;
  }
  if (t_s < next_bar_s_ || !have_osc_) return;
  next_bar_s_ = t_s + 1.0;
  // A bar from 0 to 1.5x the band's top: '[' the band ']', '|' the last peak, '.' its trough.
  const double full = 1.5 * plan_.band_max_n;
  auto col = [&](double n) {
    return std::clamp(static_cast<int>(n / full * kWidth), 0, kWidth - 1);
  };
  std::string bar(kWidth, '-');
  bar[static_cast<std::size_t>(col(plan_.band_min_n))] = '[';
  bar[static_cast<std::size_t>(col(plan_.band_max_n))] = ']';
  bar[static_cast<std::size_t>(col(last_osc_.trough_n))] = '.';
  bar[static_cast<std::size_t>(col(last_osc_.peak_n))] = '|';
  const double df = last_osc_.frequency_hz - plan_.frequency_hz;
  std::printf("  force %s %4.1f-%4.1f N   frequency %4.2f Hz (%s%.2f)\n", bar.c_str(),
              last_osc_.trough_n, last_osc_.peak_n, last_osc_.frequency_hz, df >= 0 ? "+" : "", df);
  std::fflush(stdout);
}

bool LessonDriver::step(double t_s) {
  if (!started_) {
    started_ = true;
    begin(0, t_s);
  }
  showScores();
  if (steps_[current_].trial > 0 && plan_.schedule == "concurrent") concurrentBars(t_s);
  if (t_s < step_end_s_) return true;
  if (current_ + 1 >= steps_.size()) return false;
  begin(++current_, t_s);
  return true;
}

void LessonDriver::finish() { showScores(); }

}  // namespace telehand::client::app
