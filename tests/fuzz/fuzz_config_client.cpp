// libFuzzer target: client configuration text into parseClientConfig.
// Properties: a refusal is a ConfigError naming the file; an accepted configuration passes
// the range checks the command-line options go through, with a loop rate within LoopConfig's
// range.
#include <cmath>

#include "telehand/config/config.h"
#include "toml_input.h"

using namespace telehand;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  ClientConfig c;
  if (!fuzz::parsesOrRefuses(
          data, size, "client.toml",
          [&](const std::string& t, const std::string& o) { c = parseClientConfig(t, o); })) {
    return 0;
  }
  validate(c.op, "again");
  validate(c.safety, "again");
  fuzz::check(c.loop.rate_hz >= LoopConfig::kMinRateHz && c.loop.rate_hz <= LoopConfig::kMaxRateHz);
  return 0;
}
