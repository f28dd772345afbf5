#pragma once
/// Perceptual deadband coding (Hinterseer & Steinbach; docs/facts.md "Rendering and perception"):
/// a state goes out only when it differs from the last one sent by more than a Weber fraction
/// of that value (forces), or by an absolute step where Weber's law does not apply (angles,
/// forces near zero), or when nothing has gone out for `max_interval_ns`. The receiver holds
/// the last value it got (zero-order hold); a sample it did not get is, by construction,
/// within the deadband of the one it holds.
#include <cstdint>

#include "telehand.h"
#include "telehand/core/sample.h"

namespace telehand {

struct DeadbandConfig {
  double weber = 0.0;                    ///< fraction, e.g. 0.05; 0 = every sample goes out
  double force_floor_n = 0.1;            ///< absolute force step always sent (device N)
  double angle_deg = 0.5;                ///< joint angle step that is always sent
  int64_t max_interval_ns = 50'000'000;  ///< heartbeat, under the 100 ms DeviceState deadline
  bool enabled() const noexcept { return weber > 0.0; }
};

/// Decides which DeviceStates go out live. Allocation-free.
class DeviceStateDeadband {
 public:
  explicit DeviceStateDeadband(const DeadbandConfig& config = {}) : c_(config) {}
  /// True when `s` must be sent (and becomes the reference). `now_ns` is the sender's clock.
  bool admit(const Sample& s, int64_t now_ns) noexcept;
  const DeadbandConfig& config() const noexcept { return c_; }

 private:
  DeadbandConfig c_;
  bool have_ = false;
  int64_t sent_ns_ = 0;
  Sample ref_{};
};

/// Decides which HandStates go out to remote viewers (the MCP angles, torques and the
/// student's applied force). Allocation-free.
class HandStateDeadband {
 public:
  explicit HandStateDeadband(const DeadbandConfig& config = {}) : c_(config) {}
  bool admit(const telehand_msg_HandState& h, int64_t now_ns) noexcept;

 private:
  DeadbandConfig c_;
  bool have_ = false;
  int64_t sent_ns_ = 0;
  double angles_[3]{};
  double torque_[3]{};
  double applied_ = 0.0;
  uint32_t model_version_ = 0;
};

/// True when `value` left the deadband around `ref`: |value − ref| > max(weber·|ref|, floor).
/// Vectors compare by the norm of the difference against the norm of the reference.
bool outsideDeadband(const double* value, const double* ref, int n, double weber,
                     double floor) noexcept;

}  // namespace telehand
