// libFuzzer target: patient case text into parsePatientCase.
// Properties: a refusal is a ConfigError naming the file; an accepted case, at the start and
// after any treatment time, is a joint model the client would accept from the network
// (toWire then fromWire, the wire's validation).
#include <string>

#include "telehand/config/config.h"
#include "telehand/protocol/wire.h"
#include "toml_input.h"

using namespace telehand;

namespace {
void sendable(const JointModelParams& p) {
  telehand_msg_JointModel w{};
  toWire(p, 1, w);
  std::string why;
  const auto back = fromWire(w, &why);
  fuzz::check(back.has_value());
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  PatientCase c;
  if (!fuzz::parsesOrRefuses(
          data, size, "case.toml",
          [&](const std::string& t, const std::string& o) { c = parsePatientCase(t, o); })) {
    return 0;
  }
  fuzz::check(!c.name.empty());
  sendable(c.model);
  for (double t : {0.0, 0.5 * c.recovery_treatment_s, c.recovery_treatment_s, 1e9})
    sendable(c.at(t));
  return 0;
}
