#pragma once
/// Conversions between wire types (idl/telehand.idl) and the C++ model, and checks on
/// samples that arrive from the network.
#include <array>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "telehand.h"
#include "telehand/core/joint_model.h"
#include "telehand/core/sample.h"

namespace telehand {

/// Copy into a fixed char array (bounded IDL strings are char arrays or char*), truncating.
template <std::size_t N>
void copyString(char (&dst)[N], std::string_view src) noexcept {
  const std::size_t n = std::min(src.size(), N - 1);
  std::memcpy(dst, src.data(), n);
  dst[n] = '\0';
}

/// A SessionCommand from `client_id` (its request number `request_seq`) about `session_id`,
/// stamped now, every string empty: what every sender of commands starts from.
telehand_msg_SessionCommand sessionCommand(telehand_msg_CommandKind kind, uint64_t client_id,
                                           uint32_t request_seq, uint64_t session_id) noexcept;

/// Fill a wire JointModel for `session_id` from model parameters.
void toWire(const JointModelParams& p, uint64_t session_id, telehand_msg_JointModel& out);
/// Parameters from a wire JointModel; nullopt with `why` set when a field is not finite or
/// out of its bounds, a range is empty, or an axis' curve is no passive joint's
/// (passiveCurveProblem: a force that falls somewhere in range, or beyond kMaxHoldingForceN).
std::optional<JointModelParams> fromWire(const telehand_msg_JointModel& m, std::string* why);

/// A recorded tick as a wire DeviceState, and back: field by field, nothing checked (the
/// receiver checks with firstNonFinite, core/sample.h).
void toWire(const Sample& s, telehand_msg_DeviceState& out) noexcept;
Sample fromWire(const telehand_msg_DeviceState& d) noexcept;
inline telehand_msg_DeviceState toWire(const Sample& s) noexcept {
  telehand_msg_DeviceState out;
  toWire(s, out);
  return out;
}

/// Point a wire sequence at `items` without handing it ownership: the sequence is valid while
/// `items` is, and nothing frees the buffer on its behalf.
template <class Sequence, class T>
void borrowSequence(Sequence& seq, std::span<T> items) noexcept {
  seq._buffer = items.data();
  seq._length = static_cast<uint32_t>(items.size());
  seq._maximum = static_cast<uint32_t>(items.size());
  seq._release = false;
}

/// A RecordChunk whose samples are `samples` (not owned: keep them alive while it is used).
inline void borrowSamples(telehand_msg_RecordChunk& c,
                          std::span<telehand_msg_DeviceState> samples) noexcept {
  borrowSequence(c.samples, samples);
}
/// A RecordChunk's samples, decoded (unchecked, as fromWire(DeviceState)).
std::vector<Sample> samplesFromWire(const telehand_msg_RecordChunk& c);

/// The samples behind a data-driven model as a wire KnnModel of `session_id` and `version`
/// (k from the model's options; source_time_ns left to the caller). The samples go through
/// `storage`, resized here, which the sequence borrows: keep it alive while `out` is used.
void toWire(const KnnTorqueModel& m, uint64_t session_id, uint32_t version,
            std::vector<telehand_msg_KnnSample>& storage, telehand_msg_KnnModel& out);
/// The model a wire KnnModel describes (k clamped to [1, 64]); null with `why` set when it
/// has no samples or more than kMaxKnnSamples, a sample is not finite or has an angle beyond
/// ±π, or the index cannot be built. Allocates.
std::unique_ptr<const KnnTorqueModel> fromWire(const telehand_msg_KnnModel& k, std::string* why);

/// Everything a HandState says, as plain values; toWire packs it.
struct HandStateFields {
  uint64_t session_id = 0;
  int64_t source_time_ns = 0;
  /// The authoritative Bullet hand computed it (else the shared joint model).
  bool bullet = false;
  float device_rate_hz = 0.0f;
  uint64_t device_lost = 0;
  uint64_t device_overruns = 0;  ///< samples flagged kLoopOverrun (the client's loop ran late)
  uint32_t model_version = 0;
  /// The device sample it reflects; without one every field below stays zero on the wire.
  bool have_device = false;
  uint64_t device_seq = 0;
  int64_t device_time_ns = 0;
  Vec3 mcp_angles_rad = Vec3::Zero();
  Vec3 mcp_torque_nm = Vec3::Zero();
  PerFinger<Vec3> fingertip_m{Vec3::Zero(), Vec3::Zero()};
  PerFinger<Vec3> fingertip_force_n{Vec3::Zero(), Vec3::Zero()};
  float applied_force_ref_n = 0.0f;
  // Bullet only: the whole hand (device frame); beyond the wire's capacity is cut off.
  struct BonePose {
    Vec3 position_m = Vec3::Zero();
    Quat orientation = Quat::Identity();
  };
  std::vector<double> joint_angles_rad;
  std::vector<BonePose> bone_poses;
  PerFinger<Vec3> sphere_m{Vec3::Zero(), Vec3::Zero()};
  PerFinger<Vec3> contact_force_n{Vec3::Zero(), Vec3::Zero()};
  // Massage: the web (server/sim web_sim.h).
  bool massage = false;
  PerFinger<double> web_depth_m{0.0, 0.0};
  PerFinger<Vec3> web_force_n{Vec3::Zero(), Vec3::Zero()};  ///< reference scale, device frame
  std::array<std::array<double, 8>, 8> web_grid_m{};        ///< compression on the 8×8 grid
};
/// A whole HandState from `f`, seq zero (the publisher numbers what it sends).
void toWire(const HandStateFields& f, telehand_msg_HandState& out) noexcept;

/// Direct mode's fingertip forces (device frame) for device sample `device_seq`, and back.
void toWire(uint64_t session_id, uint64_t device_seq, int64_t source_time_ns,
            const PerFinger<Vec3>& force_n, telehand_msg_DirectForce& out) noexcept;
PerFinger<Vec3> forcesFromWire(const telehand_msg_DirectForce& f) noexcept;

std::string_view modeName(telehand_msg_SessionMode m) noexcept;
std::optional<telehand_msg_SessionMode> parseMode(std::string_view name) noexcept;
/// The technique of a session as its record keeps its mode: "massage" and "capture-massage"
/// are the web's, everything else the joint's.
Technique techniqueOfMode(std::string_view recorded_mode) noexcept;
std::string_view stateName(telehand_msg_SessionState s) noexcept;
std::string_view eventKindName(telehand_msg_EventKind k) noexcept;

}  // namespace telehand
