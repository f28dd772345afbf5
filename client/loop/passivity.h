#pragma once
/// Time-domain passivity observer and controller at the device port (Hannaford & Ryu 2002;
/// FACTS.md "Rendering and perception"). Whatever renders the force (the local joint model,
/// or forces from a remote server), the observer counts the energy that side has absorbed
/// from the operator:
///   E(n) = E(n-1) − Σ_fingers F(n-1) · (p(n) − p(n-1)),
/// exact for a force held over the tick (zero-order hold). A passive environment keeps
/// E ≥ 0. When E falls below zero the controller adds the damping that dissipates the
/// deficit over the next tick, α = −E / (Σ|v|² dt), bounded by `max_damping`, and the
/// dissipated energy is counted when the next tick observes it. Allocation-free, noexcept.
#include <cstdint>

#include "telehand/common/math.h"

namespace telehand::client::loop {

struct PassivityConfig {
  bool control = true;                  ///< false: observe only
  /// Damping bound, N·s/m per finger: at 1 kHz with ~50 g at the grip, well inside the
  /// discrete stability limit (m / T = 50 N·s/m).
  double max_damping_ns_per_m = 20.0;
};

struct PassivityOutput {
  PerFinger<Vec3> force_n{Vec3::Zero(), Vec3::Zero()};
  double damping_ns_per_m = 0.0;        ///< 0 when the controller did nothing
};

class PassivityGuard {
 public:
  explicit PassivityGuard(const PassivityConfig& config = {}) : config_(config) {}

  /// Count the energy of the last tick: thimble positions now and the force that was commanded
  /// (after the safety gate) over the tick that just ended. Call once per tick, first.
  void observe(const PerFinger<Vec3>& p_device_finger, const PerFinger<Vec3>& last_force_n,
               int64_t now_ns) noexcept;

  /// The controller: `request` plus the damping the energy deficit calls for.
  PassivityOutput control(const PerFinger<Vec3>& request) const noexcept;

  /// Energy the rendering side has absorbed from the operator so far, J (device scale).
  double energyJ() const noexcept { return energy_j_; }
  /// Thimble velocities from the last two observations, m/s.
  const PerFinger<Vec3>& velocity() const noexcept { return v_; }
  const PassivityConfig& config() const noexcept { return config_; }
  void setControl(bool on) noexcept { config_.control = on; }

 private:
  PassivityConfig config_;
  bool have_last_ = false;
  int64_t last_ns_ = 0;
  double dt_s_ = 1e-3;
  PerFinger<Vec3> last_p_{Vec3::Zero(), Vec3::Zero()};
  PerFinger<Vec3> v_{Vec3::Zero(), Vec3::Zero()};
  double energy_j_ = 0.0;
};

}  // namespace telehand::client::loop
