#pragma once
/// The MF-2 over USB (libusb). A thread of its own runs libusb's event loop: asynchronous
/// interrupt transfers (state packets in, command packets out), hotplug, reconnection and
/// error recovery. The haptic loop's read()/write() only touch wait-free triple buffers and
/// atomics: they never block on USB, allocate or lock.
///
/// Every accepted state packet is answered with one command packet carrying the newest force
/// the loop wrote (zero, actuators disabled, if the loop has not written for
/// command_fresh_ns). Unplugging sets status() to kDisconnected at once; the loop then
/// commands zero force, and the driver reopens the device when it comes back.
#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "telehand/core/clock.h"
#include "telehand/core/rt/spsc_ring.h"
#include "telehand/core/rt/triple_buffer.h"
#include "telehand/devices/device.h"
#include "telehand/devices/mf2_calibration.h"
#include "telehand/devices/mf2_protocol.h"

struct libusb_context;
struct libusb_device_handle;
struct libusb_transfer;
struct libusb_device;

namespace telehand::client::usb {

namespace proto = devices::proto;
using devices::Device;
using devices::DeviceDynamics;
using devices::DeviceSample;
using devices::DeviceStatus;
using devices::ForceCommand;
using devices::Mf2Calibration;

struct UsbMf2Config {
  uint16_t vendor_id = proto::kDefaultVendorId;
  uint16_t product_id = proto::kDefaultProductId;
  std::string serial;         ///< empty: the first MF-2 found
  uint16_t watchdog_ms = 20;  ///< the device zeroes current after this long without a command
  int in_timeout_ms = 100;    ///< no state packet for this long is a timeout error
  int out_timeout_ms = 50;
  int64_t command_fresh_ns = 10'000'000;  ///< older loop output is replaced by zero force
  int reconnect_period_ms = 200;          ///< how often to look for the device while it is absent
  int in_flight = 2;                      ///< IN transfers queued (1..4)
};

/// Counters the USB thread writes and any thread reads.
struct UsbMf2Stats {
  std::atomic<uint64_t> packets_in{0};              ///< state packets accepted
  std::atomic<uint64_t> commands_out{0};            ///< command packets the device took
  std::array<std::atomic<uint64_t>, 8> rejected{};  ///< by proto::DecodeError
  std::atomic<uint64_t> stale{0};                   ///< repeated seq or device time
  std::atomic<uint64_t> out_of_order{0};            ///< seq behind the last accepted one
  std::atomic<uint64_t> lost{0};                    ///< seq gaps: packets never seen
  std::atomic<uint64_t> resyncs{0};          ///< device counter restarted without re-enumerating
  std::atomic<uint64_t> bad_pose{0};         ///< encoder counts the linkage cannot take: rejected
  std::atomic<uint64_t> stalls{0};           ///< endpoint halts (cleared and resumed)
  std::atomic<uint64_t> timeouts{0};         ///< IN or OUT transfers that timed out
  std::atomic<uint64_t> overflows{0};        ///< IN packets larger than the buffer
  std::atomic<uint64_t> transfer_errors{0};  ///< other transfer failures
  std::atomic<uint64_t> connects{0};
  std::atomic<uint64_t> disconnects{0};
  std::atomic<uint64_t> stale_loop_output{0};  ///< commands sent as zero: the loop stopped writing
  std::atomic<uint64_t> device_rx_errors{0};   ///< commands the device reported rejecting
  std::atomic<uint64_t> rtt_count{0};          ///< command -> state echoing it
  std::atomic<int64_t> rtt_sum_ns{0};
  std::atomic<int64_t> rtt_max_ns{0};

  uint64_t rejectedTotal() const noexcept;
};

/// One attached MF-2 as the probe lists it.
struct UsbMf2Info {
  uint8_t bus = 0;
  uint8_t address = 0;
  uint16_t vendor_id = 0;
  uint16_t product_id = 0;
  uint16_t bcd_device = 0;
  std::string serial;   ///< empty if it could not be read
  std::string problem;  ///< why it cannot be opened (permissions, busy...), empty if it can
};

/// Lists attached devices with the given IDs (opens each briefly to read its serial and to
/// check permissions). Throws DeviceError if libusb cannot start.
std::vector<UsbMf2Info> listUsbMf2(uint16_t vendor_id = proto::kDefaultVendorId,
                                   uint16_t product_id = proto::kDefaultProductId);

/// The list as the probe and `telehand-client --list-devices` print it.
std::string formatUsbMf2List(const std::vector<UsbMf2Info>& devices, uint16_t vendor_id,
                             uint16_t product_id);

/// A USB vendor or product ID in hex as lsusb prints it ("1209" or "0x1209"); throws
/// ConfigError naming `what` if it is not one.
uint16_t parseUsbId(const std::string& text, const std::string& what);

class UsbMf2 final : public Device {
 public:
  /// `calibration` and `clock` must outlive the device (the calibration is used by the USB
  /// thread only). Samples are stamped with `clock` when they arrive (the loop's clock: its
  /// watchdog compares against it).
  UsbMf2(const UsbMf2Config& config, Mf2Calibration& calibration, const Clock& clock);
  ~UsbMf2() override;
  UsbMf2(const UsbMf2&) = delete;
  UsbMf2& operator=(const UsbMf2&) = delete;

  /// Starts libusb and the USB thread (throws DeviceError if libusb cannot start). The
  /// device may be absent: the thread keeps looking for it.
  void start();
  /// Sends a last zero, disabled command if the device is open, closes it, joins the thread.
  void stop();
  /// Waits until state packets stream (status kOk) or the timeout passes.
  bool waitReady(std::chrono::milliseconds timeout) const;

