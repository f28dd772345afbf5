#include "telehand/protocol/deadband.h"

#include <algorithm>
#include <cmath>

#include "telehand/core/math.h"

namespace telehand {

bool outsideDeadband(const double* value, const double* ref, int n, double weber,
                     double floor) noexcept {
  double d2 = 0.0, r2 = 0.0;
  for (int i = 0; i < n; ++i) {
    d2 += (value[i] - ref[i]) * (value[i] - ref[i]);
    r2 += ref[i] * ref[i];
  }
  const double band = std::max(weber * std::sqrt(r2), floor);
  return !(std::sqrt(d2) <= band);  // NaN goes out: the receiver must see it
}

namespace {

// Flags that do not by themselves make a sample worth sending: bookkeeping, and the gate's
// clamp and rate limit, which flicker on every few ticks at the force limits (the record has
// them all). Faults (watchdog, non-finite, FSR faults) and capture always go out.
constexpr uint32_t kUncodedFlags =
    sample_flags::kModelBlending | sample_flags::kSafetyClamped | sample_flags::kSafetyRateLimited |
    sample_flags::kPassivityControl | sample_flags::kSentLive | sample_flags::kDeadband;

// The forces a remote side uses: each thimble's FSR pair (paper eqs. 1-2) and command.
bool forcesMoved(const Sample& s, const Sample& r, const DeadbandConfig& c) noexcept {
  for (int k = 0; k < 2; ++k) {
    const double a[2] = {s.fingers[k].tangential_n, s.fingers[k].normal_n};
    const double b[2] = {r.fingers[k].tangential_n, r.fingers[k].normal_n};
    if (outsideDeadband(a, b, 2, c.weber, c.force_floor_n)) return true;
    if (outsideDeadband(s.fingers[k].command_n, r.fingers[k].command_n, 3, c.weber,
                        c.force_floor_n)) {
      return true;
    }
  }
  return false;
}

}  // namespace

bool DeviceStateDeadband::admit(const Sample& s, int64_t now_ns) noexcept {
  bool send = !c_.enabled() || !have_ || now_ns - sent_ns_ >= c_.max_interval_ns ||
              s.model_version != ref_.model_version ||
              (s.flags & ~kUncodedFlags) != (ref_.flags & ~kUncodedFlags) ||
              s.session_id != ref_.session_id;
  if (!send) send = forcesMoved(s, ref_, c_);
  if (!send) {
    send = outsideDeadband(s.mcp_angles_rad, ref_.mcp_angles_rad, 3, 0.0, degToRad(c_.angle_deg));
  }
  if (send) {
    have_ = true;
    sent_ns_ = now_ns;
    ref_ = s;
  }
  return send;
}

bool HandStateDeadband::admit(const telehand_msg_HandState& h, int64_t now_ns) noexcept {
  const double applied = h.applied_force_ref_n;
  // Torques at reference scale: the force floor at a 1 cm lever, at the 1:4 scale.
  const double torque_floor = c_.force_floor_n * 4.0 * 0.01;
  bool send = !c_.enabled() || !have_ || now_ns - sent_ns_ >= c_.max_interval_ns ||
              h.model_version != model_version_ ||
              outsideDeadband(h.mcp_angles_rad, angles_, 3, 0.0, degToRad(c_.angle_deg)) ||
              outsideDeadband(h.mcp_torque_nm, torque_, 3, c_.weber, torque_floor) ||
              outsideDeadband(&applied, &applied_, 1, c_.weber, c_.force_floor_n * 4.0);
  if (send) {
    have_ = true;
    sent_ns_ = now_ns;
    std::copy(h.mcp_angles_rad, h.mcp_angles_rad + 3, angles_);
    std::copy(h.mcp_torque_nm, h.mcp_torque_nm + 3, torque_);
    applied_ = applied;
    model_version_ = h.model_version;
  }
  return send;
}

}  // namespace telehand
