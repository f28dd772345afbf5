#pragma once
/// The MF-2 controller board's USB wire protocol, version 1 (docs/mf2-usb-protocol.md): a
/// 96-byte state packet from the device every millisecond and a 32-byte command packet from
/// the host. Little-endian, CRC-32 protected. This codec has no dependencies besides the
/// standard library (the fuzzer builds it alone), allocates nothing and never throws.
#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string_view>

namespace telehand::devices::proto {

constexpr uint8_t kProtocolVersion = 1;
constexpr std::array<uint8_t, 2> kMagic = {'M', '2'};
constexpr uint8_t kTypeState = 0x01;
constexpr uint8_t kTypeCommand = 0x02;

/// USB identity. The IDs are placeholders (not registered): set the board's own with
/// --usb-vid/--usb-pid and in deploy/udev/60-telehand-mf2.rules.
constexpr uint16_t kDefaultVendorId = 0x1209;
constexpr uint16_t kDefaultProductId = 0x4d32;
constexpr uint8_t kInterfaceNumber = 0;
constexpr uint8_t kEndpointIn = 0x81;   ///< interrupt IN, 1 ms interval: state packets
constexpr uint8_t kEndpointOut = 0x01;  ///< interrupt OUT: command packets

constexpr int kActuators =
    7;                       ///< 0 the shared base joint, 1-3 thumb, 4-6 index (device model order)
constexpr int kGimbals = 6;  ///< 0-2 thumb gimbal, 3-5 index gimbal
constexpr int kFsrs = 8;     ///< 0-3 thumb FSRs 1..4, 4-7 index FSRs 1..4
constexpr uint16_t kFsrMaxRaw = 4095;  ///< 12-bit ADC

constexpr std::size_t kStateSize = 96;
constexpr std::size_t kCommandSize = 32;
constexpr std::size_t kMaxPacketIn = 128;  ///< wMaxPacketSize of the IN endpoint

/// State status bits (device -> host).
enum StateStatus : uint16_t {
  kStatusEnabled = 1u << 0,          ///< actuators powered and following commands
  kStatusEstopButton = 1u << 1,      ///< the hardware emergency-stop button is pressed
  kStatusEstopLatched = 1u << 2,     ///< an e-stop happened; cleared by kCommandClearFault
  kStatusWatchdogExpired = 1u << 3,  ///< no valid command within the watchdog period
  kStatusOvercurrent = 1u << 4,      ///< a commanded current was above the limit and clamped
  kStatusFsrFault = 1u << 5,         ///< an FSR channel reads open or shorted
  kStatusEncoderFault = 1u << 6,     ///< an encoder lost count (index pulse mismatch)
  kStatusCommandRejected = 1u << 7,  ///< the last command packet failed its checks
};
constexpr uint16_t kStatusKnownBits = 0x00ff;

/// Command flag bits (host -> device).
enum CommandFlags : uint8_t {
  kCommandEnable = 1u << 0,      ///< drive the actuators (off: zero current)
  kCommandEstop = 1u << 1,       ///< emergency stop: zero current, latch until cleared
  kCommandClearFault = 1u << 2,  ///< clear a latched e-stop / watchdog (only without kCommandEstop)
};
constexpr uint8_t kCommandKnownFlags = 0x07;
constexpr uint16_t kWatchdogMinMs = 2;
constexpr uint16_t kWatchdogMaxMs = 1000;

struct StatePacket {
  uint32_t seq = 0;             ///< +1 per 1 kHz tick, wraps
  uint64_t device_time_us = 0;  ///< device clock since power-up
  std::array<int32_t, kActuators> actuator_counts{};
  std::array<int32_t, kGimbals> gimbal_counts{};
  std::array<uint16_t, kFsrs> fsr_raw{};
  uint16_t status = 0;            ///< StateStatus bits
  uint16_t rx_errors = 0;         ///< command packets the device rejected (saturates)
  uint32_t last_command_seq = 0;  ///< seq of the last command the device accepted
};

struct CommandPacket {
  uint32_t seq = 0;
  std::array<int16_t, kActuators> current_ma{};  ///< signed motor currents, mA
  uint8_t flags = 0;                             ///< CommandFlags bits
  uint16_t watchdog_ms = 20;                     ///< zero current after this long without a command
};

enum class DecodeError : uint8_t {
  kOk = 0,
  kShort,  ///< fewer bytes than the packet
  kLong,   ///< more bytes than the packet
  kBadMagic,
  kBadVersion,  ///< a protocol this codec does not speak
  kBadType,
  kBadCrc,
  kBadValue,  ///< well-formed but out of range (FSR above 12 bits, unknown bits, watchdog)
};
std::string_view toString(DecodeError e) noexcept;

/// CRC-32 (ISO-HDLC / IEEE 802.3: reflected 0x04C11DB7, init and xor-out 0xFFFFFFFF).
uint32_t crc32(std::span<const uint8_t> bytes) noexcept;

/// Encoders write exactly kStateSize / kCommandSize bytes; `out` must be at least that long
/// (otherwise they write nothing and return 0). `version` is for tests of version handling.
std::size_t encodeState(const StatePacket& p, std::span<uint8_t> out,
                        uint8_t version = kProtocolVersion) noexcept;
std::size_t encodeCommand(const CommandPacket& p, std::span<uint8_t> out,
                          uint8_t version = kProtocolVersion) noexcept;

/// Decoders check length, magic, version, type, CRC and value ranges; `out` is written only
/// when the result is kOk.
DecodeError decodeState(std::span<const uint8_t> in, StatePacket& out) noexcept;
DecodeError decodeCommand(std::span<const uint8_t> in, CommandPacket& out) noexcept;

/// Sequence checks on decoded packets (one instance per stream, reset on reconnect).
/// Accepts a packet only if its seq is ahead of the last accepted one (a gap counts the
/// packets lost) and its device time advanced. A repeat of the last seq or time is stale, a
/// seq behind is out of order; both are rejected. A device that restarted its counter
/// without re-enumerating is followed again after kResyncRun consecutive packets that are
/// in order among themselves.
class SequenceTracker {
 public:
  enum class Verdict : uint8_t { kAccept, kStale, kOutOfOrder };
  static constexpr uint32_t kResyncRun = 8;

  Verdict check(uint32_t seq, uint64_t device_time_us) noexcept;
  void reset() noexcept { *this = SequenceTracker{}; }

  uint64_t accepted() const noexcept { return accepted_; }
  uint64_t lost() const noexcept { return lost_; }  ///< seq gaps among accepted packets
  uint64_t stale() const noexcept { return stale_; }
  uint64_t outOfOrder() const noexcept { return out_of_order_; }
  uint64_t resyncs() const noexcept { return resyncs_; }

 private:
  bool have_last_ = false;
  uint32_t last_seq_ = 0;
  uint64_t last_time_us_ = 0;
  bool have_run_ = false;
  uint32_t run_seq_ = 0;
  uint64_t run_time_us_ = 0;
  uint32_t run_length_ = 0;
  uint64_t accepted_ = 0, lost_ = 0, stale_ = 0, out_of_order_ = 0, resyncs_ = 0;
};

}  // namespace telehand::devices::proto
