#include "telehand/devices/mf2_calibration.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>

namespace telehand::devices {

Mf2ModelCalibration::Mf2ModelCalibration(const mf2::Mf2Description& device, const Mf2Motors& motors)
    : kin_(device),
      motors_(motors),
      fsr_{mf2::FsrMonitor(device.thimbles[kThumb]), mf2::FsrMonitor(device.thimbles[kIndex])} {}

void Mf2ModelCalibration::reset() noexcept {
  const auto& d = kin_.description();
  fsr_ = {mf2::FsrMonitor(d.thimbles[kThumb]), mf2::FsrMonitor(d.thimbles[kIndex])};
}

mf2::EncoderCounts Mf2ModelCalibration::encoderCounts(const proto::StatePacket& raw) noexcept {
  mf2::EncoderCounts c;
  for (int i = 0; i < proto::kActuators; ++i) c.actuators[i] = raw.actuator_counts[i];
  for (int k = 0; k < 2; ++k) {
    for (int j = 0; j < mf2::kGimbalAxes; ++j) c.gimbal[k][j] = raw.gimbal_counts[3 * k + j];
  }
  return c;
}

bool Mf2ModelCalibration::toFingers(const proto::StatePacket& raw,
                                    PerFinger<FingerSample>& out) noexcept {
  const mf2::JointAngles q = kin_.anglesFromCounts(encoderCounts(raw));
  // Angles past a mechanical stop by more than calibration slack cannot be real.
  const auto& d = kin_.description();
  auto beyond = [](const mf2::EncoderCalibration& e, double a) {
    return a < e.min_rad - kStopSlackRad || a > e.max_rad + kStopSlackRad;
  };
  for (int i = 0; i < proto::kActuators; ++i) {
    if (beyond(d.actuator_encoders[i], q.actuators[i])) return false;
  }
  for (int k = 0; k < 2; ++k) {
    for (int j = 0; j < mf2::kGimbalAxes; ++j) {
      if (beyond(d.gimbal_encoders[k][j], q.gimbal[k][j])) return false;
    }
  }
  PerFinger<mf2::ThimblePose> pose;
  if (!kin_.forward(q, pose)) return false;
  for (int k = 0; k < 2; ++k) {
    out[k].position_m = pose[k].position_m;
    out[k].orientation = pose[k].orientation;
    std::array<uint16_t, mf2::kFsrPerThimble> counts{};
    for (int i = 0; i < mf2::kFsrPerThimble; ++i) counts[i] = raw.fsr_raw[4 * k + i];
    const mf2::ThimbleReading r = fsr_[k].update(counts);
    out[k].fsr_n = r.fsr_n;
    out[k].fsr_fault_mask = r.faultMask();
  }
  return true;
}

void Mf2ModelCalibration::toCurrents(const PerFinger<Vec3>& force_n, const proto::StatePacket& raw,
                                     CurrentsMa& out) const noexcept {
  out = {};
  mf2::ActuatorTorques tau;
  const mf2::JointAngles q = kin_.anglesFromCounts(encoderCounts(raw));
  if (!kin_.actuatorTorques(q.actuators, force_n, tau) || !std::isfinite(tau.sum())) return;
  // Above an actuator's torque or the driver's current limit, all torques are scaled down
  // together: the force keeps its direction.
  const auto& limit = kin_.description().max_torque_nm;
  double scale = 1.0;
  for (int i = 0; i < proto::kActuators; ++i) {
    const double max_nm = std::min(limit[i], motors_.max_current_a * motors_.nm_per_amp[i]);
    if (std::abs(tau[i]) > max_nm) scale = std::min(scale, max_nm / std::abs(tau[i]));
  }
  for (int i = 0; i < proto::kActuators; ++i) {
    const double ma =
        std::clamp(tau[i] * scale / motors_.nm_per_amp[i] * 1000.0, -32767.0, 32767.0);
    out[i] = static_cast<int16_t>(std::lround(ma));
  }
}

double Mf2ModelCalibration::lightestMassKg(const proto::StatePacket& raw) const noexcept {
  const mf2::JointAngles q = kin_.anglesFromCounts(encoderCounts(raw));
  mf2::Jacobian j;
  if (!(motors_.inertia_kgm2 > 0.0) || !kin_.jacobian(q.actuators, j) || !j.allFinite()) return 0.0;
  // The thimbles' mobility (their acceleration per force): J·I⁻¹·Jᵀ; its largest eigenvalue is
  // the inverse of the lightest mass a force at the thimbles meets.
  const Eigen::Matrix<double, 6, 6> mobility = j * j.transpose() / motors_.inertia_kgm2;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> eig(mobility,
                                                                       Eigen::EigenvaluesOnly);
  if (eig.info() != Eigen::Success) return 0.0;
  const double largest = eig.eigenvalues().maxCoeff();
  return largest > 0.0 && std::isfinite(largest) ? 1.0 / largest : 0.0;
}

}  // namespace telehand::devices
