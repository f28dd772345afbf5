#include "telehand/devices/record.h"

#include "telehand/core/thimble.h"

namespace telehand::devices {

Vec3 recordTick(const DeviceSample& d, const PerFinger<Vec3>& command_n,
                const ProxyOutput& rendered, Sample& s) noexcept {
  s.flags |= (static_cast<uint32_t>(d.fingers[kThumb].fsr_fault_mask & 0xFu) |
              static_cast<uint32_t>(d.fingers[kIndex].fsr_fault_mask & 0xFu) << 4)
             << sample_flags::kFsrFaultShift;
  Vec3 applied = Vec3::Zero();
  for (int k = 0; k < 2; ++k) {
    const auto& f = d.fingers[k];
    auto& w = s.fingers[k];
    const ThimbleForces tf = thimbleForces(f.fsr_n);
    applied += thimbleForceVector(tf, f.orientation);
    w.tangential_n = static_cast<float>(tf.tangential_n);
    w.normal_n = static_cast<float>(tf.normal_n);
    for (int i = 0; i < 3; ++i) {
      w.position_m[i] = f.position_m[i];
      w.command_n[i] = command_n[k][i];
    }
    w.orientation_q[0] = f.orientation.w();
    w.orientation_q[1] = f.orientation.x();
    w.orientation_q[2] = f.orientation.y();
    w.orientation_q[3] = f.orientation.z();
    for (int i = 0; i < 4; ++i) w.fsr_n[i] = f.fsr_n[i];
  }
  for (int i = 0; i < 3; ++i) {
    s.mcp_angles_rad[i] = rendered.angles_rad[i];
    s.mcp_torque_nm[i] = rendered.torque_ref_nm[i];
  }
  return applied;
}

}  // namespace telehand::devices
