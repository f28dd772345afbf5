#pragma once
// A DeviceState's grip as the client's loop records it when the thimbles pinch the phalanx
// at the given MCP angles (8 mm apart): thimble positions, orientations and the proxy angles.
#include "telehand.h"
#include "telehand/core/joint_model.h"

namespace telehand::test {

inline void setGrip(telehand_msg_DeviceState& d, const JointModel& joint, const Vec3& angles) {
  const PerFinger<Vec3> p = joint.gripFromAngles(angles, 0.008);
  for (int k = 0; k < 2; ++k) {
    const Quat q = joint.thimbleOrientation(k, angles);
    const double qv[4] = {q.w(), q.x(), q.y(), q.z()};
    for (int j = 0; j < 3; ++j) d.fingers[k].position_m[j] = p[k][j];
    for (int j = 0; j < 4; ++j) d.fingers[k].orientation_q[j] = qv[j];
  }
  for (int j = 0; j < 3; ++j) d.mcp_angles_rad[j] = angles[j];
}

}  // namespace telehand::test
