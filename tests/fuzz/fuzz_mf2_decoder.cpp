// libFuzzer target for the MF-2 packet decoder (tests/fuzz/README.md has the commands).
// Properties checked on every input, besides the sanitizers' memory and UB checks:
// - a packet that decodes re-encodes to exactly the same bytes (nothing is half-parsed);
// - with its CRC fixed up, the input also exercises the range checks behind the CRC;
// - the sequence tracker never accepts a packet behind or equal to the last accepted one
//   (except through its documented resynchronization).
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "telehand/devices/mf2_protocol.h"

namespace proto = telehand::devices::proto;

namespace {

template <typename Packet, std::size_t kSize, typename Decode, typename Encode>
void roundTrip(const uint8_t* data, std::size_t size, Decode decode, Encode encode) {
  Packet p;
  if (decode(std::span<const uint8_t>(data, size), p) != proto::DecodeError::kOk) return;
  uint8_t again[kSize];
  if (size != kSize || encode(p, std::span<uint8_t>(again, kSize)) != kSize ||
      std::memcmp(again, data, kSize) != 0) {
    std::abort();
  }
}

void withCrcFixed(const uint8_t* data, std::size_t size, std::size_t packet_size) {
  if (size != packet_size) return;
  std::vector<uint8_t> b(data, data + size);
  const uint32_t crc = proto::crc32(std::span<const uint8_t>(b.data(), size - 4));
  for (int i = 0; i < 4; ++i) b[size - 4 + i] = static_cast<uint8_t>(crc >> (8 * i));
  roundTrip<proto::StatePacket, proto::kStateSize>(
      b.data(), size, proto::decodeState,
      [](const proto::StatePacket& p, std::span<uint8_t> o) { return proto::encodeState(p, o); });
  roundTrip<proto::CommandPacket, proto::kCommandSize>(
      b.data(), size, proto::decodeCommand,
      [](const proto::CommandPacket& p, std::span<uint8_t> o) {
        return proto::encodeCommand(p, o);
      });
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  auto enc_state = [](const proto::StatePacket& p, std::span<uint8_t> o) {
    return proto::encodeState(p, o);
  };
  auto enc_cmd = [](const proto::CommandPacket& p, std::span<uint8_t> o) {
    return proto::encodeCommand(p, o);
  };
  roundTrip<proto::StatePacket, proto::kStateSize>(data, size, proto::decodeState, enc_state);
  roundTrip<proto::CommandPacket, proto::kCommandSize>(data, size, proto::decodeCommand, enc_cmd);
  withCrcFixed(data, size, proto::kStateSize);
  withCrcFixed(data, size, proto::kCommandSize);

  // The input as a stream of (seq, time) pairs.
  proto::SequenceTracker t;
  bool have = false;
  uint32_t last_seq = 0;
  uint64_t last_time = 0;
  for (std::size_t i = 0; i + 8 <= size; i += 8) {
    uint32_t seq = 0, dt = 0;
    std::memcpy(&seq, data + i, 4);
    std::memcpy(&dt, data + i + 4, 4);
    const uint64_t time = dt;
    const uint64_t resyncs = t.resyncs();
    if (t.check(seq, time) == proto::SequenceTracker::Verdict::kAccept) {
      const bool ahead = !have || (static_cast<int32_t>(seq - last_seq) > 0 && time > last_time);
      if (!ahead && t.resyncs() == resyncs) std::abort();
      have = true;
      last_seq = seq;
      last_time = time;
    }
  }
  return 0;
}
