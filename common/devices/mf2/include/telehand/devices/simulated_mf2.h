#pragma once
/// A simulated MF-2 held by a virtual operator who performs the paper's MCP mobilization:
/// pushes the proximal phalanx in flexion with a force that rises to a band (12-16 N at
/// reference scale) and oscillates across it at a set frequency, against whatever force the
/// loop renders back. Deterministic for a given seed and clock. The operator's skill
/// (OperatorConfig: force bias, frequency error, amplitude scale, tremor) makes it a
/// student; all at their defaults it is the clinician.
///
/// The device itself is the MF-2 device model (common/mf2_device.h): the thimble poses go
/// through inverse kinematics to encoder counts and back through forward kinematics (so
/// positions carry encoder quantization), forces are synthesized as raw FSR ADC counts and
/// calibrated with the thimbles' calibration (quantization, saturation and dead-channel
/// flags included), and force commands are rendered through the actuators: J^T F, the
/// actuators' torque limits, and back to the fingertip forces those torques make.

#include "telehand/config/config.h"
#include "telehand/core/clock.h"
#include "telehand/core/joint_model.h"
#include "telehand/devices/device.h"
#include "telehand/devices/mf2_device.h"
#include "telehand/devices/simulated_hardware.h"

namespace telehand::devices {

/// What the operator's hand and the device's links feel like, in joint space at the grip.
struct SimulatedMf2Dynamics {
  double mass_kg = 0.05;              ///< finger + thimble + link mass moved at the grip
  double operator_damping = 1.0;      ///< N·s/m at the grip: the operator's hand is viscous
  double operator_stiffness = 200.0;  ///< N/m holding abduction and axial rotation at neutral
  double half_width_m = 0.008;        ///< thimble centre to phalanx axis
  double pad_angle_deg = 20.0;        ///< how the normal load splits over FSRs 1 (end) and 4 (pad)
  /// Integration steps per 1 ms sample. One steps the grip with the loop; a capture rig takes
  /// more, so that its record samples the finger's continuous motion, not the step's own.
  int substeps = 1;
};

/// Who holds the thimbles: the torque per MCP axis (reference scale, N·m) their fingers
/// press on the phalanx at time t. Called from the device's 1 kHz step: no allocation.
class Operator {
 public:
  virtual ~Operator() = default;
  virtual Vec3 torqueNm(double t_s, const Vec3& angles_rad, const Vec3& rates_rad_s) noexcept = 0;
};

/// A real finger's passive joint, for captures of joints the cubic model cannot express
/// (e.g. coupled axes). Called from the device's 1 kHz step: no allocation.
class PatientJoint {
 public:
  virtual ~PatientJoint() = default;
  virtual Vec3 passiveTorqueNm(const Vec3& angles_rad, const Vec3& rates_rad_s) const noexcept = 0;
};

class SimulatedMf2 final : public Device {
 public:
  SimulatedMf2(const JointModelParams& geometry, const OperatorConfig& op, const Clock& clock,
               const SimulatedMf2Dynamics& dyn = {},
               const mf2::Mf2Description& device = mf2::defaultMf2());

  /// A real finger in the grip (capture): its passive torques act on the phalanx besides
  /// whatever the device renders. Call before the first read.
  void setPatient(const JointModelParams& truth);
  /// As above with any joint; not owned, must outlive the device.
  void setPatient(const PatientJoint* joint) noexcept { custom_patient_ = joint; }
  /// Where the phalanx starts (MCP angles, at rest): e.g. a patient's resting posture instead
  /// of the neutral pose. Call before the first read.
  void setPose(const Vec3& angles_rad) noexcept {
    angles_ = angles_rad;
    rates_.setZero();
  }
  /// Replace the built-in mobilization (flexion force band, other axes held) by a script.
  /// The operator must outlive the device.
  void setOperator(Operator* op) noexcept { script_ = op; }
  /// Thimble measurement error expressed per MCP axis: the force each axis sees through the
  /// thimbles gets N(0, sigma^2) newtons at the lever arm (reference scale), independently
  /// per sample and axis; the phalanx moves under the true force.
  void setAxisForceNoise(double sigma_n) noexcept { axis_noise_n_ = sigma_n; }

  bool read(DeviceSample& out) noexcept override;
  bool write(const ForceCommand& cmd) noexcept override;
  DeviceStatus status() const noexcept override { return DeviceStatus::kOk; }
  std::string_view name() const noexcept override { return "sim"; }
  /// The grip's mass; a force written now acts from the next step.
  DeviceDynamics dynamics() const noexcept override { return {dyn_.mass_kg, 0}; }

  /// Ground truth for tests.
  const Vec3& angles() const noexcept { return angles_; }
  const Vec3& rates() const noexcept { return rates_; }
  /// Force rendered at each thimble after the actuators (device frame) and their torques.
  const PerFinger<Vec3>& renderedForce() const noexcept { return hw_.rendered(); }
  const mf2::ActuatorTorques& actuatorTorques() const noexcept { return hw_.torques(); }
  const mf2::Mf2Kinematics& kinematics() const noexcept { return hw_.kinematics(); }
  /// Force the operator means to apply now, reference scale (N): the band's oscillation
  /// (amplitude_scale, frequency_hz + frequency_error_hz) plus force_bias_n, built up over
  /// ramp_s. The tremor comes on top (tremorN).
  double targetForceN(double t_s) const noexcept;
  /// The tremor force of the last step, reference scale (N): 0 unless tremor_n > 0.
  double tremorN() const noexcept { return tremor_n_; }

 private:
  void advanceTo(int64_t t_ns) noexcept;
  /// One step of dt, `into_s` into the sample's millisecond; `sampled`: the last before the
  /// sample (the FSRs' noise and the tremor are drawn once a sample).
  void integrate(double dt, double into_s, bool sampled) noexcept;
  PerFinger<Quat> thimbleOrientations() const noexcept;
  bool updatePose(const PerFinger<Quat>& thimbles, PerFinger<mf2::ThimblePose>& measured) noexcept;

  JointModel geometry_;  // joint frame and lever arm; the stiffness comes from what is rendered
  SimulatedMf2Hardware hw_;
  JointModel patient_{JointModelParams{}};
  bool has_patient_ = false;
  const PatientJoint* custom_patient_ = nullptr;
  Operator* script_ = nullptr;
  double axis_noise_n_ = 0.0;
  OperatorConfig op_;
  const Clock& clock_;
  SimulatedMf2Dynamics dyn_;
  GaussianNoise noise_;
  // Tremor: white noise from its own generator (the clinician's sensor noise is the same with
  // or without it) through the 8-12 Hz band-pass.
  GaussianNoise tremor_noise_;
  TremorFilter tremor_;
  double tremor_n_ = 0;

  int64_t start_ns_;
  int64_t sim_ns_;
  uint64_t seq_ = 0;
  Vec3 angles_ = Vec3::Zero();
  Vec3 rates_ = Vec3::Zero();
  PerFinger<Vec3> operator_force_{Vec3::Zero(), Vec3::Zero()};
};

}  // namespace telehand::devices
