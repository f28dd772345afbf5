#include "telehand/client/usb/usb_mf2.h"

#include <libusb.h>
#include <pthread.h>
#include <sys/prctl.h>

#include <cstdio>

#include "telehand/core/error.h"

namespace telehand::client::usb {

namespace {

constexpr std::size_t kMaxMessages = 256;

std::string hex4(uint16_t v) {
  char b[8];
  std::snprintf(b, sizeof b, "%04x", v);
  return b;
}

std::string ids(uint16_t vid, uint16_t pid) { return hex4(vid) + ":" + hex4(pid); }

std::string usbError(int rc) {
  return std::string(libusb_error_name(rc)) + ": " + libusb_strerror(static_cast<libusb_error>(rc));
}

std::string permissionHint(uint16_t vid, uint16_t pid) {
  return "permission denied on the USB device node. Install the udev rule "
         "(sudo cp deploy/udev/60-telehand-mf2.rules /etc/udev/rules.d/ && sudo udevadm control "
         "--reload && sudo udevadm trigger), make sure it names " +
         ids(vid, pid) + ", and replug the MF-2";
}

/// The MF-2 interface: vendor class, one interrupt IN (0x81) and one interrupt OUT (0x01).
bool hasMf2Interface(libusb_device* dev) {
  libusb_config_descriptor* cfg = nullptr;
  if (libusb_get_active_config_descriptor(dev, &cfg) != 0) {
    if (libusb_get_config_descriptor(dev, 0, &cfg) != 0) return false;
  }
  bool in = false, out = false;
  for (int i = 0; i < cfg->bNumInterfaces; ++i) {
    const libusb_interface& itf = cfg->interface[i];
    if (itf.num_altsetting < 1) continue;
    const libusb_interface_descriptor& alt = itf.altsetting[0];
    if (alt.bInterfaceNumber != proto::kInterfaceNumber ||
        alt.bInterfaceClass != LIBUSB_CLASS_VENDOR_SPEC) {
      continue;
    }
    for (int e = 0; e < alt.bNumEndpoints; ++e) {
      const libusb_endpoint_descriptor& ep = alt.endpoint[e];
      const bool interrupt = (ep.bmAttributes & 0x3) == LIBUSB_TRANSFER_TYPE_INTERRUPT;
      in |= interrupt && ep.bEndpointAddress == proto::kEndpointIn &&
            ep.wMaxPacketSize >= proto::kStateSize;
      out |= interrupt && ep.bEndpointAddress == proto::kEndpointOut &&
             ep.wMaxPacketSize >= proto::kCommandSize;
    }
  }
  libusb_free_config_descriptor(cfg);
  return in && out;
}

std::string readSerial(libusb_device_handle* h, uint8_t index) {
  if (index == 0) return {};
  unsigned char buf[128] = {};
  const int n = libusb_get_string_descriptor_ascii(h, index, buf, sizeof buf);
  return n > 0 ? std::string(reinterpret_cast<char*>(buf), static_cast<std::size_t>(n))
               : std::string{};
}

void bump(std::atomic<uint64_t>& c, uint64_t n = 1) noexcept {
  c.fetch_add(n, std::memory_order_relaxed);
}

}  // namespace

/// libusb's C callbacks, forwarded to the driver on the USB thread.
struct UsbMf2Callbacks {
  static void LIBUSB_CALL in(libusb_transfer* t) { static_cast<UsbMf2*>(t->user_data)->onIn(t); }
  static void LIBUSB_CALL out(libusb_transfer* t) { static_cast<UsbMf2*>(t->user_data)->onOut(t); }
  static int LIBUSB_CALL hotplug(libusb_context*, libusb_device* dev, libusb_hotplug_event ev,
                                 void* self) {
    static_cast<UsbMf2*>(self)->onHotplug(dev, ev == LIBUSB_HOTPLUG_EVENT_DEVICE_ARRIVED);
    return 0;
  }
};

uint64_t UsbMf2Stats::rejectedTotal() const noexcept {
  uint64_t n = 0;
  for (const auto& r : rejected) n += r.load(std::memory_order_relaxed);
  return n;
}

std::vector<UsbMf2Info> listUsbMf2(uint16_t vendor_id, uint16_t product_id) {
  libusb_context* ctx = nullptr;
  if (const int rc = libusb_init(&ctx); rc != 0) {
    throw DeviceError("cannot start libusb (" + usbError(rc) + ")");
  }
  std::vector<UsbMf2Info> found;
  libusb_device** list = nullptr;
  const ssize_t n = libusb_get_device_list(ctx, &list);
  for (ssize_t i = 0; i < n; ++i) {
    libusb_device_descriptor d{};
    if (libusb_get_device_descriptor(list[i], &d) != 0) continue;
    if (d.idVendor != vendor_id || d.idProduct != product_id) continue;
    UsbMf2Info info;
    info.bus = libusb_get_bus_number(list[i]);
    info.address = libusb_get_device_address(list[i]);
    info.vendor_id = d.idVendor;
    info.product_id = d.idProduct;
    info.bcd_device = d.bcdDevice;
    libusb_device_handle* h = nullptr;
    const int rc = libusb_open(list[i], &h);
    if (rc == LIBUSB_ERROR_ACCESS) {
      info.problem = permissionHint(vendor_id, product_id);
    } else if (rc != 0) {
      info.problem = "cannot open (" + usbError(rc) + ")";
    } else {
      info.serial = readSerial(h, d.iSerialNumber);
      if (!hasMf2Interface(list[i]))
        info.problem = "no MF-2 interface (vendor class, endpoints 0x81/0x01)";
      libusb_close(h);
    }
    found.push_back(std::move(info));
  }
  if (list != nullptr) libusb_free_device_list(list, 1);  // allocated even when empty
  libusb_exit(ctx);
  return found;
}

std::string formatUsbMf2List(const std::vector<UsbMf2Info>& devices, uint16_t vendor_id,
                             uint16_t product_id) {
  if (devices.empty()) {
    return "no MF-2 (USB " + ids(vendor_id, product_id) + ") attached\n";
  }
  std::string out;
  for (const UsbMf2Info& d : devices) {
    char line[160];
    std::snprintf(line, sizeof line,
                  "MF-2 %s at bus %03u address %03u, firmware %x.%02x, serial %s: ",
                  ids(d.vendor_id, d.product_id).c_str(), d.bus, d.address, d.bcd_device >> 8,
                  d.bcd_device & 0xffu, d.serial.empty() ? "(unknown)" : d.serial.c_str());
    out += line;
    out += d.problem.empty() ? "ready" : d.problem;
    out += "\n";
  }
  return out;
}

uint16_t parseUsbId(const std::string& text, const std::string& what) {
  std::string digits = text;
  if (digits.size() > 2 && digits[0] == '0' && (digits[1] == 'x' || digits[1] == 'X')) {
    digits = digits.substr(2);
  }
  const bool hex = !digits.empty() && digits.size() <= 4 &&
                   digits.find_first_not_of("0123456789abcdefABCDEF") == std::string::npos;
  if (!hex) {
    throw ConfigError(what + ": '" + text + "' is not a 16-bit hex USB ID (e.g. 1209)");
  }
  return static_cast<uint16_t>(std::stoul(digits, nullptr, 16));
}

UsbMf2::UsbMf2(const UsbMf2Config& config, Mf2Calibration& calibration, const Clock& clock)
    : cfg_(config),
      cal_(calibration),
      clock_(clock),
      samples_(std::make_unique<TripleBuffer<DeviceSample>>()),
      forces_(std::make_unique<TripleBuffer<TimedForce>>()),
      raw_(std::make_unique<TripleBuffer<proto::StatePacket>>()),
      rtt_(std::make_unique<SpscRing<int64_t, 4096>>()) {
  if (cfg_.in_flight < 1 || cfg_.in_flight > kMaxInFlight) {
    throw DeviceError("usb: in_flight must be 1.." + std::to_string(kMaxInFlight));
  }
  if (cfg_.watchdog_ms < proto::kWatchdogMinMs || cfg_.watchdog_ms > proto::kWatchdogMaxMs) {
    throw DeviceError("usb: watchdog_ms must be " + std::to_string(proto::kWatchdogMinMs) + ".." +
                      std::to_string(proto::kWatchdogMaxMs));
  }
  status_text_ = "not started";
}

UsbMf2::~UsbMf2() {
  stop();
  for (auto*& t : in_xfer_) {
    libusb_free_transfer(t);
    t = nullptr;
  }
  libusb_free_transfer(out_xfer_);
  if (ctx_ != nullptr) libusb_exit(ctx_);
}

void UsbMf2::start() {
  if (running_.load()) return;
  if (ctx_ == nullptr) {
    if (const int rc = libusb_init(&ctx_); rc != 0) {
      ctx_ = nullptr;
      throw DeviceError("cannot start libusb (" + usbError(rc) + ")");
    }
    for (auto& t : in_xfer_) t = libusb_alloc_transfer(0);
    out_xfer_ = libusb_alloc_transfer(0);
  }
  if (!has_hotplug_ && libusb_has_capability(LIBUSB_CAP_HAS_HOTPLUG) != 0) {
    const int rc = libusb_hotplug_register_callback(
        ctx_,
        static_cast<libusb_hotplug_event>(LIBUSB_HOTPLUG_EVENT_DEVICE_ARRIVED |
                                          LIBUSB_HOTPLUG_EVENT_DEVICE_LEFT),
        static_cast<libusb_hotplug_flag>(0), cfg_.vendor_id, cfg_.product_id,
        LIBUSB_HOTPLUG_MATCH_ANY, &UsbMf2Callbacks::hotplug, this, &hotplug_handle_);
    has_hotplug_ = rc == 0;  // without it the thread only polls for the device
  }
  setStatus(DeviceStatus::kNotReady,
            "looking for the MF-2 (USB " + ids(cfg_.vendor_id, cfg_.product_id) + ")", false);
  running_.store(true);
  thread_ = std::thread([this] { run(); });
}

void UsbMf2::stop() {
  if (!running_.exchange(false)) return;
  if (ctx_ != nullptr) libusb_interrupt_event_handler(ctx_);
  if (thread_.joinable()) thread_.join();
  if (has_hotplug_) libusb_hotplug_deregister_callback(ctx_, hotplug_handle_);
  has_hotplug_ = false;
}

bool UsbMf2::waitReady(std::chrono::milliseconds timeout) const {
  const auto end = std::chrono::steady_clock::now() + timeout;
  while (status() != DeviceStatus::kOk) {
    if (std::chrono::steady_clock::now() > end) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return true;
}

bool UsbMf2::read(DeviceSample& out) noexcept { return samples_->read(out); }

bool UsbMf2::write(const ForceCommand& cmd) noexcept {
  forces_->write(TimedForce{cmd, clock_.nowNs()});
  return status() == DeviceStatus::kOk;
}

void UsbMf2::emergencyStop(bool on) noexcept {
  estop_request_.store(on, std::memory_order_release);
  if (!on) clear_request_.store(true, std::memory_order_release);
}

std::string UsbMf2::statusText() const {
  std::lock_guard lock(text_mu_);
  return status_text_;
}

std::vector<std::string> UsbMf2::takeMessages() {
  std::lock_guard lock(text_mu_);
  std::vector<std::string> out(messages_.begin(), messages_.end());
  messages_.clear();
  return out;
}

void UsbMf2::note(const std::string& message) {
  std::lock_guard lock(text_mu_);
  if (messages_.size() >= kMaxMessages) messages_.pop_front();
  messages_.push_back(message);
}

void UsbMf2::setStatus(DeviceStatus s, const std::string& text, bool notify) {
  bool changed = false;
  {
    std::lock_guard lock(text_mu_);
    changed = text != status_text_;
    status_text_ = text;
  }
  status_.store(s, std::memory_order_release);
  if (notify && changed) note(text);
}

// ---- the USB thread ---------------------------------------------------------------------

void UsbMf2::run() {
  // The event loop wakes for every packet: 1 ns timer slack keeps its wake-ups (and the
  // ioctl round trips of an emulated device, docs/facts.md "umockdev") short.
  prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);
  pthread_setname_np(pthread_self(), "telehand-usb");
  auto next_attempt = std::chrono::steady_clock::now();
  while (running_.load(std::memory_order_acquire)) {
    const auto now = std::chrono::steady_clock::now();
    if (handle_ == nullptr && (hotplug_arrived_.exchange(false) || now >= next_attempt)) {
      tryOpen();
      next_attempt = now + std::chrono::milliseconds(cfg_.reconnect_period_ms);
    }
    timeval tv{0, handle_ != nullptr ? 2000 : 20000};
    libusb_handle_events_timeout_completed(ctx_, &tv, nullptr);
    afterEvents();
  }
  closeDevice();
}

void UsbMf2::tryOpen() {
  libusb_device** list = nullptr;
  const ssize_t n = libusb_get_device_list(ctx_, &list);
  int matches = 0;
  std::string problem;
  for (ssize_t i = 0; i < n && handle_ == nullptr; ++i) {
    libusb_device_descriptor d{};
    if (libusb_get_device_descriptor(list[i], &d) != 0) continue;
    if (d.idVendor != cfg_.vendor_id || d.idProduct != cfg_.product_id) continue;
    ++matches;
    const std::string where = "bus " + std::to_string(libusb_get_bus_number(list[i])) +
                              " address " + std::to_string(libusb_get_device_address(list[i]));
    libusb_device_handle* h = nullptr;
    int rc = libusb_open(list[i], &h);
    if (rc == LIBUSB_ERROR_ACCESS) {
      problem = "MF-2 at " + where + ": " + permissionHint(cfg_.vendor_id, cfg_.product_id);
      continue;
    }
    if (rc == LIBUSB_ERROR_NO_DEVICE) {  // still listed, already gone: not there
      --matches;
      continue;
    }
    if (rc != 0) {
      problem = "MF-2 at " + where + ": cannot open (" + usbError(rc) + ")";
      continue;
    }
    const std::string serial = readSerial(h, d.iSerialNumber);
    if (!cfg_.serial.empty() && serial != cfg_.serial) {
      problem = "an MF-2 at " + where + " has serial '" + serial + "', not '" + cfg_.serial + "'";
      libusb_close(h);
      continue;
    }
    if (!hasMf2Interface(list[i])) {
      problem = "USB device " + ids(d.idVendor, d.idProduct) + " at " + where +
                " has no MF-2 interface (vendor class, interrupt endpoints 0x81 and 0x01)";
      libusb_close(h);
      continue;
    }
    rc = libusb_claim_interface(h, proto::kInterfaceNumber);
    if (rc == LIBUSB_ERROR_NO_DEVICE) {  // unplugged while we opened it
      --matches;
      libusb_close(h);
      continue;
    }
    if (rc != 0) {
      problem =
          "MF-2 at " + where + ": cannot claim its interface (" + usbError(rc) + ")" +
          (rc == LIBUSB_ERROR_BUSY ? ": another program (another telehand-client?) uses it" : "");
      libusb_close(h);
      continue;
    }
    handle_ = h;
    where_ = where + (serial.empty() ? "" : ", serial " + serial);
  }
  if (list != nullptr) libusb_free_device_list(list, 1);  // allocated even when empty

  if (handle_ == nullptr) {
    const DeviceStatus s = status() == DeviceStatus::kDisconnected ? DeviceStatus::kDisconnected
                                                                   : DeviceStatus::kNotReady;
    if (matches == 0 && s == DeviceStatus::kDisconnected) return;  // keep saying what happened
    if (matches == 0) {
      problem = "no MF-2 (USB " + ids(cfg_.vendor_id, cfg_.product_id) +
                ") attached; waiting for one (telehand-probe lists devices)";
    }
    setStatus(s, problem, true);
    return;
  }
  tracker_.reset();
  cal_.reset();
  have_state_ = false;
  bad_pose_run_ = 0;
  disconnect_pending_ = false;
  clear_halt_in_ = clear_halt_out_ = false;
  command_pending_ = false;
  consecutive_errors_ = 0;
  cmd_seq_ = 0;
  last_echo_ = 0;
  bump(stats_.connects);
  setStatus(DeviceStatus::kNotReady, "MF-2 opened at " + where_ + "; waiting for state packets",
            true);
  for (int i = 0; i < cfg_.in_flight; ++i) submitIn(i);
}

void UsbMf2::submitIn(int i) {
  if (handle_ == nullptr || disconnect_pending_ || closing_ || in_busy_[i]) return;
  libusb_fill_interrupt_transfer(in_xfer_[i], handle_, proto::kEndpointIn, in_buf_[i].data(),
                                 static_cast<int>(in_buf_[i].size()), &UsbMf2Callbacks::in, this,
                                 static_cast<unsigned>(cfg_.in_timeout_ms));
  const int rc = libusb_submit_transfer(in_xfer_[i]);
  if (rc == 0) {
    in_busy_[i] = true;
  } else if (rc == LIBUSB_ERROR_NO_DEVICE) {
    markDisconnected("unplugged");
  } else if (rc == LIBUSB_ERROR_PIPE) {
    clear_halt_in_ = true;
  } else {
    bump(stats_.transfer_errors);
    note("cannot queue a state transfer (" + usbError(rc) + "); retrying");
  }
}

void UsbMf2::onIn(libusb_transfer* t) {
  int i = 0;
  while (i < kMaxInFlight && in_xfer_[i] != t) ++i;
  if (i == kMaxInFlight) return;
  in_busy_[i] = false;
  switch (t->status) {
    case LIBUSB_TRANSFER_COMPLETED:
      consecutive_errors_ = 0;
      handlePacket(t->buffer, t->actual_length);
      submitIn(i);
      return;
    case LIBUSB_TRANSFER_TIMED_OUT:
      bump(stats_.timeouts);
      if (status() == DeviceStatus::kOk) {
        setStatus(DeviceStatus::kNotReady,
                  "MF-2 at " + where_ + ": no state packet for " +
                      std::to_string(cfg_.in_timeout_ms) +
                      " ms (IN transfer timeout); forces zeroed, waiting for it to resume",
                  true);
      }
      submitIn(i);
      return;
    case LIBUSB_TRANSFER_STALL:
      bump(stats_.stalls);
      clear_halt_in_ = true;
      setStatus(DeviceStatus::kNotReady,
                "MF-2 at " + where_ + ": state endpoint 0x81 stalled; clearing the halt", true);
      return;
    case LIBUSB_TRANSFER_OVERFLOW:
      bump(stats_.overflows);
      note("MF-2 at " + where_ + ": a state packet overflowed the " +
           std::to_string(proto::kMaxPacketIn) + "-byte buffer (overflow); dropped");
      submitIn(i);
      return;
    case LIBUSB_TRANSFER_NO_DEVICE:
      markDisconnected("unplugged");
      return;
    case LIBUSB_TRANSFER_CANCELLED:
      return;
    default:
      bump(stats_.transfer_errors);
      if (++consecutive_errors_ > 50) {
        markDisconnected("50 transfer errors in a row");
        return;
      }
      submitIn(i);
      return;
  }
}

void UsbMf2::handlePacket(const uint8_t* data, int length) {
  proto::StatePacket s;
  const proto::DecodeError e =
      proto::decodeState({data, static_cast<std::size_t>(std::max(length, 0))}, s);
  if (e != proto::DecodeError::kOk) {
    bump(stats_.rejected[static_cast<std::size_t>(e)]);
    if (e == proto::DecodeError::kBadVersion && length > 2) {
      setStatus(DeviceStatus::kFault,
                "MF-2 at " + where_ + " speaks protocol version " + std::to_string(data[2]) +
                    "; this client speaks version " + std::to_string(proto::kProtocolVersion),
                true);
    }
    return;
  }
  const uint64_t stale0 = tracker_.stale(), ooo0 = tracker_.outOfOrder();
  const uint64_t lost0 = tracker_.lost(), resync0 = tracker_.resyncs();
  const auto verdict = tracker_.check(s.seq, s.device_time_us);
  bump(stats_.stale, tracker_.stale() - stale0);
  bump(stats_.out_of_order, tracker_.outOfOrder() - ooo0);
  bump(stats_.lost, tracker_.lost() - lost0);
  bump(stats_.resyncs, tracker_.resyncs() - resync0);
  if (verdict != proto::SequenceTracker::Verdict::kAccept) return;

  DeviceSample sample;
  if (!cal_.toFingers(s, sample.fingers)) {
    // No pose to work the currents out at: the command goes on, zero and disabled (the last
    // one's currents must not stay on until the firmware's watchdog), and the device's own
    // faults are still told; a run of them is a fault of its own.
    bump(stats_.bad_pose);
    if (bad_pose_run_ < UINT32_MAX) ++bad_pose_run_;
    reportFaults(s.status);
    sendCommand();
    return;
  }
  bad_pose_run_ = 0;
  const int64_t now = clock_.nowNs();
  bump(stats_.packets_in);
  stats_.device_rx_errors.store(s.rx_errors, std::memory_order_relaxed);
  if (cmd_seq_ != 0 && s.last_command_seq != last_echo_ &&
      static_cast<uint32_t>(cmd_seq_ - s.last_command_seq) < sent_ns_.size()) {
    const int64_t rtt = now - sent_ns_[s.last_command_seq % sent_ns_.size()];
    rtt_->tryPush(rtt);
    bump(stats_.rtt_count);
    stats_.rtt_sum_ns.fetch_add(rtt, std::memory_order_relaxed);
    if (rtt > stats_.rtt_max_ns.load(std::memory_order_relaxed)) {
      stats_.rtt_max_ns.store(rtt, std::memory_order_relaxed);
    }
  }
  last_echo_ = s.last_command_seq;

  if (mass_countdown_-- == 0) {
    // The pose changes what the thimbles weigh; the loop's damping is bounded by the lightest.
    mass_countdown_ = 63;
    const double m = cal_.lightestMassKg(s);
    const double seen = lightest_mass_kg_.load(std::memory_order_relaxed);
    if (m > 0.0 && (seen == 0.0 || m < seen)) lightest_mass_kg_.store(m, std::memory_order_relaxed);
  }
  sample.seq = s.seq;
  sample.time_ns = now;
  state_ = s;
  have_state_ = true;
  samples_->write(sample);
  raw_->write(s);

  reportFaults(s.status);
  sendCommand();
}

void UsbMf2::reportFaults(uint16_t status) {
  // The device's own faults: an emergency stop, and an encoder that lost count (the pose,
  // and every force worked out at it, is wrong until the device counts true again); and a
  // pose the linkage cannot take, packet after packet. Set and cleared only on a change: the
  // text costs an allocation and a lock, once per packet otherwise.
  auto faults = static_cast<uint16_t>(status & kDeviceFaultBits);
  if (bad_pose_run_ >= kBadPoseFault) faults |= kBadPoseBit;
  const DeviceStatus now_status = status_.load(std::memory_order_relaxed);
  if (faults != 0) {
    if (now_status != DeviceStatus::kFault || faults != reported_faults_) {
      std::string text = "MF-2 at " + where_ + ":";
      if (faults & (proto::kStatusEstopButton | proto::kStatusEstopLatched)) {
        text += (faults & proto::kStatusEstopButton)
                    ? " emergency stop button pressed"
                    : " emergency stop latched (clear it to resume)";
      }
      if (faults & proto::kStatusEncoderFault) {
        if (text.back() != ':') text += ";";
        text += " encoder fault (an encoder lost count): no force until it clears";
      }
      if (faults & kBadPoseBit) {
        if (text.back() != ':') text += ";";
        text += " its encoders read a pose outside the linkage's range (" +
                std::to_string(bad_pose_run_) +
                " packets in a row; an encoder that lost count, or the device file's "
                "zero_counts off): no force until the pose is back in range";
      }
      setStatus(DeviceStatus::kFault, text, true);
      reported_faults_ = faults;
    }
  } else if (now_status != DeviceStatus::kOk && have_state_) {
    reported_faults_ = 0;
    setStatus(DeviceStatus::kOk, "MF-2 streaming from " + where_, true);
  }
}

void UsbMf2::sendCommand() {
  if (handle_ == nullptr || disconnect_pending_ || closing_ || !have_state_) return;
  if (out_busy_ || clear_halt_out_) {
    command_pending_ = true;
    return;
  }
  command_pending_ = false;
  const int64_t now = clock_.nowNs();
  forces_->read(force_);
  const bool fresh = force_.time_ns != 0 && now - force_.time_ns <= cfg_.command_fresh_ns;
  // An encoder that lost count: the currents would be worked out at a wrong pose. Zero, and
  // the actuators disabled, until the device reports it cleared.
  const bool encoder_fault = (state_.status & proto::kStatusEncoderFault) != 0 || bad_pose_run_ > 0;
  proto::CommandPacket c;
  c.seq = ++cmd_seq_;
  if (fresh && !encoder_fault) {
    cal_.toCurrents(force_.force.force_n, state_, c.current_ma);
  } else if (!fresh && force_.time_ns != 0) {
    bump(stats_.stale_loop_output);
  }
  const bool estop = estop_request_.load(std::memory_order_acquire);
  c.flags = static_cast<uint8_t>((fresh && !estop && !encoder_fault ? proto::kCommandEnable : 0) |
                                 (estop ? proto::kCommandEstop : 0));
  if (!estop && clear_request_.exchange(false)) c.flags |= proto::kCommandClearFault;
  c.watchdog_ms = cfg_.watchdog_ms;
  proto::encodeCommand(c, out_buf_);
  sent_ns_[c.seq % sent_ns_.size()] = now;
  libusb_fill_interrupt_transfer(out_xfer_, handle_, proto::kEndpointOut, out_buf_.data(),
                                 static_cast<int>(out_buf_.size()), &UsbMf2Callbacks::out, this,
                                 static_cast<unsigned>(cfg_.out_timeout_ms));
  const int rc = libusb_submit_transfer(out_xfer_);
  if (rc == 0) {
    out_busy_ = true;
  } else if (rc == LIBUSB_ERROR_NO_DEVICE) {
    markDisconnected("unplugged");
  } else if (rc == LIBUSB_ERROR_PIPE) {
    clear_halt_out_ = true;
  } else {
    bump(stats_.transfer_errors);
  }
}

void UsbMf2::onOut(libusb_transfer* t) {
  out_busy_ = false;
  switch (t->status) {
    case LIBUSB_TRANSFER_COMPLETED:
      bump(stats_.commands_out);
      if (command_pending_) sendCommand();
      return;
    case LIBUSB_TRANSFER_TIMED_OUT:
      bump(stats_.timeouts);
      note("MF-2 at " + where_ + ": a command was not taken within " +
           std::to_string(cfg_.out_timeout_ms) + " ms (OUT transfer timeout)");
      return;
    case LIBUSB_TRANSFER_STALL:
      bump(stats_.stalls);
      clear_halt_out_ = true;
      note("MF-2 at " + where_ + ": command endpoint 0x01 stalled; clearing the halt");
      return;
    case LIBUSB_TRANSFER_NO_DEVICE:
      markDisconnected("unplugged");
      return;
    case LIBUSB_TRANSFER_CANCELLED:
      return;
    default:
      bump(stats_.transfer_errors);
      return;
  }
}

void UsbMf2::onHotplug(libusb_device* dev, bool arrived) {
  if (arrived) {
    hotplug_arrived_.store(true);
  } else if (handle_ != nullptr && libusb_get_device(handle_) == dev) {
    markDisconnected("unplugged");
  }
}

void UsbMf2::markDisconnected(const std::string& why) {
  if (handle_ == nullptr || disconnect_pending_) return;
  disconnect_pending_ = true;
  bump(stats_.disconnects);
  setStatus(DeviceStatus::kDisconnected,
            "MF-2 at " + where_ + " disconnected (" + why +
                "): forces zeroed; waiting for it to come back",
            true);
  for (int i = 0; i < kMaxInFlight; ++i) {
    if (in_busy_[i]) libusb_cancel_transfer(in_xfer_[i]);
  }
  if (out_busy_) libusb_cancel_transfer(out_xfer_);
}

void UsbMf2::afterEvents() {
  if (handle_ == nullptr) return;
  const bool any_in_busy = anyInBusy();
  if (disconnect_pending_) {
    if (!any_in_busy && !out_busy_) closeDevice();
    return;
  }
  // A halted endpoint is cleared once nothing is in flight on it; false: the device is gone.
  auto clearHalt = [&](unsigned char endpoint, const char* what, const char* otherwise) {
    const int rc = libusb_clear_halt(handle_, endpoint);
    if (rc == LIBUSB_ERROR_NO_DEVICE) {
      markDisconnected("unplugged");
      return false;
    }
    note(rc == 0 ? "MF-2 at " + where_ + ": " + what + " endpoint halt cleared; resuming"
                 : "MF-2 at " + where_ + ": clearing the " + what + " endpoint halt failed (" +
                       usbError(rc) + ")" + otherwise);
    return true;
  };
  if (clear_halt_in_ && !any_in_busy) {
    if (!clearHalt(proto::kEndpointIn, "state", "; resuming anyway")) return;
    clear_halt_in_ = false;
    for (int i = 0; i < cfg_.in_flight; ++i) submitIn(i);
  }
  if (clear_halt_out_ && !out_busy_) {
    if (!clearHalt(proto::kEndpointOut, "command", "")) return;
    clear_halt_out_ = false;
    command_pending_ = true;
  }
  if (command_pending_ && !out_busy_) sendCommand();
  // An IN queue that emptied without an error (submission failures) is refilled.
  if (!any_in_busy && !clear_halt_in_) {
    for (int i = 0; i < cfg_.in_flight; ++i) submitIn(i);
  }
}

bool UsbMf2::anyInBusy() const noexcept {
  for (const bool b : in_busy_) {
    if (b) return true;
  }
  return false;
}

void UsbMf2::closeDevice() {
  if (handle_ == nullptr) return;
  const bool orderly = !disconnect_pending_;
  closing_ = true;
  for (int i = 0; i < kMaxInFlight; ++i) {
    if (in_busy_[i]) libusb_cancel_transfer(in_xfer_[i]);
  }
  if (!orderly && out_busy_) libusb_cancel_transfer(out_xfer_);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(500);
  while ((out_busy_ || anyInBusy()) && std::chrono::steady_clock::now() < deadline) {
    timeval tv{0, 2000};
    libusb_handle_events_timeout_completed(ctx_, &tv, nullptr);
  }
  if (orderly && have_state_) {
    // Leave the device with zero current and its actuators disabled.
    proto::CommandPacket c;
    c.seq = ++cmd_seq_;
    c.watchdog_ms = cfg_.watchdog_ms;
    std::array<uint8_t, proto::kCommandSize> buf{};
    proto::encodeCommand(c, buf);
    int done = 0;
    libusb_interrupt_transfer(handle_, proto::kEndpointOut, buf.data(),
                              static_cast<int>(buf.size()), &done, 50);
  }
  libusb_release_interface(handle_, proto::kInterfaceNumber);
  libusb_close(handle_);
  handle_ = nullptr;
  in_busy_ = {};
  out_busy_ = false;
  have_state_ = false;
  bad_pose_run_ = 0;
  closing_ = false;
  disconnect_pending_ = false;
  if (orderly) setStatus(DeviceStatus::kNotReady, "MF-2 at " + where_ + " closed", true);
}

}  // namespace telehand::client::usb
