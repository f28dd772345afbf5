// libFuzzer target: a DirectForce from the network (CDR through Cyclone's deserializer, as
// the client's reader takes it in direct mode) into forcesFromWire and then, as the loop
// does with every force, through the safety gate.
// Properties: forcesFromWire keeps every value as sent (bit for bit); whatever arrives, the
// gate's output is finite and within its per-finger limit, and a non-finite request is
// flagged and commands zero.
#include <cmath>
#include <cstdlib>
#include <cstring>

#include "cdr_input.h"
#include "telehand/core/safety.h"
#include "telehand/protocol/wire.h"

using namespace telehand;

using fuzz::check;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  fuzz::CdrSample<telehand_msg_DirectForce> in(telehand_msg_DirectForce_desc);
  if (!in.read(data, size)) return 0;
  const telehand_msg_DirectForce& w = in.get();
  const PerFinger<Vec3> force = forcesFromWire(w);
  for (std::size_t k = 0; k < 2; ++k) {
    for (int i = 0; i < 3; ++i) check(std::memcmp(&force[k][i], &w.force_n[k][i], 8) == 0);
  }

  SafetyGate gate;
  // Two ticks 1 ms apart, each with a fresh device sample.
  for (int64_t t = 1'000'000; t <= 2'000'000; t += 1'000'000) {
    const SafetyOutput o = gate.apply(force, t, t);
    const bool finite = allFinite(force[0]) && allFinite(force[1]);
    for (const auto& f : o.force_n) {
      check(allFinite(f));
      check(f.norm() <= gate.limits().max_force_n * (1.0 + 1e-9));
    }
    if (!finite) {
      check((o.flags & kSafetyNonFinite) != 0);
      check(o.force_n[0].isZero() && o.force_n[1].isZero());
    }
  }
  return 0;
}
