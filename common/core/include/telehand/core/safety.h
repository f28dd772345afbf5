#pragma once
/// The one gate every force passes before it reaches a device.
#include <cstdint>

#include "telehand/core/math.h"

namespace telehand {

struct SafetyLimits {
  double max_force_n = 4.0;         ///< per finger; MF-2 maximum (docs/facts.md "The paper")
  double max_rate_n_per_s = 200.0;  ///< per finger, on the force vector
  int64_t watchdog_ns = 5'000'000;  ///< no fresh device sample for this long -> zero force
};

/// Why the gate changed what was asked. Bits match the DeviceState kFlag* constants.
enum SafetyFlag : uint32_t {
  kSafetyClamped = 1u,
  kSafetyRateLimited = 2u,
  kSafetyWatchdog = 4u,
  kSafetyNonFinite = 8u,
  kSafetyCapture = 32u,  ///< capture mode: actuators off, every output is zero
};

struct SafetyOutput {
  PerFinger<Vec3> force_n{Vec3::Zero(), Vec3::Zero()};
  uint32_t flags = 0;
};

/// Finite check, per-finger clamp, rate limit, watchdog. A fault (non-finite request or a
/// stale sample) commands zero at once, without rate limiting; leaving a fault ramps up
/// from zero through the rate limit. Allocation-free, lock-free, noexcept.
class SafetyGate {
 public:
  explicit SafetyGate(const SafetyLimits& limits = {}) : limits_(limits) {}

  /// `sample_time_ns` is when the device sample behind `requested` was taken.
  SafetyOutput apply(const PerFinger<Vec3>& requested, int64_t now_ns,
                     int64_t sample_time_ns) noexcept;

  /// Forget the last output (next output rate-limits from zero).
  void reset() noexcept;
  /// Capture mode: every output is zero whatever is requested (the clinician moves a real
  /// finger with the actuators off); leaving it ramps up from zero through the rate limit.
  void setCapture(bool on) noexcept { capture_ = on; }
  const SafetyLimits& limits() const noexcept { return limits_; }

 private:
  SafetyLimits limits_;
  PerFinger<Vec3> last_{Vec3::Zero(), Vec3::Zero()};
  int64_t last_ns_ = 0;
  bool have_last_ = false;
  bool capture_ = false;
};

}  // namespace telehand
