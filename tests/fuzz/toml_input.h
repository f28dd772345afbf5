#pragma once
// Shared by the TOML fuzz targets: the input as file text, and the one error a parser may
// report (ConfigError with a message). Any other exception escapes to libFuzzer, which
// reports it as a crash, as it does a sanitizer finding, a hang or a failed property.
#include <cstdint>
#include <cstdlib>
#include <string>

#include "telehand/core/error.h"

namespace telehand::fuzz {

inline void check(bool ok) {
  if (!ok) std::abort();
}

/// Runs `parse` on the input as text; true when it accepted it. A refusal must be a
/// ConfigError with a message naming the origin (or, with `names_origin` false, naming
/// something: a device file's error may name the thimble file it refers to).
template <class Parse>
bool parsesOrRefuses(const uint8_t* data, std::size_t size, const std::string& origin, Parse parse,
                     bool names_origin = true) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    parse(text, origin);
    return true;
  } catch (const ConfigError& e) {
    const std::string what = e.what();
    check(!what.empty() && (!names_origin || what.find(origin) != std::string::npos));
    return false;
  }
}

}  // namespace telehand::fuzz
