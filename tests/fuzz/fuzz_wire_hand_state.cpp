// libFuzzer target: a HandState from the network (CDR through Cyclone's deserializer, as
// the watch and remote viewers take it) through the server's HandState deadband, and its
// fields (HandStateFields) back to the wire with toWire.
// Properties: the deadband sends the first state and never reads beyond the message;
// toWire packs at most 32 joint angles and 24 bone poses whatever it is given, keeps every
// value it packs, and leaves the Bullet-only fields zero for a shared-joint-model state.
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>

#include "cdr_input.h"
#include "telehand/protocol/deadband.h"
#include "telehand/protocol/wire.h"

using namespace telehand;

using fuzz::check;

namespace {
bool same(double a, double b) { return std::memcmp(&a, &b, sizeof a) == 0; }
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  fuzz::CdrSample<telehand_msg_HandState> in(telehand_msg_HandState_desc);
  if (!in.read(data, size)) return 0;
  const telehand_msg_HandState& h = in.get();

  DeadbandConfig dc;
  dc.weber = static_cast<double>(h.seq % 21) / 100.0;
  HandStateDeadband deadband(dc);
  check(deadband.admit(h, h.source_time_ns));
  (void)deadband.admit(h, h.source_time_ns);

  // The wire's counts are not trusted: fill as many entries as it claims (the capacity is
  // what toWire must respect), cycling through the ones the message holds.
  HandStateFields f;
  f.session_id = h.session_id;
  f.source_time_ns = h.source_time_ns;
  f.bullet = h.source == telehand_msg_HAND_SOURCE_BULLET;
  f.device_rate_hz = h.device_rate_hz;
  f.device_lost = h.device_lost;
  f.device_overruns = h.device_overruns;
  f.model_version = h.model_version;
  f.have_device = (h.seq & 1u) != 0;
  f.device_seq = h.device_seq;
  f.device_time_ns = h.device_time_ns;
  f.mcp_angles_rad = Vec3(h.mcp_angles_rad[0], h.mcp_angles_rad[1], h.mcp_angles_rad[2]);
  f.mcp_torque_nm = Vec3(h.mcp_torque_nm[0], h.mcp_torque_nm[1], h.mcp_torque_nm[2]);
  for (int k = 0; k < 2; ++k) {
    f.fingertip_m[k] = Vec3(h.fingertip_m[k][0], h.fingertip_m[k][1], h.fingertip_m[k][2]);
    f.fingertip_force_n[k] =
        Vec3(h.fingertip_force_n[k][0], h.fingertip_force_n[k][1], h.fingertip_force_n[k][2]);
    f.sphere_m[k] = Vec3(h.sphere_m[k][0], h.sphere_m[k][1], h.sphere_m[k][2]);
    f.contact_force_n[k] =
        Vec3(h.contact_force_n[k][0], h.contact_force_n[k][1], h.contact_force_n[k][2]);
  }
  f.applied_force_ref_n = h.applied_force_ref_n;
  const std::size_t dofs = std::min<std::size_t>(h.dof_count, 200);
  const std::size_t bones = std::min<std::size_t>(h.bone_count, 200);
  for (std::size_t i = 0; i < dofs; ++i) f.joint_angles_rad.push_back(h.joint_angles_rad[i % 32]);
  for (std::size_t b = 0; b < bones; ++b) {
    const double* v = h.bone_pose[b % 24];
    f.bone_poses.push_back({Vec3(v[0], v[1], v[2]), Quat(v[3], v[4], v[5], v[6])});
  }

  telehand_msg_HandState out;
  toWire(f, out);
  check(out.dof_count <= 32 && out.bone_count <= 24);
  check(out.session_id == f.session_id && out.model_version == f.model_version);
  if (!f.have_device) {
    check(out.dof_count == 0 && out.bone_count == 0 && out.device_seq == 0);
    check(out.source == telehand_msg_HAND_SOURCE_SHARED_JOINT_MODEL);
    return 0;
  }
  for (int i = 0; i < 3; ++i) check(same(out.mcp_angles_rad[i], f.mcp_angles_rad[i]));
  if (!f.bullet) {
    check(out.dof_count == 0 && out.bone_count == 0);
    return 0;
  }
  check(out.dof_count == std::min<std::size_t>(dofs, 32));
  check(out.bone_count == std::min<std::size_t>(bones, 24));
  for (std::size_t i = 0; i < out.dof_count; ++i) {
    check(same(out.joint_angles_rad[i], f.joint_angles_rad[i]));
  }
  for (std::size_t b = 0; b < out.bone_count; ++b) {
    check(same(out.bone_pose[b][0], f.bone_poses[b].position_m.x()));
  }
  return 0;
}
