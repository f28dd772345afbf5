#pragma once
/// The capture rig: a simulated MF-2 with a patient's finger in its thimbles, moved through
/// each axis by a sweeping clinician with the actuators off (paper section IV.B). The client
/// runs it through its haptic loop and streams it like a real capture; synthetic captures
/// step it directly, recording each tick as the loop records a capture (the output is zero,
/// so no loop is needed).
#include <memory>

#include "telehand/config/config.h"
#include "telehand/core/clock.h"
#include "telehand/core/joint_model.h"
#include "telehand/core/sample.h"
#include "telehand/devices/mf2_device.h"
#include "telehand/devices/simulated_mf2.h"
#include "telehand/devices/sweep_operator.h"

namespace telehand::devices {

/// The proximal phalanx's moment of inertia about the MCP, kg·m² (docs/facts.md, "Ground
/// truth"): it moves with the grip, so the rig adds it to the mass at the thimbles.
inline constexpr double kPhalanxInertiaKgM2 = 2.1e-5;

struct CaptureRigOptions {
  /// The joint frame and lever arm the device is set up with; a capture measures real
  /// forces, so its force scale is 1.
  JointModelParams geometry = healthyIndexMcp();
  /// The finger in the grip.
  JointModelParams patient = healthyIndexMcp();
  /// A finger the cubics cannot express (coupled axes): moves instead of `patient`. Not
  /// owned; must outlive the rig.
  const PatientJoint* patient_joint = nullptr;
  SweepPlan plan;
  OperatorConfig op;          ///< FSR noise and seed (the band and frequency are unused)
  double axis_noise_n = 0.0;  ///< thimble error per axis, N RMS (paper: 1.43)
  mf2::Mf2Description device = mf2::defaultMf2();
  /// Integration steps of the finger per 1 ms sample (SimulatedMf2Dynamics::substeps). At 10
  /// the record samples the finger's continuous motion, as a real finger's would be: a
  /// sample's force goes with the angle and rate at its own instant (0.1 ms before it). With
  /// 1, semi-implicit Euler at the loop's rate, the force of a sample goes with the angle a
  /// sample before and the rate half a sample before that, a discretization no finger has
  /// (docs/capture.md, "Known limits": what that changed for the fit).
  int substeps = 10;
};

class CaptureRig {
 public:
  CaptureRig(const CaptureRigOptions& o, const Clock& clock);
  CaptureRig(const CaptureRig&) = delete;
  CaptureRig& operator=(const CaptureRig&) = delete;

  /// The device, for a haptic loop in capture mode.
  SimulatedMf2& device() noexcept { return *device_; }
  const SweepOperator& clinician() const noexcept { return clinician_; }

  /// One tick without a loop, at the clock's time: read the device, command zero force and
  /// record the tick with sequence number `seq` as the loop records a capture. False when
  /// the device gave no sample.
  bool step(uint64_t seq, Sample& s) noexcept;

 private:
  SweepOperator clinician_;
  std::unique_ptr<SimulatedMf2> device_;
  JointProxy proxy_;
  const Clock& clock_;
  int64_t wall_offset_ns_;
  DeviceSample reading_{};
};

}  // namespace telehand::devices
