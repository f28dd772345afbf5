#pragma once
/// A clinician capturing a joint (paper section IV.B) as a simulated operator: the
/// actuators are off and the clinician moves the phalanx through each axis in turn, out to
/// the end of its range and a little into the end stop (the end-feel, as a clinician
/// explores it), or to the angle where it takes `max_force_n` if that comes first (the
/// thimbles' FSRs saturate at about 22 N), holding the other axes still. The hand is a
/// position servo (a stiff, damped spring toward the planned angle, its torque bounded),
/// so every torque it makes is what the thimbles measure.
#include <array>

#include "telehand/core/joint_model.h"
#include "telehand/devices/simulated_mf2.h"

namespace telehand::devices {

struct SweepPlan {
  std::array<double, kAxes> lo_deg{};  ///< sweep limits per axis
  std::array<double, kAxes> hi_deg{};
  std::array<double, kAxes> hold_deg{};  ///< where an axis is held while another moves
  double seconds_per_axis = 20.0;
  double frequency_hz = 0.5;  ///< slow: manipulation is < 40 N/s (paper III)
  /// A clinician does not mobilize at one exact frequency: within each axis' sweep the
  /// frequency swings smoothly between frequency_hz and this fraction of it (1: a pure
  /// sinusoid), once every `spread_cycles` cycles at frequency_hz. Then the acceleration at
  /// an angle varies from cycle to cycle, and the fit can tell the moving mass from the
  /// stiffness (in a pure sinusoid the acceleration is −ω²·(angle − centre)).
  double frequency_spread = 0.5;
  double spread_cycles = 4.0;
  double ramp_s = 1.0;                ///< into and out of each axis' sweep
  double stiffness_nm_per_rad = 4.0;  ///< the clinician's servo at the grip
  double damping_nms_per_rad = 0.006;
  /// The servo's torque is bounded per axis (0: unbounded), N·m at the grip.
  double max_torque_nm = 0.0;
  bool repeat = true;  ///< start again with flexion after the last axis
  /// Instead of one axis at a time: flexion and abduction together, at frequency_hz and
  /// 3.7 times it (incommensurate: the pair covers the plane), axial rotation held. For
  /// joints whose axes are coupled.
  bool combined = false;

  double durationS() const noexcept { return kAxes * seconds_per_axis; }
};

/// Sweep limits for a joint: in each direction, `wall_deg` past the end of the range (into
/// the end stop), or the angle where the holding force reaches `max_force_n`, whichever
/// comes first; the planned angle leads that by the servo's lag under the holding force
/// there. The servo's torque is bounded at 1.2 × max_force_n at the lever arm. Axes are held
/// at their rest angle.
SweepPlan planSweep(const JointModelParams& joint, double max_force_n = 18.0,
                    double wall_deg = 3.0);

class SweepOperator final : public Operator {
 public:
  explicit SweepOperator(const SweepPlan& plan) : plan_(plan) {}
  Vec3 torqueNm(double t_s, const Vec3& angles_rad, const Vec3& rates_rad_s) noexcept override;
  /// The planned angles at t.
  Vec3 target(double t_s) const noexcept;
  const SweepPlan& plan() const noexcept { return plan_; }

 private:
  SweepPlan plan_;
};

}  // namespace telehand::devices
