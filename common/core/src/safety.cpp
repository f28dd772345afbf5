#include "telehand/core/safety.h"

namespace telehand {

SafetyOutput SafetyGate::apply(const PerFinger<Vec3>& requested, int64_t now_ns,
                               int64_t sample_time_ns) noexcept {
  SafetyOutput out;
  const bool stale = now_ns - sample_time_ns > limits_.watchdog_ns;
  const bool finite = allFinite(requested[0]) && allFinite(requested[1]);
  if (capture_ || stale || !finite) {
    // Capture (actuators off) or a fault: zero at once, without rate limiting.
    out.flags = capture_ ? kSafetyCapture
                         : (stale ? kSafetyWatchdog : 0u) | (finite ? 0u : kSafetyNonFinite);
    last_ = out.force_n;  // zero
    last_ns_ = now_ns;
    have_last_ = true;
    return out;
  }
  const double dt = have_last_ ? static_cast<double>(now_ns - last_ns_) * 1e-9 : 0.0;
  const double max_step = limits_.max_rate_n_per_s * std::max(dt, 0.0);
  for (int k = 0; k < 2; ++k) {
    Vec3 f = requested[k];
    const double n = f.norm();
    if (n > limits_.max_force_n) {
      f *= limits_.max_force_n / n;
      out.flags |= kSafetyClamped;
    }
    const Vec3 step = f - last_[k];
    const double step_n = step.norm();
    if (step_n > max_step) {
      f = last_[k] + step * (max_step / step_n);
      out.flags |= kSafetyRateLimited;
    }
    out.force_n[k] = f;
  }
  last_ = out.force_n;
  last_ns_ = now_ns;
  have_last_ = true;
  return out;
}

void SafetyGate::reset() noexcept {
  last_ = {Vec3::Zero(), Vec3::Zero()};
  have_last_ = false;
}

}  // namespace telehand
