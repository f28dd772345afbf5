#pragma once
/// Conversions between wire types (idl/telehand.idl) and the C++ model, and checks on
/// samples that arrive from the network.
#include <cstddef>
#include <cstring>
#include <optional>
#include <string>
#include <string_view>

#include "telehand.h"
#include "telehand/common/joint_model.h"

namespace telehand {

/// Copy into a fixed char array (bounded IDL strings are char arrays or char*), truncating.
template <std::size_t N>
void copyString(char (&dst)[N], std::string_view src) noexcept {
  const std::size_t n = std::min(src.size(), N - 1);
  std::memcpy(dst, src.data(), n);
  dst[n] = '\0';
}

/// Fill a wire JointModel for `session_id` from model parameters.
void toWire(const JointModelParams& p, uint64_t session_id, telehand_msg_JointModel& out);
/// Parameters from a wire JointModel; nullopt with `why` set when a field is not finite or
/// a range is empty.
std::optional<JointModelParams> fromWire(const telehand_msg_JointModel& m, std::string* why);

/// Names the first field of a DeviceState that is not finite, or nullopt when all are.
std::optional<std::string> firstNonFinite(const telehand_msg_DeviceState& s);

/// Thimble positions of a DeviceState.
PerFinger<Vec3> thimblePositions(const telehand_msg_DeviceState& s) noexcept;

std::string_view modeName(telehand_msg_SessionMode m) noexcept;
std::optional<telehand_msg_SessionMode> parseMode(std::string_view name) noexcept;
std::string_view stateName(telehand_msg_SessionState s) noexcept;
std::string_view eventKindName(telehand_msg_EventKind k) noexcept;

}  // namespace telehand
