#include "telehand/devices/sweep_operator.h"

#include <algorithm>
#include <cmath>

namespace telehand::devices {

SweepPlan planSweep(const JointModelParams& joint, double max_force_n, double wall_deg) {
  SweepPlan plan;
  const JointModel m(joint);
  const double lever = joint.lever_arm_m;
  plan.max_torque_nm = 1.2 * max_force_n * lever;
  for (int i = 0; i < kAxes; ++i) {
    const auto ax = static_cast<std::size_t>(i);
    const CubicCurve& c = joint.axes[ax];
    const double rest = radToDeg(m.restAngleRad(i));
    plan.hold_deg[ax] = rest;
    auto force = [&](double deg) { return m.holdingForceN(i, degToRad(deg)); };
    // Walk out from rest to the range end and into the end stop, or until the force.
    double lo = rest, hi = rest;
    constexpr double kStep = 0.05;
    while (lo - kStep >= c.min_deg - wall_deg && std::abs(force(lo - kStep)) <= max_force_n)
      lo -= kStep;
    while (hi + kStep <= c.max_deg + wall_deg && std::abs(force(hi + kStep)) <= max_force_n)
      hi += kStep;
    // The servo holds the phalanx short of its target by force / stiffness: aim past it.
    plan.lo_deg[ax] = lo + radToDeg(force(lo) * lever / plan.stiffness_nm_per_rad);
    plan.hi_deg[ax] = hi + radToDeg(force(hi) * lever / plan.stiffness_nm_per_rad);
  }
  return plan;
}

Vec3 SweepOperator::target(double t_s) const noexcept {
  Vec3 a;
  for (int i = 0; i < kAxes; ++i) a[i] = degToRad(plan_.hold_deg[static_cast<std::size_t>(i)]);
  if (t_s < 0.0) return a;
  const double total = plan_.durationS();
  double t = plan_.repeat ? std::fmod(t_s, total) : std::min(t_s, total);
  // One axis swept at `freq` between its limits, eased in and out of its hold angle by `w`
  // (no step in the planned angle).
  auto sweep = [&](int axis, double freq, double w, double spread = 1.0) {
    const auto ax = static_cast<std::size_t>(axis);
    const double centre = 0.5 * (plan_.lo_deg[ax] + plan_.hi_deg[ax]);
    const double amp = 0.5 * (plan_.hi_deg[ax] - plan_.lo_deg[ax]);
    // The phase of a frequency f(t) = freq · (m + h cos(2π t / T)), m ± h = 1 and `spread`:
    // its integral, so that the planned angle stays smooth.
    const double mid = 0.5 * (1.0 + spread), half = 0.5 * (1.0 - spread);
    double cycles = mid * freq * t;
    if (half > 0.0 && plan_.spread_cycles > 0.0 && freq > 0.0) {
      const double period = plan_.spread_cycles / freq;
      cycles += half * freq * period / (2.0 * kPi) * std::sin(2.0 * kPi * t / period);
    }
    const double deg = centre + amp * std::sin(2.0 * kPi * cycles);
    a[axis] = degToRad(plan_.hold_deg[ax] + w * (deg - plan_.hold_deg[ax]));
  };
  if (plan_.combined) {
    const double w = smoothRamp(std::min(t, total - t), plan_.ramp_s);
    sweep(kFlexion, plan_.frequency_hz, w);
    sweep(kAbduction, 3.7 * plan_.frequency_hz, w);
    return a;
  }
  const int axis = std::min(static_cast<int>(t / plan_.seconds_per_axis), kAxes - 1);
  t -= axis * plan_.seconds_per_axis;
  sweep(axis, plan_.frequency_hz, smoothRamp(std::min(t, plan_.seconds_per_axis - t), plan_.ramp_s),
        std::clamp(plan_.frequency_spread, 0.0, 1.0));
  return a;
}

Vec3 SweepOperator::torqueNm(double t_s, const Vec3& angles, const Vec3& rates) noexcept {
  Vec3 tau =
      plan_.stiffness_nm_per_rad * (target(t_s) - angles) - plan_.damping_nms_per_rad * rates;
  if (plan_.max_torque_nm > 0.0) {
    for (int i = 0; i < kAxes; ++i)
      tau[i] = std::clamp(tau[i], -plan_.max_torque_nm, plan_.max_torque_nm);
  }
  return tau;
}

}  // namespace telehand::devices
