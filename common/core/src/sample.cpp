#include "telehand/core/sample.h"

#include <cmath>

namespace telehand {

std::optional<std::string> firstNonFinite(const Sample& s) {
  for (int k = 0; k < 2; ++k) {
    const auto& f = s.fingers[k];
    const std::string finger = k == 0 ? "fingers[0] (thumb)" : "fingers[1] (index)";
    for (int i = 0; i < 3; ++i) {
      if (!std::isfinite(f.position_m[i])) return finger + ".position_m[" + std::to_string(i) + "]";
      if (!std::isfinite(f.command_n[i])) return finger + ".command_n[" + std::to_string(i) + "]";
    }
    for (int i = 0; i < 4; ++i) {
      if (!std::isfinite(f.orientation_q[i])) {
        return finger + ".orientation_q[" + std::to_string(i) + "]";
      }
      if (!std::isfinite(f.fsr_n[i])) return finger + ".fsr_n[" + std::to_string(i) + "]";
    }
    if (!std::isfinite(f.tangential_n)) return finger + ".tangential_n";
    if (!std::isfinite(f.normal_n)) return finger + ".normal_n";
  }
  for (int i = 0; i < 3; ++i) {
    if (!std::isfinite(s.mcp_angles_rad[i])) return "mcp_angles_rad[" + std::to_string(i) + "]";
    if (!std::isfinite(s.mcp_torque_nm[i])) return "mcp_torque_nm[" + std::to_string(i) + "]";
  }
  return std::nullopt;
}

PerFinger<Vec3> thimblePositions(const Sample& s) noexcept {
  PerFinger<Vec3> p;
  for (int k = 0; k < 2; ++k) {
    p[k] = Vec3(s.fingers[k].position_m[0], s.fingers[k].position_m[1], s.fingers[k].position_m[2]);
  }
  return p;
}

}  // namespace telehand
