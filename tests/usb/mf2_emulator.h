#pragma once
// An emulated MF-2 on an emulated USB bus, for tests (links umockdev; production never does).
// A umockdev testbed holds the device's sysfs entry (descriptors: one vendor interface with
// an interrupt IN and an interrupt OUT endpoint) and a /dev/bus/usb node whose USBDEVFS
// ioctls a handler answers by running Mf2Firmware. As in libusb's own umockdev tests, the
// process must run under `umockdev-wrapper` (LD_PRELOAD), and the testbed must exist before
// libusb starts. Child processes inherit the emulated bus: their ioctls reach this handler.
//
// Faults a test can inject: endpoint stalls (halt until CLEAR_HALT), a silent device (IN
// transfers time out), oversized packets (overflow), corrupt/short/stale/out-of-order
// packets, unplug and replug.
#include <array>
#include <atomic>
#include <cstdint>
#include <deque>
#include <functional>
#include <mutex>
#include <string>
#include <vector>

#include "mf2_firmware.h"

typedef struct _UMockdevTestbed UMockdevTestbed;
typedef struct _UMockdevIoctlBase UMockdevIoctlBase;
typedef struct _UMockdevIoctlClient UMockdevIoctlClient;
typedef struct _UMockdevIoctlData UMockdevIoctlData;

namespace telehand::test::usb {

struct EmulatorOptions {
  uint16_t vendor_id = proto::kDefaultVendorId;
  uint16_t product_id = proto::kDefaultProductId;
  uint16_t bcd_device = 0x0100;
  std::string serial = "MF2-EMU-0001";
  /// 0: a state packet whenever the host asks (as fast as the emulation goes);
  /// 1'000'000: at most one per millisecond, like the real device.
  int64_t pace_ns = 0;
  FirmwareParams firmware = firmwareFor(mf2::defaultMf2());
};

enum class Corruption {
  kBitFlip,  ///< one payload bit flipped: CRC mismatch
  kShort,    ///< truncated to 60 bytes
  kBadMagic,
  kBadVersion,  ///< protocol version 2
  kDuplicate,   ///< the previous packet again (stale)
  kOutOfOrder,  ///< a packet from 2 ticks ago
};

class Mf2Emulator {
 public:
  explicit Mf2Emulator(const EmulatorOptions& options = {});
  ~Mf2Emulator();
  Mf2Emulator(const Mf2Emulator&) = delete;
  Mf2Emulator& operator=(const Mf2Emulator&) = delete;

  /// Pull the cable: in-flight transfers fail with ESHUTDOWN, every later ioctl with ENODEV,
  /// and udev sees the device leave.
  void unplug();
  /// Plug it back in (the firmware powers up again from reset).
  void replug();
  bool plugged() const;

  void stallIn();                     ///< halt the state endpoint until the host clears it
  void stallOut();                    ///< halt the command endpoint until the host clears it
  void silence(int64_t duration_ns);  ///< answer no IN transfer for this long
  void overflowNext(int count);       ///< next IN transfers complete with EOVERFLOW
  void corruptNext(Corruption kind, int count);

  /// Runs `f` on the firmware with the handler held off.
  template <typename F>
  auto withFirmware(F&& f) {
    std::lock_guard lock(mu_);
    return f(fw_);
  }

  struct Counters {
    uint64_t states_sent = 0;        ///< good state packets delivered
    uint64_t corrupted_sent = 0;     ///< deliberately bad packets delivered
    uint64_t commands_received = 0;  ///< OUT transfers (good or not)
    uint64_t stalls_cleared = 0;
    uint64_t unhandled_ioctls = 0;  ///< must stay 0: something the emulation does not know
    uint64_t discarded = 0;         ///< URBs the host cancelled (timeouts, close)
  };
  Counters counters() const;

  /// The handler callback (umockdev's thread).
  bool handleIoctl(UMockdevIoctlClient* client);

 private:
  struct Urb {
    UMockdevIoctlClient* client = nullptr;  // a reference is held
    UMockdevIoctlData* data = nullptr;      // a reference is held
    unsigned long addr = 0;                 // the URB's address in the client
    uint8_t endpoint = 0;
    int status = 0;
    int actual = 0;
  };
  void addDevice();
  void complete(Urb& u, UMockdevIoctlData* arg, UMockdevIoctlClient* client);
  void release(Urb& u);
  bool produceIn(Urb& u, int64_t now_ns);
  bool answerControl(Urb& u);

  EmulatorOptions opt_;
  UMockdevTestbed* testbed_ = nullptr;
  UMockdevIoctlBase* handler_ = nullptr;

  mutable std::mutex mu_;
  Mf2Firmware fw_;
  bool plugged_ = false;
  bool halted_in_ = false, halted_out_ = false;
  int64_t silent_until_ns_ = 0;
  int overflow_left_ = 0;
  Corruption corruption_ = Corruption::kBitFlip;
  int corrupt_left_ = 0;
  int64_t next_due_ns_ = 0;
  std::array<uint8_t, proto::kStateSize> prev_{}, prev2_{};  // the last two good packets sent
  int prev_count_ = 0;
  std::deque<Urb> pending_in_;  // waiting for the device's next state packet
  std::deque<Urb> done_;        // completed, waiting to be reaped
  Counters counters_;
};

}  // namespace telehand::test::usb
