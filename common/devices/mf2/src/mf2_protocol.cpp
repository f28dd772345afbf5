#include "telehand/devices/mf2_protocol.h"

namespace telehand::devices::proto {

namespace {

constexpr std::array<uint32_t, 256> makeCrcTable() {
  std::array<uint32_t, 256> t{};
  for (uint32_t i = 0; i < 256; ++i) {
    uint32_t c = i;
    for (int k = 0; k < 8; ++k) c = (c & 1u) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
    t[i] = c;
  }
  return t;
}
constexpr std::array<uint32_t, 256> kCrcTable = makeCrcTable();

// Little-endian field access at fixed offsets; callers have checked the length.
void put16(uint8_t* p, uint16_t v) noexcept {
  p[0] = static_cast<uint8_t>(v);
  p[1] = static_cast<uint8_t>(v >> 8);
}
void put32(uint8_t* p, uint32_t v) noexcept {
  for (int i = 0; i < 4; ++i) p[i] = static_cast<uint8_t>(v >> (8 * i));
}
void put64(uint8_t* p, uint64_t v) noexcept {
  for (int i = 0; i < 8; ++i) p[i] = static_cast<uint8_t>(v >> (8 * i));
}
uint16_t get16(const uint8_t* p) noexcept { return static_cast<uint16_t>(p[0] | (p[1] << 8)); }
uint32_t get32(const uint8_t* p) noexcept {
  uint32_t v = 0;
  for (int i = 0; i < 4; ++i) v |= static_cast<uint32_t>(p[i]) << (8 * i);
  return v;
}
uint64_t get64(const uint8_t* p) noexcept {
  uint64_t v = 0;
  for (int i = 0; i < 8; ++i) v |= static_cast<uint64_t>(p[i]) << (8 * i);
  return v;
}

// State packet layout (docs/mf2-usb-protocol.md).
constexpr std::size_t kOffSeq = 4;
constexpr std::size_t kOffTime = 8;
constexpr std::size_t kOffActuators = 16;
constexpr std::size_t kOffGimbals = kOffActuators + 4 * kActuators;  // 44
constexpr std::size_t kOffFsr = kOffGimbals + 4 * kGimbals;          // 68
constexpr std::size_t kOffStatus = kOffFsr + 2 * kFsrs;              // 84
constexpr std::size_t kOffRxErrors = kOffStatus + 2;                 // 86
constexpr std::size_t kOffLastCommand = kOffRxErrors + 2;            // 88
constexpr std::size_t kOffStateCrc = kOffLastCommand + 4;            // 92
static_assert(kOffStateCrc + 4 == kStateSize);

// Command packet layout.
constexpr std::size_t kOffCurrents = 8;
constexpr std::size_t kOffFlags = kOffCurrents + 2 * kActuators;  // 22
constexpr std::size_t kOffReserved8 = kOffFlags + 1;              // 23
constexpr std::size_t kOffWatchdog = kOffReserved8 + 1;           // 24
constexpr std::size_t kOffReserved16 = kOffWatchdog + 2;          // 26
constexpr std::size_t kOffCommandCrc = kOffReserved16 + 2;        // 28
static_assert(kOffCommandCrc + 4 == kCommandSize);

void putHeader(uint8_t* p, uint8_t version, uint8_t type, uint32_t seq) noexcept {
  p[0] = kMagic[0];
  p[1] = kMagic[1];
  p[2] = version;
  p[3] = type;
  put32(p + kOffSeq, seq);
}

DecodeError checkFrame(std::span<const uint8_t> in, std::size_t size, uint8_t type) noexcept {
  if (in.size() < size) return DecodeError::kShort;
  if (in.size() > size) return DecodeError::kLong;
  if (in[0] != kMagic[0] || in[1] != kMagic[1]) return DecodeError::kBadMagic;
  if (in[2] != kProtocolVersion) return DecodeError::kBadVersion;
  if (in[3] != type) return DecodeError::kBadType;
  if (crc32(in.first(size - 4)) != get32(in.data() + size - 4)) return DecodeError::kBadCrc;
  return DecodeError::kOk;
}

}  // namespace

std::string_view toString(DecodeError e) noexcept {
  switch (e) {
    case DecodeError::kOk:
      return "ok";
    case DecodeError::kShort:
      return "short packet";
    case DecodeError::kLong:
      return "oversized packet";
    case DecodeError::kBadMagic:
      return "bad magic";
    case DecodeError::kBadVersion:
      return "unsupported protocol version";
    case DecodeError::kBadType:
      return "wrong packet type";
    case DecodeError::kBadCrc:
      return "CRC mismatch";
    case DecodeError::kBadValue:
      return "value out of range";
  }
  return "unknown";
}

uint32_t crc32(std::span<const uint8_t> bytes) noexcept {
  uint32_t c = 0xFFFFFFFFu;
  for (const uint8_t b : bytes) c = kCrcTable[(c ^ b) & 0xFFu] ^ (c >> 8);
  return c ^ 0xFFFFFFFFu;
}

std::size_t encodeState(const StatePacket& s, std::span<uint8_t> out, uint8_t version) noexcept {
  if (out.size() < kStateSize) return 0;
  uint8_t* p = out.data();
  putHeader(p, version, kTypeState, s.seq);
  put64(p + kOffTime, s.device_time_us);
  for (int i = 0; i < kActuators; ++i) {
    put32(p + kOffActuators + 4 * i, static_cast<uint32_t>(s.actuator_counts[i]));
  }
  for (int i = 0; i < kGimbals; ++i) {
    put32(p + kOffGimbals + 4 * i, static_cast<uint32_t>(s.gimbal_counts[i]));
  }
  for (int i = 0; i < kFsrs; ++i) put16(p + kOffFsr + 2 * i, s.fsr_raw[i]);
  put16(p + kOffStatus, s.status);
  put16(p + kOffRxErrors, s.rx_errors);
  put32(p + kOffLastCommand, s.last_command_seq);
  put32(p + kOffStateCrc, crc32(out.first(kOffStateCrc)));
  return kStateSize;
}

std::size_t encodeCommand(const CommandPacket& c, std::span<uint8_t> out,
                          uint8_t version) noexcept {
  if (out.size() < kCommandSize) return 0;
  uint8_t* p = out.data();
  putHeader(p, version, kTypeCommand, c.seq);
  for (int i = 0; i < kActuators; ++i) {
    put16(p + kOffCurrents + 2 * i, static_cast<uint16_t>(c.current_ma[i]));
  }
  p[kOffFlags] = c.flags;
  p[kOffReserved8] = 0;
  put16(p + kOffWatchdog, c.watchdog_ms);
  put16(p + kOffReserved16, 0);
  put32(p + kOffCommandCrc, crc32(out.first(kOffCommandCrc)));
  return kCommandSize;
}

DecodeError decodeState(std::span<const uint8_t> in, StatePacket& out) noexcept {
  if (const DecodeError e = checkFrame(in, kStateSize, kTypeState); e != DecodeError::kOk) {
    return e;
  }
  const uint8_t* p = in.data();
  StatePacket s;
  s.seq = get32(p + kOffSeq);
  s.device_time_us = get64(p + kOffTime);
  for (int i = 0; i < kActuators; ++i) {
    s.actuator_counts[i] = static_cast<int32_t>(get32(p + kOffActuators + 4 * i));
  }
  for (int i = 0; i < kGimbals; ++i) {
    s.gimbal_counts[i] = static_cast<int32_t>(get32(p + kOffGimbals + 4 * i));
  }
  for (int i = 0; i < kFsrs; ++i) {
    s.fsr_raw[i] = get16(p + kOffFsr + 2 * i);
    if (s.fsr_raw[i] > kFsrMaxRaw) return DecodeError::kBadValue;
  }
  s.status = get16(p + kOffStatus);
  if ((s.status & ~kStatusKnownBits) != 0) return DecodeError::kBadValue;
  s.rx_errors = get16(p + kOffRxErrors);
  s.last_command_seq = get32(p + kOffLastCommand);
  out = s;
  return DecodeError::kOk;
}

DecodeError decodeCommand(std::span<const uint8_t> in, CommandPacket& out) noexcept {
  if (const DecodeError e = checkFrame(in, kCommandSize, kTypeCommand); e != DecodeError::kOk) {
    return e;
  }
  const uint8_t* p = in.data();
  CommandPacket c;
  c.seq = get32(p + kOffSeq);
  for (int i = 0; i < kActuators; ++i) {
    c.current_ma[i] = static_cast<int16_t>(get16(p + kOffCurrents + 2 * i));
  }
  c.flags = p[kOffFlags];
  c.watchdog_ms = get16(p + kOffWatchdog);
  if ((c.flags & ~kCommandKnownFlags) != 0 || p[kOffReserved8] != 0 ||
      get16(p + kOffReserved16) != 0 || c.watchdog_ms < kWatchdogMinMs ||
      c.watchdog_ms > kWatchdogMaxMs) {
    return DecodeError::kBadValue;
  }
  out = c;
  return DecodeError::kOk;
}

SequenceTracker::Verdict SequenceTracker::check(uint32_t seq, uint64_t time_us) noexcept {
  Verdict v = Verdict::kAccept;
  if (have_last_) {
    const auto ahead = static_cast<int32_t>(seq - last_seq_);
    if (ahead < 0) {
      v = Verdict::kOutOfOrder;
    } else if (ahead == 0 || time_us <= last_time_us_) {
      v = Verdict::kStale;
    }
  }
  if (v == Verdict::kAccept) {
    if (have_last_) lost_ += static_cast<uint32_t>(seq - last_seq_) - 1u;
    have_last_ = true;
    last_seq_ = seq;
    last_time_us_ = time_us;
    have_run_ = false;
    ++accepted_;
    return v;
  }
  // A run of rejected packets that are in order among themselves: the device restarted.
  if (have_run_ && seq == run_seq_ + 1 && time_us > run_time_us_) {
    ++run_length_;
  } else {
    run_length_ = 1;
  }
  have_run_ = true;
  run_seq_ = seq;
  run_time_us_ = time_us;
  if (run_length_ >= kResyncRun) {
    ++resyncs_;
    ++accepted_;
    last_seq_ = seq;
    last_time_us_ = time_us;
    have_run_ = false;
    return Verdict::kAccept;
  }
  (v == Verdict::kStale ? stale_ : out_of_order_) += 1;
  return v;
}

}  // namespace telehand::devices::proto
