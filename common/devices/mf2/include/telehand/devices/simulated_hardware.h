#pragma once
/// The parts every simulated MF-2 shares, whoever holds its thimbles (the mobilization's
/// SimulatedMf2, the massage's SimulatedMassageMf2): the MF-2 device model as a driver would
/// see it, and the operator's noise sources.
///
///  - Poses: the true thimble poses go through inverse kinematics to encoder counts and back
///    through forward kinematics, so the positions carry the encoders' quantization.
///  - FSRs: the force a finger presses on its thimble is split over the four sensors (the
///    normal load over 1 (end) and 4 (pad) at the pad angle, the side load over 2 or 3),
///    noise added in newtons, turned into raw 12-bit ADC counts through the thimble's
///    calibration and calibrated back (quantization, saturation and dead-channel flags).
///  - Actuators: a force command becomes joint torques J^T F, scaled down together when one
///    exceeds its limit (the direction is kept), and the fingertip forces those torques make.
///
/// Everything here is allocation-free and noexcept after construction.
#include <array>
#include <cstdint>
#include <random>

#include "telehand/core/math.h"
#include "telehand/devices/device.h"
#include "telehand/devices/mf2_device.h"

namespace telehand::devices {

/// A seeded source of standard normal numbers.
class GaussianNoise {
 public:
  explicit GaussianNoise(uint64_t seed) noexcept : rng_(seed) {}
  double operator()() noexcept { return dist_(rng_); }

 private:
  std::mt19937_64 rng_;
  std::normal_distribution<double> dist_{0.0, 1.0};
};

/// Physiological tremor of the hand: white noise through an 8-12 Hz band-pass (docs/facts.md
/// "Tremor and smoothness"), scaled so that unit white noise comes out at unit RMS.
class TremorFilter {
 public:
  static constexpr double kLowHz = 8.0;
  static constexpr double kHighHz = 12.0;
  /// Stepped at 1 kHz.
  TremorFilter() noexcept : TremorFilter(1e-3) {}
  /// `step_s`: the interval it is stepped at.
  explicit TremorFilter(double step_s) noexcept;
  /// One step: the band-passed, unit-RMS value for this white-noise input.
  double step(double white) noexcept { return gain_ * raw(white); }
  void reset() noexcept { state_ = {}; }

 private:
  double raw(double x) noexcept;
  double b0_ = 0, b2_ = 0, a1_ = 0, a2_ = 0, gain_ = 0;
  std::array<std::array<double, 4>, 2> state_{};  // per section: x1, x2, y1, y2
};

/// The MF-2 device model of a simulation: measured poses, FSR readings and rendered forces.
class SimulatedMf2Hardware {
 public:
  /// `pad_angle_deg`: how the normal load splits over FSRs 1 (end, sin) and 4 (pad, cos).
  SimulatedMf2Hardware(const mf2::Mf2Description& device, double pad_angle_deg);

  /// The poses a driver reads for these true thimble poses (through the encoders); keeps the
  /// actuator angles for render(). False when a pose is out of the linkage's reach.
  bool measurePoses(const PerFinger<mf2::ThimblePose>& truth,
                    PerFinger<mf2::ThimblePose>& measured) noexcept;
  /// A pose has been measured: render() has actuator angles to work with.
  bool hasPose() const noexcept { return have_q_; }

  /// The FSR readings of `finger` when the finger presses `pressed_device` (device frame) on
  /// its thimble of orientation `thimble`: each sensor gets sigma_n · noise() newtons (drawn
  /// for all four sensors, in order, whatever sigma_n). Fills fsr_n and fsr_fault_mask.
  void readFsr(int finger, const Quat& thimble, const Vec3& pressed_device, double sigma_n,
               GaussianNoise& noise, FingerSample& out) noexcept;

  /// Render a command through the actuators at the last measured pose; false (nothing
  /// rendered) without a pose or when the Jacobian is singular.
  bool render(const PerFinger<Vec3>& force_n) noexcept;
  /// Actuators off: nothing rendered.
  void off() noexcept;

  /// Force rendered at each thimble after the actuators (device frame) and their torques.
  const PerFinger<Vec3>& rendered() const noexcept { return rendered_; }
  const mf2::ActuatorTorques& torques() const noexcept { return tau_act_; }
  const mf2::Mf2Kinematics& kinematics() const noexcept { return kin_; }

 private:
  mf2::Mf2Kinematics kin_;
  PerFinger<mf2::FsrMonitor> fsr_;
  double pad_sin_, pad_cos_;
  mf2::ActuatorAngles q_act_ = mf2::ActuatorAngles::Zero();
  bool have_q_ = false;
  PerFinger<Vec3> rendered_{Vec3::Zero(), Vec3::Zero()};
  mf2::ActuatorTorques tau_act_ = mf2::ActuatorTorques::Zero();
};

}  // namespace telehand::devices