  // Real-time side.
  bool read(DeviceSample& out) noexcept override;
  bool write(const ForceCommand& cmd) noexcept override;
  DeviceStatus status() const noexcept override { return status_.load(std::memory_order_acquire); }
  std::string_view name() const noexcept override { return "usb"; }
  /// The lightest mass met at the thimbles in any pose streamed so far (the calibration's
  /// model, worked out every 64 packets on the USB thread), and one packet of command delay.
  DeviceDynamics dynamics() const noexcept override {
    return {lightest_mass_kg_.load(std::memory_order_relaxed), 1};
  }

  // Any other thread.
  /// What the driver is doing or why it cannot: "streaming from bus 1 address 3", "no MF-2
  /// (USB 1209:4d32) attached", "permission denied ...".
  std::string statusText() const;
  /// Status changes and errors since the last call, oldest first (bounded).
  std::vector<std::string> takeMessages();
  const UsbMf2Stats& stats() const noexcept { return stats_; }
  /// The newest accepted raw state packet (one consumer thread only).
  bool latestRaw(proto::StatePacket& out) noexcept { return raw_->read(out); }
  /// Command -> echo round trips in ns (one consumer thread only; new ones dropped when full).
  SpscRing<int64_t, 4096>& roundTrips() noexcept { return *rtt_; }
  /// Latch an emergency stop on the device (true), or clear a latched one (false).
  void emergencyStop(bool on) noexcept;

 private:
  struct TimedForce {
    ForceCommand force;
    int64_t time_ns = 0;
  };

  void run();
  void tryOpen();
  void closeDevice();
  bool anyInBusy() const noexcept;
  void submitIn(int i);
  void sendCommand();
  void afterEvents();
  void handlePacket(const uint8_t* data, int length);
  /// The status for the device's fault bits and the bad-pose run (set on a change only).
  void reportFaults(uint16_t status);
  void markDisconnected(const std::string& why);
  void setStatus(DeviceStatus s, const std::string& text, bool notify);
  void note(const std::string& message);

  void onIn(libusb_transfer* t);
  void onOut(libusb_transfer* t);
  void onHotplug(libusb_device* dev, bool arrived);
  friend struct UsbMf2Callbacks;

  UsbMf2Config cfg_;
  Mf2Calibration& cal_;
  const Clock& clock_;

  std::atomic<DeviceStatus> status_{DeviceStatus::kNotReady};
  std::atomic<bool> running_{false};
  std::atomic<bool> estop_request_{false};
  std::atomic<bool> clear_request_{false};
  std::atomic<double> lightest_mass_kg_{0.0};
  std::thread thread_;

  // Hand-offs with the real-time loop and the probe.
  std::unique_ptr<TripleBuffer<DeviceSample>> samples_;
  std::unique_ptr<TripleBuffer<TimedForce>> forces_;
  std::unique_ptr<TripleBuffer<proto::StatePacket>> raw_;
  std::unique_ptr<SpscRing<int64_t, 4096>> rtt_;
  UsbMf2Stats stats_;

  // USB thread only.
  libusb_context* ctx_ = nullptr;
  libusb_device_handle* handle_ = nullptr;
  int hotplug_handle_ = 0;
  bool has_hotplug_ = false;
  std::atomic<bool> hotplug_arrived_{false};
  static constexpr int kMaxInFlight = 4;
  std::array<libusb_transfer*, kMaxInFlight> in_xfer_{};
  std::array<bool, kMaxInFlight> in_busy_{};
  std::array<std::array<uint8_t, proto::kMaxPacketIn>, kMaxInFlight> in_buf_{};
  libusb_transfer* out_xfer_ = nullptr;
  bool out_busy_ = false;
  std::array<uint8_t, proto::kCommandSize> out_buf_{};
  bool command_pending_ = false;
  bool clear_halt_in_ = false;
  bool clear_halt_out_ = false;
  bool disconnect_pending_ = false;
  bool closing_ = false;
  bool have_state_ = false;
  uint32_t mass_countdown_ = 0;  // packets until the lightest mass is worked out again
  int consecutive_errors_ = 0;
  proto::SequenceTracker tracker_;
  proto::StatePacket state_{};
  /// Status bits that make the device a fault (DeviceStatus::kFault): an emergency stop, an
  /// encoder that lost count.
  static constexpr uint16_t kDeviceFaultBits =
      proto::kStatusEstopButton | proto::kStatusEstopLatched | proto::kStatusEncoderFault;
  uint16_t reported_faults_ = 0;  // the fault bits the status text tells of
  /// Packets in a row whose encoder counts the linkage cannot take (a lost count, a device
  /// file's zero off by a turn): no force while there is one; a fault after kBadPoseFault.
  uint32_t bad_pose_run_ = 0;
  static constexpr uint32_t kBadPoseFault = 100;  // 0.1 s at 1 kHz
  /// reported_faults_'s bit for a pose out of the linkage's range (no device status bit).
  static constexpr uint16_t kBadPoseBit = 1u << 15;
  TimedForce force_{};
  uint32_t cmd_seq_ = 0;
  uint32_t last_echo_ = 0;
  std::array<int64_t, 64> sent_ns_{};
  std::string where_;  // "bus 1 address 3"

  mutable std::mutex text_mu_;
  std::string status_text_;
  std::deque<std::string> messages_;
};

}  // namespace telehand::client::usb
