// libFuzzer target: server configuration text into parseServerConfig.
// Properties: a refusal is a ConfigError naming the file; an accepted configuration passes
// validateServerConfig (the range table the command-line flags share).
#include "telehand/config/config.h"
#include "toml_input.h"

using namespace telehand;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  ServerConfig c;
  if (!fuzz::parsesOrRefuses(
          data, size, "server.toml",
          [&](const std::string& t, const std::string& o) { c = parseServerConfig(t, o); })) {
    return 0;
  }
  validateServerConfig(c, "again");
  return 0;
}
