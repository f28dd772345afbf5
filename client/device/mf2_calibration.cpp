#include "client/device/mf2_calibration.h"

#include <algorithm>
#include <cmath>

namespace telehand::client::device {

void LinearMf2Calibration::toFingers(const proto::StatePacket& raw,
                                     PerFinger<FingerSample>& out) const noexcept {
  for (int k = 0; k < 2; ++k) {
    FingerSample& f = out[k];
    for (int i = 0; i < 3; ++i) {
      f.position_m[i] = p_.origin_m[k][i] + raw.actuator_counts[3 * k + i] / p_.counts_per_m;
    }
    const double z = raw.gimbal_counts[3 * k] / p_.counts_per_rad;
    const double y = raw.gimbal_counts[3 * k + 1] / p_.counts_per_rad;
    const double x = raw.gimbal_counts[3 * k + 2] / p_.counts_per_rad;
    f.orientation = Quat(Eigen::AngleAxisd(z, Vec3::UnitZ()) * Eigen::AngleAxisd(y, Vec3::UnitY()) *
                         Eigen::AngleAxisd(x, Vec3::UnitX()));
    for (int i = 0; i < 4; ++i) {
      const int c = 4 * k + i;
      const int counts = std::max(0, raw.fsr_raw[c] - p_.fsr_zero_counts[c]);
      f.fsr_n[i] = static_cast<float>(counts * p_.fsr_n_per_count);
    }
  }
}

void LinearMf2Calibration::toCurrents(const PerFinger<Vec3>& force_n, const proto::StatePacket&,
                                      CurrentsMa& out) const noexcept {
  const double limit_ma = p_.max_current_a * 1000.0;
  for (int k = 0; k < 2; ++k) {
    for (int i = 0; i < 3; ++i) {
      double ma = force_n[k][i] / p_.n_per_amp * 1000.0;
      if (!std::isfinite(ma)) ma = 0.0;
      out[3 * k + i] = static_cast<int16_t>(std::lround(std::clamp(ma, -limit_ma, limit_ma)));
    }
  }
  out[6] = 0;  // the redundant base joint holds still in this stand-in
}

}  // namespace telehand::client::device
