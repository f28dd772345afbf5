#pragma once
/// The JSON frames telehand-web sends to the page (docs/web.md "Protocol").
#include <cstdint>
#include <string>
#include <string_view>

#include "telehand/protocol/dds.h"

namespace telehand::web {

/// A JSON string literal of `s` (quoted, escaped; invalid UTF-8 replaced).
std::string jsonString(std::string_view s);
/// A JSON number, or null when not finite.
std::string jsonNumber(double v);

/// {"type":"hand",...}: one HandState; `rx_wall_ns` when the gateway took it.
std::string handFrame(const telehand_msg_HandState& h, int64_t rx_wall_ns);
/// {"type":"event",...}
std::string eventFrame(const telehand_msg_SessionEvent& e);
/// {"type":"error","code":...,"message":...}
std::string errorFrame(std::string_view code, std::string_view message);

}  // namespace telehand::web
