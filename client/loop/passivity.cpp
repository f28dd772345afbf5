#include "client/loop/passivity.h"

#include <algorithm>

namespace telehand::client::loop {

void PassivityGuard::observe(const PerFinger<Vec3>& p, const PerFinger<Vec3>& last_force_n,
                             int64_t now_ns) noexcept {
  if (!allFinite(p[0]) || !allFinite(p[1])) return;  // a bad sample is the gate's business
  if (have_last_ && now_ns > last_ns_) {
    dt_s_ = static_cast<double>(now_ns - last_ns_) * 1e-9;
    for (int k = 0; k < 2; ++k) {
      const Vec3 d = p[k] - last_p_[k];
      // The device pushed the finger with last_force over d: that work left the environment.
      if (allFinite(last_force_n[k])) energy_j_ -= last_force_n[k].dot(d);
      v_[k] = d / dt_s_;
    }
  } else if (!have_last_) {
    v_ = {Vec3::Zero(), Vec3::Zero()};
  }
  have_last_ = true;
  last_ns_ = now_ns;
  last_p_ = p;
}

PassivityOutput PassivityGuard::control(const PerFinger<Vec3>& request) const noexcept {
  PassivityOutput out;
  out.force_n = request;
  if (!config_.control || energy_j_ >= 0.0) return out;
  const double v2 = v_[0].squaredNorm() + v_[1].squaredNorm();
  if (v2 * dt_s_ <= 1e-15) return out;  // nothing moves: no damping can dissipate anything
  const double alpha = std::min(-energy_j_ / (v2 * dt_s_), config_.max_damping_ns_per_m);
  for (int k = 0; k < 2; ++k) out.force_n[k] = request[k] - alpha * v_[k];
  out.damping_ns_per_m = alpha;
  return out;
}

}  // namespace telehand::client::loop
