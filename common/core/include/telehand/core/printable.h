#pragma once
// Text from the network (names, event text) made safe to print on a terminal.
#include <cstddef>
#include <cstring>
#include <string>
#include <string_view>

namespace telehand {

/// `text` with every control character replaced by '?': C0 (below 0x20, so ESC and newlines
/// too), DEL, and the C1 controls U+0080..U+009F as UTF-8 encodes them, so that a name or an
/// event cannot move the cursor, clear or recolour the terminal it is printed on. A byte that
/// is not part of well-formed UTF-8 becomes '?' too (a terminal could take a lone 0x9B for
/// a CSI); other UTF-8 ("±", "°", "é") passes unchanged.
inline std::string printable(std::string_view text) {
  std::string out;
  out.reserve(text.size());
  const std::size_t n = text.size();
  auto byte = [&](std::size_t i) { return static_cast<unsigned char>(text[i]); };
  auto continuation = [&](std::size_t i) { return i < n && (byte(i) & 0xC0) == 0x80; };
  for (std::size_t i = 0; i < n;) {
    const unsigned char c = byte(i);
    if (c < 0x80) {
      out += c < 0x20 || c == 0x7F ? '?' : static_cast<char>(c);
      ++i;
      continue;
    }
    // Well-formed sequences (The Unicode Standard, table 3-7): the lead byte gives the length
    // and the range of the byte after it (no overlong forms, no surrogates, nothing past
    // U+10FFFF).
    std::size_t len = 0;
    unsigned char lo = 0x80, hi = 0xBF;
    if (c >= 0xC2 && c <= 0xDF) {
      len = 2;
    } else if (c >= 0xE0 && c <= 0xEF) {
      len = 3;
      if (c == 0xE0) lo = 0xA0;
      if (c == 0xED) hi = 0x9F;
    } else if (c >= 0xF0 && c <= 0xF4) {
      len = 4;
      if (c == 0xF0) lo = 0x90;
      if (c == 0xF4) hi = 0x8F;
    }
    bool whole = len > 0 && i + 1 < n && byte(i + 1) >= lo && byte(i + 1) <= hi;
    for (std::size_t k = 2; whole && k < len; ++k) whole = continuation(i + k);
    if (!whole) {
      out += '?';
      ++i;
      continue;
    }
    const bool c1_control = c == 0xC2 && byte(i + 1) <= 0x9F;
    if (c1_control) {
      out += '?';
    } else {
      out.append(text.substr(i, len));
    }
    i += len;
  }
  return out;
}

/// A fixed-size text field: up to its first NUL, at most `max` characters.
inline std::string printable(const char* s, std::size_t max) {
  return printable(std::string_view(s, strnlen(s, max)));
}
template <std::size_t N>
inline std::string printable(const char (&s)[N]) {
  return printable(s, N);
}

}  // namespace telehand
