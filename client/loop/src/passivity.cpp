#include "telehand/client/loop/passivity.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace telehand::client::loop {

namespace {
/// The part of an estimate above its resolution (a soft threshold, continuous in the
/// estimate): nothing for a still thimble whose position flickers by a count.
Vec3 resolved(const AdaptiveVelocity& e) noexcept {
  const double speed = e.velocity().norm();
  if (!(speed > e.resolution())) return Vec3::Zero();
  return e.velocity() * ((speed - e.resolution()) / speed);
}
}  // namespace

PassivityGuard::PassivityGuard(const PassivityConfig& config)
    : config_(config),
      vel_{AdaptiveVelocity(config.position_uncertainty_m, config.velocity_window),
           AdaptiveVelocity(config.position_uncertainty_m, config.velocity_window)} {
  bound_ns_per_m_ = config.max_damping_ns_per_m;
}

void PassivityGuard::observe(const PerFinger<Vec3>& p, const PerFinger<Vec3>& last_force_n,
                             int64_t now_ns) noexcept {
  if (!allFinite(p[0]) || !allFinite(p[1])) return;  // a bad sample is the gate's business
  if (have_last_ && now_ns > last_ns_) {
    dt_s_ = static_cast<double>(now_ns - last_ns_) * 1e-9;
    for (int k = 0; k < 2; ++k) {
      const Vec3 d = p[k] - last_p_[k];
      // The device pushed the finger with last_force over d: that work left the environment.
      if (allFinite(last_force_n[k])) energy_j_ -= last_force_n[k].dot(d);
    }
  }
  for (int k = 0; k < 2; ++k) {
    vel_[k].update(p[k], now_ns);
    vc_[k] = resolved(vel_[k]);
  }
  have_last_ = true;
  last_ns_ = now_ns;
  last_p_ = p;
}

double PassivityGuard::boundFor(double limit_ns_per_m) const noexcept {
  return limit_ns_per_m > 0.0
             ? std::min(config_.max_damping_ns_per_m, config_.stability_margin * limit_ns_per_m)
             : config_.max_damping_ns_per_m;
}

void PassivityGuard::setDeviceLimit(double limit_ns_per_m) noexcept {
  bound_ns_per_m_ = boundFor(limit_ns_per_m);
}

void PassivityGuard::restart() noexcept {
  have_last_ = false;
  for (int k = 0; k < 2; ++k) {
    vel_[k].reset();
    vc_[k].setZero();
  }
  alpha_ = 0.0;
}

PassivityOutput PassivityGuard::control(const PerFinger<Vec3>& request) noexcept {
  PassivityOutput out;
  out.force_n = request;
  const Vec3& v0 = vc_[0];
  const Vec3& v1 = vc_[1];
  const double v2 = v0.squaredNorm() + v1.squaredNorm();
  // The damping that would dissipate the whole deficit over the next tick.
  const double bound = bound_ns_per_m_;
  double target = 0.0;
  if (config_.control && energy_j_ < 0.0 && v2 * dt_s_ > 1e-15) {
    target = std::min(-energy_j_ / (v2 * dt_s_), bound);
  }
  // Move toward it by at most what changes the added force by max_force_rate·dt at the
  // current speed (at once when nothing moves: the force is nil either way).
  const double speed = std::max(v0.norm(), v1.norm());
  const double step = config_.max_force_rate_n_per_s * dt_s_;
  const double max_change = speed > 0.0 ? step / speed : std::numeric_limits<double>::infinity();
  alpha_ = config_.control ? std::clamp(target, alpha_ - max_change, alpha_ + max_change) : 0.0;
  alpha_ = std::clamp(alpha_, 0.0, bound);
  if (alpha_ <= 0.0) return out;
  out.force_n[0] = request[0] - alpha_ * v0;
  out.force_n[1] = request[1] - alpha_ * v1;
  out.damping_ns_per_m = alpha_;
  return out;
}

}  // namespace telehand::client::loop
