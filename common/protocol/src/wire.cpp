#include "telehand/protocol/wire.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>

#include "telehand/core/clock.h"
#include "telehand/core/error.h"
#include "telehand/core/knn_model.h"

namespace telehand {

telehand_msg_SessionCommand sessionCommand(telehand_msg_CommandKind kind, uint64_t client_id,
                                           uint32_t request_seq, uint64_t session_id) noexcept {
  telehand_msg_SessionCommand c{};
  c.client_id = client_id;
  c.request_seq = request_seq;
  c.source_time_ns = wallNs();
  c.kind = kind;
  c.session_id = session_id;
  copyString(c.case_name, "");
  copyString(c.user, "");
  copyString(c.text, "");
  return c;
}

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
  for (int i = 0; i < kAxes; ++i)
    out.neutral_zone_deg[i] = p.neutral_zone_deg[static_cast<std::size_t>(i)];
  out.speed_gain_s_per_rad = p.speed_gain_s_per_rad;
  for (int i = 0; i < 3; ++i) out.joint_origin_m[i] = p.joint_origin_m[i];
  out.joint_orientation_q[0] = p.joint_orientation.w();
  out.joint_orientation_q[1] = p.joint_orientation.x();
  out.joint_orientation_q[2] = p.joint_orientation.y();
  out.joint_orientation_q[3] = p.joint_orientation.z();
  copyString(out.case_name, std::string_view(p.case_name.data()));
  for (int i = 0; i < 3; ++i) out.grip_offset_rad[i] = p.grip_offset_rad[i];
  const GuideParams& g = p.guide;
  out.guide_authority = g.authority;
  out.guide_period_s = g.period_s;
  out.guide_stiffness_n_per_deg = g.stiffness_n_per_deg;
  out.guide_max_force_n = g.max_force_n;
  for (int k = 0; k < GuideParams::kPoints; ++k) {
    for (int i = 0; i < 3; ++i)
      out.guide_path_rad[k][i] = g.path_rad[static_cast<std::size_t>(k)][i];
  }
  out.technique = p.technique == Technique::kMassage ? telehand_msg_TECHNIQUE_MASSAGE
                                                     : telehand_msg_TECHNIQUE_MOBILIZATION;
  const TissueParams& t = p.tissue;
  telehand_msg_TissueModel& w = out.tissue;
  for (int i = 0; i < 3; ++i) w.origin_m[i] = t.origin_m[i];
  w.orientation_q[0] = t.orientation.w();
  w.orientation_q[1] = t.orientation.x();
  w.orientation_q[2] = t.orientation.y();
  w.orientation_q[3] = t.orientation.z();
  w.thickness_m = t.thickness_m;
  w.pad_radius_m = t.pad_radius_m;
  w.half_extent_m = t.half_extent_m;
  w.stiffness_n_per_m_pow = t.stiffness_n_per_m_pow;
  w.exponent = t.exponent;
  w.damping_s_per_m = t.damping_s_per_m;
  w.lateral_stiffness_n_per_m = t.lateral_stiffness_n_per_m;
  w.mu_static = t.mu_static;
  w.mu_kinetic = t.mu_kinetic;
  w.viscous_n_s_per_m = t.viscous_n_s_per_m;
  w.patch_x_m = t.patch_x_m;
  w.patch_y_m = t.patch_y_m;
  w.patch_radius_m = t.patch_radius_m;
  w.patch_stiffness_factor = t.patch_stiffness_factor;
  w.patch_friction_factor = t.patch_friction_factor;
  w.patch_rim_m = t.patch_rim_m;
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
    // A patient case's bounds: beyond them (or not finite) the rest angle, the energy
    // budget and the range-runaway check lose their meaning.
    const std::string axis(kAxisNames[static_cast<std::size_t>(i)]);
    auto outside = [&](const char* field, double v, DegreeBounds b) {
      char text[96];
      std::snprintf(text, sizeof text, " %s %g is not finite or outside [%g, %g] deg", field, v,
                    b.lo, b.hi);
      return bad(axis + text);
    };
    if (!kRangeMinDegBounds.contains(a.min_deg)) {
      return outside("min_deg", a.min_deg, kRangeMinDegBounds);
    }
    if (!kRangeMaxDegBounds.contains(a.max_deg)) {
      return outside("max_deg", a.max_deg, kRangeMaxDegBounds);
    }
    if (!(a.min_deg < a.max_deg)) return bad(axis + " range is empty");
    // What a patient case must be: a force that rises with the angle and stays a joint's.
    if (const auto problem = passiveCurveProblem(a)) return bad(axis + " curve " + *problem);
  }
  p.lever_arm_m = m.lever_arm_m;
  p.force_scale = m.force_scale;
  p.damping_nms_per_rad = m.damping_nms_per_rad;
  for (int i = 0; i < kAxes; ++i) {
    p.neutral_zone_deg[static_cast<std::size_t>(i)] = m.neutral_zone_deg[i];
    if (!(m.neutral_zone_deg[i] >= 0.0 && m.neutral_zone_deg[i] <= 30.0)) {
      return bad(std::string(kAxisNames[static_cast<std::size_t>(i)]) +
                 " neutral zone out of [0, 30] deg");
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
  GuideParams& g = p.guide;
  g.authority = m.guide_authority;
  g.period_s = m.guide_period_s;
  g.stiffness_n_per_deg = m.guide_stiffness_n_per_deg;
  g.max_force_n = m.guide_max_force_n;
  if (!(g.authority >= 0.0 && g.authority <= 1.0)) return bad("guide_authority out of [0, 1]");
  if (!(g.period_s == 0.0 || (g.period_s >= 0.1 && g.period_s <= 10.0))) {
    return bad("guide_period_s neither 0 nor in [0.1, 10] s");
  }
  if (!(g.stiffness_n_per_deg >= 0.0 &&
        g.stiffness_n_per_deg <= GuideParams::kMaxStiffnessNPerDeg)) {
    return bad("guide_stiffness_n_per_deg out of [0, 2]");
  }
  if (!(g.max_force_n >= 0.0 && g.max_force_n <= GuideParams::kMaxForceN)) {
    return bad("guide_max_force_n out of [0, 16] N");
  }
  for (int k = 0; k < GuideParams::kPoints; ++k) {
    Vec3& a = g.path_rad[static_cast<std::size_t>(k)];
    a = Vec3(m.guide_path_rad[k][0], m.guide_path_rad[k][1], m.guide_path_rad[k][2]);
    if (!allFinite(a) || a.cwiseAbs().maxCoeff() > M_PI) {
      return bad("guide_path_rad point " + std::to_string(k) + " is not finite or beyond ±180 deg");
    }
  }
  if (m.technique != telehand_msg_TECHNIQUE_MOBILIZATION &&
      m.technique != telehand_msg_TECHNIQUE_MASSAGE) {
    return bad("technique is neither mobilization nor massage");
  }
  p.technique = m.technique == telehand_msg_TECHNIQUE_MASSAGE ? Technique::kMassage
                                                              : Technique::kMobilization;
  const telehand_msg_TissueModel& w = m.tissue;
  TissueParams& t = p.tissue;
  t.origin_m = Vec3(w.origin_m[0], w.origin_m[1], w.origin_m[2]);
  t.orientation =
      Quat(w.orientation_q[0], w.orientation_q[1], w.orientation_q[2], w.orientation_q[3]);
  t.thickness_m = w.thickness_m;
  t.pad_radius_m = w.pad_radius_m;
  t.half_extent_m = w.half_extent_m;
  t.stiffness_n_per_m_pow = w.stiffness_n_per_m_pow;
  t.exponent = w.exponent;
  t.damping_s_per_m = w.damping_s_per_m;
  t.lateral_stiffness_n_per_m = w.lateral_stiffness_n_per_m;
  t.mu_static = w.mu_static;
  t.mu_kinetic = w.mu_kinetic;
  t.viscous_n_s_per_m = w.viscous_n_s_per_m;
  t.patch_x_m = w.patch_x_m;
  t.patch_y_m = w.patch_y_m;
  t.patch_radius_m = w.patch_radius_m;
  t.patch_stiffness_factor = w.patch_stiffness_factor;
  t.patch_friction_factor = w.patch_friction_factor;
  t.patch_rim_m = w.patch_rim_m;
  if (const char* field = invalidTissueParam(t)) {
    return bad(std::string("tissue ") + field + " is not finite or out of range");
  }
  t.orientation.normalize();
  std::memcpy(p.case_name.data(), m.case_name, std::min(sizeof(m.case_name), p.case_name.size()));
  p.case_name.back() = '\0';
  return p;
}

namespace {
// Sample and DeviceState name their fields alike: one copy serves both directions.
template <typename From, typename To>
void copyFinger(const From& f, To& w) noexcept {
  for (int i = 0; i < 3; ++i) w.position_m[i] = f.position_m[i];
  for (int i = 0; i < 4; ++i) w.orientation_q[i] = f.orientation_q[i];
  for (int i = 0; i < 4; ++i) w.fsr_n[i] = f.fsr_n[i];
  w.tangential_n = f.tangential_n;
  w.normal_n = f.normal_n;
  for (int i = 0; i < 3; ++i) w.command_n[i] = f.command_n[i];
  w.contact_depth_m = f.contact_depth_m;
  for (int i = 0; i < 3; ++i) w.tissue_force_n[i] = f.tissue_force_n[i];
}

template <typename From, typename To>
void copySample(const From& s, To& out) noexcept {
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
                  sample_flags::kLoopOverrun == telehand_msg_kFlagLoopOverrun &&
                  sample_flags::kFsrFaultShift == telehand_msg_kFlagFsrFaultShift,
              "sample flags are the wire's");

void toWire(const Sample& s, telehand_msg_DeviceState& out) noexcept { copySample(s, out); }

Sample fromWire(const telehand_msg_DeviceState& d) noexcept {
  Sample s;
  copySample(d, s);
  return s;
}

std::vector<Sample> samplesFromWire(const telehand_msg_RecordChunk& c) {
  std::vector<Sample> samples;
  samples.reserve(c.samples._length);
  for (uint32_t i = 0; i < c.samples._length; ++i)
    samples.push_back(fromWire(c.samples._buffer[i]));
  return samples;
}

void toWire(const KnnTorqueModel& m, uint64_t session_id, uint32_t version,
            std::vector<telehand_msg_KnnSample>& storage, telehand_msg_KnnModel& out) {
  storage.resize(m.size());
  for (std::size_t i = 0; i < storage.size(); ++i) {
    const KnnPoint& p = m.samples()[i];
    for (int a = 0; a < 3; ++a) {
      storage[i].angles_rad[a] = static_cast<float>(p.angles_rad[a]);
      storage[i].torque_nm[a] = static_cast<float>(p.torque_nm[a]);
    }
  }
  out.session_id = session_id;
  out.version = version;
  out.k = static_cast<uint32_t>(m.options().k);
  borrowSequence(out.samples, std::span<telehand_msg_KnnSample>(storage));
}

std::unique_ptr<const KnnTorqueModel> fromWire(const telehand_msg_KnnModel& k, std::string* why) {
  auto bad = [why](std::string w) -> std::unique_ptr<const KnnTorqueModel> {
    if (why) *why = std::move(w);
    return nullptr;
  };
  if (k.samples._length > kMaxKnnSamples) {
    return bad("has " + std::to_string(k.samples._length) + " samples, more than the " +
               std::to_string(kMaxKnnSamples) + " a model may hold");
  }
  // Joint angles are Euler angles: within ±π (as the wire's float rounds it).
  constexpr float kMaxAngleRad = std::numbers::pi_v<float>;
  std::vector<KnnPoint> points;
  points.reserve(k.samples._length);
  for (uint32_t i = 0; i < k.samples._length; ++i) {
    const auto& p = k.samples._buffer[i];
    const Vec3 angles(p.angles_rad[0], p.angles_rad[1], p.angles_rad[2]);
    const Vec3 torque(p.torque_nm[0], p.torque_nm[1], p.torque_nm[2]);
    if (!allFinite(angles) || !allFinite(torque)) {
      return bad("sample " + std::to_string(i) + " is not finite");
    }
    for (std::size_t a = 0; a < kAxes; ++a) {
      if (!(std::abs(p.angles_rad[a]) <= kMaxAngleRad)) {
        char text[32];
        std::snprintf(text, sizeof text, "%g", static_cast<double>(p.angles_rad[a]));
        return bad("sample " + std::to_string(i) + " " + std::string(kAxisNames[a]) + " angle " +
                   text + " rad is beyond ±π");
      }
    }
    points.push_back({angles, torque});
  }
  KnnOptions o;
  o.k = static_cast<int>(std::clamp<uint32_t>(k.k, 1, 64));
  try {
    return std::make_unique<const KnnTorqueModel>(std::move(points), o);
  } catch (const Error& e) {
    return bad(e.what());
  }
}

void toWire(const HandStateFields& f, telehand_msg_HandState& out) noexcept {
  out = telehand_msg_HandState{};
  out.session_id = f.session_id;
  out.source_time_ns = f.source_time_ns;
  out.source = telehand_msg_HAND_SOURCE_SHARED_JOINT_MODEL;
  out.device_rate_hz = f.device_rate_hz;
  out.device_lost = f.device_lost;
  out.device_overruns = f.device_overruns;
  out.model_version = f.model_version;
  if (!f.have_device) return;
  out.device_seq = f.device_seq;
  out.device_time_ns = f.device_time_ns;
  if (f.bullet) {
    out.source = telehand_msg_HAND_SOURCE_BULLET;
    out.dof_count = static_cast<uint16_t>(std::min<std::size_t>(f.joint_angles_rad.size(), 32));
    for (std::size_t i = 0; i < out.dof_count; ++i) out.joint_angles_rad[i] = f.joint_angles_rad[i];
    out.bone_count = static_cast<uint16_t>(std::min<std::size_t>(f.bone_poses.size(), 24));
    for (std::size_t b = 0; b < out.bone_count; ++b) {
      const auto& pose = f.bone_poses[b];
      const double v[7] = {pose.position_m.x(),  pose.position_m.y(),  pose.position_m.z(),
                           pose.orientation.w(), pose.orientation.x(), pose.orientation.y(),
                           pose.orientation.z()};
      for (int i = 0; i < 7; ++i) out.bone_pose[b][i] = v[i];
    }
    for (int k = 0; k < 2; ++k) {
      for (int i = 0; i < 3; ++i) {
        out.sphere_m[k][i] = f.sphere_m[static_cast<std::size_t>(k)][i];
        out.contact_force_n[k][i] = f.contact_force_n[static_cast<std::size_t>(k)][i];
      }
    }
  }
  for (int k = 0; k < 2; ++k) {
    for (int i = 0; i < 3; ++i) {
      out.fingertip_m[k][i] = f.fingertip_m[static_cast<std::size_t>(k)][i];
      out.fingertip_force_n[k][i] = f.fingertip_force_n[static_cast<std::size_t>(k)][i];
    }
  }
  for (int i = 0; i < 3; ++i) {
    out.mcp_angles_rad[i] = f.mcp_angles_rad[i];
    out.mcp_torque_nm[i] = f.mcp_torque_nm[i];
  }
  out.applied_force_ref_n = f.applied_force_ref_n;
  out.technique = f.massage ? telehand_msg_TECHNIQUE_MASSAGE : telehand_msg_TECHNIQUE_MOBILIZATION;
  for (int k = 0; k < 2; ++k) {
    out.web_depth_m[k] = f.web_depth_m[static_cast<std::size_t>(k)];
    for (int i = 0; i < 3; ++i)
      out.web_force_n[k][i] = f.web_force_n[static_cast<std::size_t>(k)][i];
  }
  for (int r = 0; r < 8; ++r) {
    for (int c = 0; c < 8; ++c)
      out.web_grid_m[r][c] = f.web_grid_m[static_cast<std::size_t>(r)][static_cast<std::size_t>(c)];
  }
}

void toWire(uint64_t session_id, uint64_t device_seq, int64_t source_time_ns,
            const PerFinger<Vec3>& force_n, telehand_msg_DirectForce& out) noexcept {
  out.session_id = session_id;
  out.device_seq = device_seq;
  out.source_time_ns = source_time_ns;
  for (int k = 0; k < 2; ++k) {
    for (int i = 0; i < 3; ++i) out.force_n[k][i] = force_n[static_cast<std::size_t>(k)][i];
  }
}

PerFinger<Vec3> forcesFromWire(const telehand_msg_DirectForce& f) noexcept {
  PerFinger<Vec3> force;
  for (std::size_t k = 0; k < 2; ++k)
    force[k] = Vec3(f.force_n[k][0], f.force_n[k][1], f.force_n[k][2]);
  return force;
}

std::string_view modeName(telehand_msg_SessionMode m) noexcept {
  switch (m) {
    case telehand_msg_MODE_MOBILIZATION:
      return "mobilization";
    case telehand_msg_MODE_EXPLORATION:
      return "exploration";
    case telehand_msg_MODE_CAPTURE:
      return "capture";
    case telehand_msg_MODE_LESSON:
      return "lesson";
    case telehand_msg_MODE_REPLAY:
      return "replay";
    case telehand_msg_MODE_MASSAGE:
      return "massage";
  }
  return "unknown";
}

std::optional<telehand_msg_SessionMode> parseMode(std::string_view name) noexcept {
  if (name == "mobilization") return telehand_msg_MODE_MOBILIZATION;
  if (name == "exploration") return telehand_msg_MODE_EXPLORATION;
  if (name == "capture") return telehand_msg_MODE_CAPTURE;
  if (name == "lesson") return telehand_msg_MODE_LESSON;
  if (name == "replay") return telehand_msg_MODE_REPLAY;
  if (name == "massage") return telehand_msg_MODE_MASSAGE;
  // A massage's capture is kept as "capture-massage" (techniqueOfMode).
  if (name == "capture-massage") return telehand_msg_MODE_CAPTURE;
  return std::nullopt;
}

Technique techniqueOfMode(std::string_view recorded_mode) noexcept {
  return recorded_mode == "massage" || recorded_mode == "capture-massage"
             ? Technique::kMassage
             : Technique::kMobilization;
}

std::string_view stateName(telehand_msg_SessionState s) noexcept {
  switch (s) {
    case telehand_msg_SESSION_ACTIVE:
      return "active";
    case telehand_msg_SESSION_CLOSING:
      return "closing";
    case telehand_msg_SESSION_CLOSED:
      return "closed";
    case telehand_msg_SESSION_SUSPENDED:
      return "suspended";
  }
  return "unknown";
}

std::string_view eventKindName(telehand_msg_EventKind k) noexcept {
  switch (k) {
    case telehand_msg_EVENT_INFO:
      return "info";
    case telehand_msg_EVENT_MARK:
      return "mark";
    case telehand_msg_EVENT_FEEDBACK:
      return "feedback";
    case telehand_msg_EVENT_SCORE:
      return "score";
    case telehand_msg_EVENT_ERROR:
      return "error";
  }
  return "unknown";
}

}  // namespace telehand
