#pragma once
/// Time-domain passivity observer and controller at the device port (Hannaford & Ryu 2002;
/// docs/facts.md "Rendering and perception"). Whatever renders the force (the local joint model,
/// or forces from a remote server), the observer counts the energy that side has absorbed
/// from the operator:
///   E(n) = E(n-1) − Σ_fingers F(n-1) · (p(n) − p(n-1)),
/// exact for a force held over the tick (zero-order hold). A passive environment keeps
/// E ≥ 0. When E falls below zero the controller adds the damping that dissipates the
/// deficit over the next tick, α = −E / (Σ|v|² dt), bounded by `max_damping`, and the
/// dissipated energy is counted when the next tick observes it. Allocation-free, noexcept.
///
/// The controller's velocity is not the one-tick difference of the positions: with encoder
/// positions that difference is mostly quantization at low speed (one count moves an MF-2
/// thimble by a few µm, i.e. several mm/s), and a damper acting on it turns the noise into
/// force steps (20 N·s/m × 5 mm/s = 0.1 N, flipping sign every tick) and, held over the next
/// tick against the next noisy increment, does negative work in the observer's account, which
/// keeps the controller on. It uses an adaptive-window estimate (AdaptiveVelocity): quiet when
/// the motion is slow, one tick when it is fast, and damps only the part of it above the
/// estimate's resolution (nothing for a still thimble whose count flickers). And its damping
/// moves toward α no faster than changes the added force by `max_force_rate` at the current
/// speed, so that switching on and off does not step the force either. The observer is
/// unchanged and exact: whatever the controller does is counted, and it acts while E < 0.
///
/// A damper is only dissipative while the loop can render it: on a mass m, with its force
/// acting d ticks of period T after the velocity it damps, b·T/m above 2·sin(π / (2(2d + 1)))
/// makes it ring and grow (stableDampingNsPerM), and an observer that sees the ringing as
/// generated energy asks for more. So the damping is bounded by the device's lightest moving
/// mass and its delay (setDeviceLimit) as well as by `max_damping`.
#include <cstdint>

#include "telehand/core/joint_model.h"
#include "telehand/core/math.h"
#include "telehand/core/velocity.h"

namespace telehand::client::loop {

struct PassivityConfig {
  bool control = true;  ///< false: observe only
  /// Damping bound, N·s/m per finger: at 1 kHz with ~50 g at the grip, well inside the
  /// discrete stability limit (m / T = 50 N·s/m).
  double max_damping_ns_per_m = 20.0;
  /// Band around the velocity window's line that every sample must lie in, m. A thimble
  /// position is off by at most 3.8 µm (the MF-2's encoder quantization through its kinematics,
  /// device model); the line goes through two such samples, so a sample of a straight motion
  /// can lie up to twice that from it.
  double position_uncertainty_m = 8e-6;
  /// Longest window of the velocity estimate, ticks (1 = the one-tick difference).
  int velocity_window = 20;
  /// Fastest change of the added force through the damping coefficient, N/s per finger: a
  /// quarter of the safety gate's 200 N/s, so that the controller never needs the gate.
  double max_force_rate_n_per_s = 50.0;
  /// Fraction of the device's stability bound (stableDampingNsPerM) the damping may reach:
  /// with the joint model's kJointDampingShare (0.5) 0.9 of it at most, as 20 + 25 N·s/m are
  /// of the 50 that 50 g take at 1 kHz.
  double stability_margin = 0.4;
};

struct PassivityOutput {
  PerFinger<Vec3> force_n{Vec3::Zero(), Vec3::Zero()};
  double damping_ns_per_m = 0.0;  ///< 0 when the controller did nothing
};

class PassivityGuard {
 public:
  explicit PassivityGuard(const PassivityConfig& config = {});

  /// Count the energy of the last tick: thimble positions now and the force that was commanded
  /// (after the safety gate) over the tick that just ended. Call once per tick, first.
  void observe(const PerFinger<Vec3>& p_device_finger, const PerFinger<Vec3>& last_force_n,
               int64_t now_ns) noexcept;

  /// The controller: `request` plus the damping the energy deficit calls for. Call once per
  /// tick, after observe (the damping moves from its last value).
  PassivityOutput control(const PerFinger<Vec3>& request) noexcept;

  /// The damping the device renders before it rings (stableDampingNsPerM with its lightest
  /// moving mass, its delay and the loop's tick; 0 or less: unknown, only `max_damping`
  /// bounds the damping). The controller keeps `stability_margin` of it. Real-time safe.
  void setDeviceLimit(double limit_ns_per_m) noexcept;
  /// The bound setDeviceLimit(limit_ns_per_m) would set, without setting it.
  double boundFor(double limit_ns_per_m) const noexcept;
  /// The most damping the controller may add, N·s/m per finger.
  double dampingBoundNsPerM() const noexcept { return bound_ns_per_m_; }

  /// After a device outage: forget the positions and velocity windows (the next sample
  /// starts them afresh, so the gap's displacement is neither differenced into a speed nor
  /// counted against a force that was not rendered) and the damping; the energy is kept.
  void restart() noexcept;

  /// Energy the rendering side has absorbed from the operator so far, J (device scale).
  double energyJ() const noexcept { return energy_j_; }
  /// Thimble velocities as the controller damps them (adaptive window, less its
  /// resolution), m/s.
  const PerFinger<Vec3>& velocity() const noexcept { return vc_; }
  const PassivityConfig& config() const noexcept { return config_; }

 private:
  PassivityConfig config_;
  bool have_last_ = false;
  int64_t last_ns_ = 0;
  double dt_s_ = 1e-3;
  PerFinger<Vec3> last_p_{Vec3::Zero(), Vec3::Zero()};
  PerFinger<AdaptiveVelocity> vel_;
  PerFinger<Vec3> vc_{Vec3::Zero(), Vec3::Zero()};
  double alpha_ = 0.0;  // damping applied on the last tick
  double energy_j_ = 0.0;
  double bound_ns_per_m_ = 0.0;  // max_damping, or less on the device set
};

}  // namespace telehand::client::loop
