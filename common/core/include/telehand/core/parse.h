#pragma once
// Numbers read from text that came from outside (command lines, message fields).
#include <charconv>
#include <cmath>
#include <string_view>
#include <system_error>

namespace telehand {

/// The whole of `text` as a finite number, in the C locale: false for "", "3x", " 3", "inf",
/// "nan" and out-of-range values; `out` is written only on success.
inline bool parseFiniteNumber(std::string_view text, double& out) noexcept {
  double v = 0.0;
  const auto [p, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (ec != std::errc{} || p != text.data() + text.size() || !std::isfinite(v)) return false;
  out = v;
  return true;
}

}  // namespace telehand
