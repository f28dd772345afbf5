#pragma once
/// A simulated MF-2 held by a virtual operator who performs the paper's MCP mobilization:
/// pushes the proximal phalanx in flexion with a force that rises to a band (12-16 N at
/// reference scale) and oscillates across it at a set frequency, against whatever force the
/// loop renders back. Deterministic for a given seed and clock.
#include <random>

#include "client/device/device.h"
#include "telehand/common/clock.h"
#include "telehand/common/config.h"
#include "telehand/common/joint_model.h"

namespace telehand::client::device {

/// What the operator's hand and the device's links feel like, in joint space at the grip.
struct SimulatedMf2Dynamics {
  double mass_kg = 0.05;            ///< finger + thimble + link mass moved at the grip
  double operator_damping = 1.0;    ///< N·s/m at the grip: the operator's hand is viscous
  double operator_stiffness = 200.0;///< N/m holding abduction and axial rotation at neutral
  double half_width_m = 0.008;      ///< thimble centre to phalanx axis
  double pad_angle_deg = 20.0;      ///< how the normal load splits over FSRs 1 (end) and 4 (pad)
};

class SimulatedMf2 final : public Device {
 public:
  SimulatedMf2(const JointModelParams& geometry, const OperatorConfig& op, const Clock& clock,
               const SimulatedMf2Dynamics& dyn = {});

  bool read(DeviceSample& out) noexcept override;
  bool write(const ForceCommand& cmd) noexcept override;
  DeviceStatus status() const noexcept override { return DeviceStatus::kOk; }
  std::string_view name() const noexcept override { return "sim"; }

  /// Ground truth for tests.
  const Vec3& angles() const noexcept { return angles_; }
  /// Force the operator wants to apply now, reference scale (N).
  double targetForceN(double t_s) const noexcept;

 private:
  void advanceTo(int64_t t_ns) noexcept;
  void integrate(double dt) noexcept;
  FsrReadings fsrFor(int finger, const Vec3& force_device) noexcept;

  JointModel geometry_;  // joint frame and lever arm; the stiffness comes from what is rendered
  OperatorConfig op_;
  const Clock& clock_;
  SimulatedMf2Dynamics dyn_;
  std::mt19937_64 rng_;
  std::normal_distribution<double> noise_{0.0, 1.0};

  int64_t start_ns_;
  int64_t sim_ns_;
  uint64_t seq_ = 0;
  Vec3 angles_ = Vec3::Zero();
  Vec3 rates_ = Vec3::Zero();
  ForceCommand command_;
  PerFinger<Vec3> operator_force_{Vec3::Zero(), Vec3::Zero()};
};

}  // namespace telehand::client::device
