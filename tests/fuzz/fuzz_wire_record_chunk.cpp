// libFuzzer target: a RecordChunk from the network (CDR through Cyclone's deserializer,
// with up to 256 samples) into samplesFromWire and firstInvalid per sample, as the server
// stores a chunk (every sample kept, the implausible ones flagged).
// Properties: one decoded sample per wire sample, field for field; firstInvalid accepts only
// finite samples within sample_bounds' sequence limit.
#include <cmath>
#include <cstdlib>
#include <cstring>

#include "cdr_input.h"
#include "telehand/protocol/wire.h"

using namespace telehand;

using fuzz::check;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  fuzz::CdrSample<telehand_msg_RecordChunk> in(telehand_msg_RecordChunk_desc);
  if (!in.read(data, size)) return 0;
  const telehand_msg_RecordChunk& c = in.get();
  check(c.samples._length <= 256);
  const auto samples = samplesFromWire(c);
  check(samples.size() == c.samples._length);
  for (std::size_t i = 0; i < samples.size(); ++i) {
    telehand_msg_DeviceState again;
    std::memset(&again, 0, sizeof again);
    toWire(samples[i], again);
    check(std::memcmp(&again, &c.samples._buffer[i], sizeof again) == 0);
    const auto bad = firstInvalid(samples[i]);
    if (bad) {
      check(!bad->empty());
    } else {
      check(!firstNonFinite(samples[i]).has_value() && samples[i].seq < sample_bounds::kMaxSeq);
    }
  }
  return 0;
}
