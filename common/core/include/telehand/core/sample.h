#pragma once
/// One tick of the haptic loop as it is recorded: what the device read, what the thimbles
/// measured (paper eqs. 1-2), what the joint proxy rendered and what the safety gate let
/// out. The loop produces it, the record stores it, the fitting reads it; the wire form
/// (DeviceState in idl/telehand.idl) is made from it in common/protocol/wire.h only.
/// Angles in radians, forces in newtons, torques in N·m, positions in metres.
#include <cstdint>
#include <optional>
#include <string>

#include "telehand/core/math.h"

namespace telehand {

/// One thimble of the MF-2 as the device reports it and the loop renders it.
struct SampleFinger {
  double position_m[3] = {0, 0, 0};        ///< thimble centre, device frame
  double orientation_q[4] = {1, 0, 0, 0};  ///< unit quaternion w, x, y, z
  float fsr_n[4] = {0, 0, 0, 0};           ///< FlexiForce A201 readings 1 (end) .. 4 (pad)
  float tangential_n = 0.0f;               ///< paper eq. 1: F2 - F3
  float normal_n = 0.0f;                   ///< paper eq. 2: sqrt(F4^2 + F1^2)
  double command_n[3] = {0, 0, 0};         ///< force commanded after the safety gate
  double contact_depth_m = 0.0;            ///< massage: pad depth in the web (0: no contact)
  double tissue_force_n[3] = {0, 0, 0};    ///< massage: the web's force, reference scale
};

struct Sample {
  uint64_t session_id = 0;
  uint64_t seq = 0;            ///< loop tick sequence number, 0-based, no gaps
  int64_t source_time_ns = 0;  ///< when the sample was read from the device (wall clock)
  uint32_t model_version = 0;  ///< JointModel version rendered
  uint32_t flags = 0;          ///< SampleFlag bits
  SampleFinger fingers[2];     ///< 0 = thumb, 1 = index
  double mcp_angles_rad[3] = {0, 0,
                              0};  ///< proxy's alpha (flexion), beta (abduction), gamma (axial)
  double mcp_torque_nm[3] = {0, 0, 0};  ///< proxy's passive torque per axis (reference scale)
  float passivity_energy_j = 0.0f;      ///< passivity observer energy so far (device scale)
  float passivity_damping = 0.0f;       ///< passivity controller damping this tick, N·s/m
};

/// Sample::flags. The values are the wire's (idl/telehand.idl kFlag*, checked in wire.cpp).
namespace sample_flags {
inline constexpr uint32_t kSafetyClamped = 1;
inline constexpr uint32_t kSafetyRateLimited = 2;
inline constexpr uint32_t kWatchdog = 4;
inline constexpr uint32_t kNonFinite = 8;
inline constexpr uint32_t kModelBlending = 16;
inline constexpr uint32_t kCapture = 32;
inline constexpr uint32_t kPassivityControl = 64;  ///< the passivity controller added damping
inline constexpr uint32_t kSentLive = 128;  ///< also went out live (not withheld by the deadband)
inline constexpr uint32_t kDirectForce = 256;  ///< rendered the server's force (direct mode)
inline constexpr uint32_t kDeadband = 512;     ///< the live stream is deadband-coded
/// The loop's tick before this one finished after its deadline (the loop ran late). The flag
/// changes the sample's flags, so the deadband lets it out live.
inline constexpr uint32_t kLoopOverrun = 1024;
/// Bits 16..23: an FSR flagged saturated or dead; bit 16 + 4 * finger + (sensor - 1).
inline constexpr uint32_t kFsrFaultShift = 16;
}  // namespace sample_flags

/// Calls f(field) for every field of a sample except session_id, in the record's column
/// order (the SQLite and PostgreSQL tables, their inserts and reads, the CSV export and the
/// digest below all follow it). The one place that order is written down.
template <class S, class F>
void visitSampleFields(S& s, F&& f) {
  f(s.seq);
  f(s.source_time_ns);
  f(s.model_version);
  f(s.flags);
  for (auto& v : s.mcp_angles_rad) f(v);
  for (auto& v : s.mcp_torque_nm) f(v);
  for (auto& finger : s.fingers) {
    for (auto& v : finger.position_m) f(v);
    for (auto& v : finger.orientation_q) f(v);
    for (auto& v : finger.fsr_n) f(v);
    f(finger.tangential_n);
    f(finger.normal_n);
    for (auto& v : finger.command_n) f(v);
  }
  f(s.passivity_energy_j);
  f(s.passivity_damping);
  for (auto& finger : s.fingers) {  // record schema 7
    f(finger.contact_depth_m);
    for (auto& v : finger.tissue_force_n) f(v);
  }
}

/// A digest of a set of samples that does not depend on the order they came in: the count,
/// and the sum (mod 2^64) of each sample's FNV-1a hash over its fields in
/// visitSampleFields() order (every NaN hashed as one). A client's digest of what it sent
/// and a record's digest of what it holds are equal when the record holds every sample,
/// field for field (`telehand-client`'s summary, `telehand-records show`).
struct SampleDigest {
  uint64_t count = 0;
  uint64_t sum = 0;
  void add(const Sample& s) noexcept;
  /// "N samples, digest 0123456789abcdef"
  std::string text() const;
  bool operator==(const SampleDigest&) const = default;
};

/// Names the first field of a sample that is not finite, or nullopt when all are.
std::optional<std::string> firstNonFinite(const Sample& s);

/// What an MF-2 can physically report, generously: a sample outside these is not a reading
/// but a fault or a forgery (docs/security.md "Bounds"). Thimbles within 1 m of the device
/// origin, unit quaternions to 10 %, FSR readings within ±50 N (the sensors saturate near
/// 22 N), thimble forces within ±100 N, commanded forces within ±20 N per axis (the device
/// renders 4 N), MCP angles within ±2π, torques within ±10 N·m, web depths within 0..10 cm and
/// the web's forces within ±100 N, sequence numbers below 2^63.
namespace sample_bounds {
inline constexpr double kPositionM = 1.0;
inline constexpr double kQuatNormTolerance = 0.1;
inline constexpr double kFsrN = 50.0;
inline constexpr double kThimbleForceN = 100.0;
inline constexpr double kCommandN = 20.0;
inline constexpr double kAngleRad = 6.283185307179586;
inline constexpr double kTorqueNm = 10.0;
inline constexpr double kDepthM = 0.1;  ///< a pad 10 cm into the web is no reading
inline constexpr uint64_t kMaxSeq = uint64_t{1} << 63;
}  // namespace sample_bounds

/// Names the first field that is not finite or out of sample_bounds (with its value), or
/// nullopt when the sample is one a device could have sent.
std::optional<std::string> firstInvalid(const Sample& s);

/// Thimble positions of a sample.
PerFinger<Vec3> thimblePositions(const Sample& s) noexcept;

}  // namespace telehand
