#include "telehand/devices/exploration_operator.h"

#include <algorithm>
#include <cmath>

namespace telehand::devices {

ExplorationPlan planExploration(const JointModelParams& joint, double reach_n) {
  ExplorationPlan plan;
  const JointModel m(joint);
  for (int i = 0; i < kAxes; ++i) {
    const auto ax = static_cast<std::size_t>(i);
    plan.rest_deg[ax] = radToDeg(m.restAngleRad(i));
    plan.min_deg[ax] = joint.axes[ax].min_deg;
    plan.max_deg[ax] = joint.axes[ax].max_deg;
  }
  plan.reach_n = reach_n;
  plan.force_scale = joint.force_scale;
  plan.lever_arm_m = joint.lever_arm_m;
  return plan;
}

ExplorationOperator::ExplorationOperator(const ExplorationPlan& plan) : plan_(plan) {}

double ExplorationOperator::jitter(uint64_t cycle, int d) const noexcept {
  // splitmix64 of (seed, cycle, direction): a fixed pseudo-random number per push.
  uint64_t z = plan_.seed + 0x9e3779b97f4a7c15ULL * (cycle * 6 + static_cast<uint64_t>(d) + 1);
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  z ^= z >> 31;
  const double u = static_cast<double>(z >> 11) * 0x1.0p-53;  // [0, 1)
  return 0.9 + 0.2 * u;
}

ExplorationOperator::Phase ExplorationOperator::phaseAt(double t_s) const noexcept {
  Phase ph;
  double t = std::max(t_s, 0.0);
  // Walk the directions (each with its own duration) up to t.
  for (uint64_t cycle = 0;; ++cycle) {
    for (int d = 0; d < 2 * kAxes; ++d) {
      const double k = jitter(cycle, d);
      const double len = k * plan_.directionS();
      if (t < len) {
        ph.direction = d;
        ph.cycle = cycle;
        ph.t = t;
        ph.k = k;
        return ph;
      }
      t -= len;
    }
    if (!plan_.repeat) {
      ph.done = true;
      return ph;
    }
    if (cycle > 100000) break;  // bounded: t is finite
  }
  ph.done = true;
  return ph;
}

int ExplorationOperator::direction(double t_s) const noexcept { return phaseAt(t_s).direction; }

double ExplorationOperator::plannedForceN(double t_s) const noexcept {
  const Phase ph = phaseAt(t_s);
  if (ph.done) return 0.0;
  const double push = ph.k * plan_.push_s, hold = ph.k * plan_.hold_s;
  const double release = ph.k * plan_.release_s;
  double t = ph.t;
  if (t < push) return plan_.reach_n * smoothRamp(t, push);
  t -= push;
  if (t < hold) return plan_.reach_n;
  t -= hold;
  if (t < release) return plan_.reach_n * (1.0 - smoothRamp(t, release));
  return 0.0;
}

Vec3 ExplorationOperator::torqueNm(double t_s, const Vec3& angles, const Vec3& rates) noexcept {
  (void)rates;  // the simulated device adds the hand's damping itself
  const Phase ph = phaseAt(t_s);
  const double planned = plannedForceN(t_s);
  const int axis = ph.direction / 2;
  const double sign = ph.direction % 2 == 0 ? 1.0 : -1.0;
  if (ph.direction != stopped_dir_ || ph.cycle != stopped_cycle_) {
    stopped_dir_ = ph.direction;
    stopped_cycle_ = ph.cycle;
    stopped_n_ = -1.0;
  }
  // The clinician feels the end of the range and pushes no harder from there on.
  const auto ax = static_cast<std::size_t>(axis);
  const double end = degToRad(sign > 0.0 ? plan_.max_deg[ax] : plan_.min_deg[ax]);
  if (stopped_n_ < 0.0 && !ph.done && sign * (angles[axis] - end) >= 0.0) stopped_n_ = push_n_;
  push_n_ = ph.done ? 0.0 : stopped_n_ >= 0.0 ? std::min(planned, stopped_n_) : planned;

  const double lever = plan_.lever_arm_m;
  const double k = plan_.hold_n_per_m * lever * lever;
  Vec3 tau;
  for (int i = 0; i < kAxes; ++i) {
    const double rest = degToRad(plan_.rest_deg[static_cast<std::size_t>(i)]);
    // The explored axis is let go as the push builds up, and taken back to rest as it fades.
    const double hold = i == axis && plan_.reach_n > 0.0 ? 1.0 - planned / plan_.reach_n : 1.0;
    tau[i] = hold * k * (rest - angles[i]);
  }
  tau[axis] += sign * push_n_ * plan_.force_scale * lever;
  return tau;
}

}  // namespace telehand::devices
