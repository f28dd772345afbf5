#pragma once
/// Conversions between wire types (idl/telehand.idl) and the C++ model, and checks on
/// samples that arrive from the network.
#include <cstddef>
#include <cstring>
#include <optional>
#include <string>
#include <string_view>

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

/// Fill a wire JointModel for `session_id` from model parameters.
void toWire(const JointModelParams& p, uint64_t session_id, telehand_msg_JointModel& out);
/// Parameters from a wire JointModel; nullopt with `why` set when a field is not finite or
/// a range is empty.
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

std::string_view modeName(telehand_msg_SessionMode m) noexcept;
std::optional<telehand_msg_SessionMode> parseMode(std::string_view name) noexcept;
std::string_view stateName(telehand_msg_SessionState s) noexcept;
std::string_view eventKindName(telehand_msg_EventKind k) noexcept;

}  // namespace telehand
