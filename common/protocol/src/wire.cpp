#include "telehand/protocol/wire.h"

#include <cmath>

namespace telehand {

void toWire(const JointModelParams& p, uint64_t session_id, telehand_msg_JointModel& out) {
  out.session_id = session_id;
  out.version = p.version;
  out.kind = p.knn ? telehand_msg_STIFFNESS_KNN : telehand_msg_STIFFNESS_CUBIC;
  for (int i = 0; i < kAxes; ++i) {
    const auto& a = p.axes[static_cast<std::size_t>(i)];
    for (int c = 0; c < 4; ++c) out.axes[i].coeffs[c] = a.coeffs[static_cast<std::size_t>(c)];
    out.axes[i].min_deg = a.min_deg;
    out.axes[i].max_deg = a.max_deg;
  }
  out.lever_arm_m = p.lever_arm_m;
  out.force_scale = p.force_scale;
  out.damping_nms_per_rad = p.damping_nms_per_rad;
  for (int i = 0; i < kAxes; ++i) out.neutral_zone_deg[i] = p.neutral_zone_deg[static_cast<std::size_t>(i)];
  out.speed_gain_s_per_rad = p.speed_gain_s_per_rad;
  for (int i = 0; i < 3; ++i) out.joint_origin_m[i] = p.joint_origin_m[i];
  out.joint_orientation_q[0] = p.joint_orientation.w();
  out.joint_orientation_q[1] = p.joint_orientation.x();
  out.joint_orientation_q[2] = p.joint_orientation.y();
  out.joint_orientation_q[3] = p.joint_orientation.z();
  copyString(out.case_name, std::string_view(p.case_name.data()));
  for (int i = 0; i < 3; ++i) out.grip_offset_rad[i] = p.grip_offset_rad[i];
}

std::optional<JointModelParams> fromWire(const telehand_msg_JointModel& m, std::string* why) {
  auto bad = [why](std::string w) -> std::optional<JointModelParams> {
    if (why) *why = std::move(w);
    return std::nullopt;
  };
  JointModelParams p;
  p.version = m.version;
  for (int i = 0; i < kAxes; ++i) {
    auto& a = p.axes[static_cast<std::size_t>(i)];
    for (int c = 0; c < 4; ++c) {
      if (!std::isfinite(m.axes[i].coeffs[c])) {
        return bad(std::string(kAxisNames[static_cast<std::size_t>(i)]) + " coefficient " +
                   std::to_string(c) + " is not finite");
      }
      a.coeffs[static_cast<std::size_t>(c)] = m.axes[i].coeffs[c];
    }
    a.min_deg = m.axes[i].min_deg;
    a.max_deg = m.axes[i].max_deg;
    if (!(a.min_deg < a.max_deg)) {
      return bad(std::string(kAxisNames[static_cast<std::size_t>(i)]) + " range is empty");
    }
  }
  p.lever_arm_m = m.lever_arm_m;
  p.force_scale = m.force_scale;
  p.damping_nms_per_rad = m.damping_nms_per_rad;
  for (int i = 0; i < kAxes; ++i) {
    p.neutral_zone_deg[static_cast<std::size_t>(i)] = m.neutral_zone_deg[i];
    if (!(m.neutral_zone_deg[i] >= 0.0 && m.neutral_zone_deg[i] <= 30.0)) {
      return bad(std::string(kAxisNames[static_cast<std::size_t>(i)]) + " neutral zone out of [0, 30] deg");
    }
  }
  p.speed_gain_s_per_rad = m.speed_gain_s_per_rad;
  if (!(p.speed_gain_s_per_rad >= 0.0 && p.speed_gain_s_per_rad <= 20.0)) {
    return bad("speed_gain_s_per_rad out of [0, 20]");
  }
  if (!(p.lever_arm_m > 0.0 && p.lever_arm_m < 0.2)) return bad("lever_arm_m out of (0, 0.2)");
  if (!(p.force_scale > 0.0 && p.force_scale <= 1.0)) return bad("force_scale out of (0, 1]");
  if (!(p.damping_nms_per_rad >= 0.0 && p.damping_nms_per_rad < 1.0)) {
    return bad("damping_nms_per_rad out of [0, 1)");
  }
  p.joint_origin_m = Vec3(m.joint_origin_m[0], m.joint_origin_m[1], m.joint_origin_m[2]);
  p.joint_orientation = Quat(m.joint_orientation_q[0], m.joint_orientation_q[1],
                             m.joint_orientation_q[2], m.joint_orientation_q[3]);
  if (!allFinite(p.joint_origin_m) || !std::isfinite(p.joint_orientation.norm()) ||
      std::abs(p.joint_orientation.norm() - 1.0) > 1e-3) {
    return bad("joint frame is not finite or not a unit quaternion");
  }
  p.joint_orientation.normalize();
  for (int i = 0; i < kAxes; ++i) {
    p.grip_offset_rad[i] = m.grip_offset_rad[i];
    if (!(std::abs(m.grip_offset_rad[i]) <= degToRad(JointModelParams::kMaxGripOffsetDeg))) {
      return bad(std::string(kAxisNames[static_cast<std::size_t>(i)]) +
                 " grip_offset_rad is not finite or beyond ±30 deg");
    }
  }
  std::memcpy(p.case_name.data(), m.case_name, std::min(sizeof(m.case_name), p.case_name.size()));
  p.case_name.back() = '\0';
  return p;
}

namespace {
void copyFinger(const SampleFinger& f, telehand_msg_Finger& w) noexcept {
  for (int i = 0; i < 3; ++i) w.position_m[i] = f.position_m[i];
  for (int i = 0; i < 4; ++i) w.orientation_q[i] = f.orientation_q[i];
  for (int i = 0; i < 4; ++i) w.fsr_n[i] = f.fsr_n[i];
  w.tangential_n = f.tangential_n;
  w.normal_n = f.normal_n;
  for (int i = 0; i < 3; ++i) w.command_n[i] = f.command_n[i];
}
void copyFinger(const telehand_msg_Finger& w, SampleFinger& f) noexcept {
  for (int i = 0; i < 3; ++i) f.position_m[i] = w.position_m[i];
  for (int i = 0; i < 4; ++i) f.orientation_q[i] = w.orientation_q[i];
  for (int i = 0; i < 4; ++i) f.fsr_n[i] = w.fsr_n[i];
  f.tangential_n = w.tangential_n;
  f.normal_n = w.normal_n;
  for (int i = 0; i < 3; ++i) f.command_n[i] = w.command_n[i];
}
}  // namespace

static_assert(sample_flags::kSafetyClamped == telehand_msg_kFlagSafetyClamped &&
                  sample_flags::kSafetyRateLimited == telehand_msg_kFlagSafetyRateLimited &&
                  sample_flags::kWatchdog == telehand_msg_kFlagWatchdog &&
                  sample_flags::kNonFinite == telehand_msg_kFlagNonFinite &&
                  sample_flags::kModelBlending == telehand_msg_kFlagModelBlending &&
                  sample_flags::kCapture == telehand_msg_kFlagCapture &&
                  sample_flags::kPassivityControl == telehand_msg_kFlagPassivityControl &&
                  sample_flags::kSentLive == telehand_msg_kFlagSentLive &&
                  sample_flags::kDirectForce == telehand_msg_kFlagDirectForce &&
                  sample_flags::kDeadband == telehand_msg_kFlagDeadband &&
                  sample_flags::kFsrFaultShift == telehand_msg_kFlagFsrFaultShift,
              "sample flags are the wire's");

void toWire(const Sample& s, telehand_msg_DeviceState& out) noexcept {
  out.session_id = s.session_id;
  out.seq = s.seq;
  out.source_time_ns = s.source_time_ns;
  out.model_version = s.model_version;
  out.flags = s.flags;
  for (int k = 0; k < 2; ++k) copyFinger(s.fingers[k], out.fingers[k]);
  for (int i = 0; i < 3; ++i) {
    out.mcp_angles_rad[i] = s.mcp_angles_rad[i];
    out.mcp_torque_nm[i] = s.mcp_torque_nm[i];
  }
  out.passivity_energy_j = s.passivity_energy_j;
  out.passivity_damping = s.passivity_damping;
}

Sample fromWire(const telehand_msg_DeviceState& d) noexcept {
  Sample s;
  s.session_id = d.session_id;
  s.seq = d.seq;
  s.source_time_ns = d.source_time_ns;
  s.model_version = d.model_version;
  s.flags = d.flags;
  for (int k = 0; k < 2; ++k) copyFinger(d.fingers[k], s.fingers[k]);
  for (int i = 0; i < 3; ++i) {
    s.mcp_angles_rad[i] = d.mcp_angles_rad[i];
    s.mcp_torque_nm[i] = d.mcp_torque_nm[i];
  }
  s.passivity_energy_j = d.passivity_energy_j;
  s.passivity_damping = d.passivity_damping;
  return s;
}

std::string_view modeName(telehand_msg_SessionMode m) noexcept {
  switch (m) {
    case telehand_msg_MODE_MOBILIZATION: return "mobilization";
    case telehand_msg_MODE_EXPLORATION: return "exploration";
    case telehand_msg_MODE_CAPTURE: return "capture";
  }
  return "unknown";
}

std::optional<telehand_msg_SessionMode> parseMode(std::string_view name) noexcept {
  if (name == "mobilization") return telehand_msg_MODE_MOBILIZATION;
  if (name == "exploration") return telehand_msg_MODE_EXPLORATION;
  if (name == "capture") return telehand_msg_MODE_CAPTURE;
  return std::nullopt;
}

std::string_view stateName(telehand_msg_SessionState s) noexcept {
  switch (s) {
    case telehand_msg_SESSION_ACTIVE: return "active";
    case telehand_msg_SESSION_CLOSING: return "closing";
    case telehand_msg_SESSION_CLOSED: return "closed";
  }
  return "unknown";
}

std::string_view eventKindName(telehand_msg_EventKind k) noexcept {
  switch (k) {
    case telehand_msg_EVENT_INFO: return "info";
    case telehand_msg_EVENT_MARK: return "mark";
    case telehand_msg_EVENT_FEEDBACK: return "feedback";
    case telehand_msg_EVENT_SCORE: return "score";
    case telehand_msg_EVENT_ERROR: return "error";
  }
  return "unknown";
}

}  // namespace telehand
