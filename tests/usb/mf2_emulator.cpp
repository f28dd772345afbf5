#include "mf2_emulator.h"

// docs/facts.md "umockdev": <linux/ioctl.h> must come before <linux/usbdevice_fs.h>.
// clang-format off
#include <linux/ioctl.h>
#include <linux/usbdevice_fs.h>
// clang-format on
#include <time.h>
#include <umockdev.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstddef>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <stdexcept>

namespace telehand::test::usb {

namespace {

constexpr const char* kDevNode = "/dev/bus/usb/001/001";
constexpr const char* kSysPath = "/sys/devices/usb1";

int64_t monotonicNs() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec * 1'000'000'000LL + ts.tv_nsec;
}

std::string hexBytes(const std::vector<uint8_t>& b) {
  std::string s;
  char h[3];
  for (const uint8_t v : b) {
    std::snprintf(h, sizeof h, "%02x", v);
    s += h;
  }
  return s;
}

/// Device descriptor + configuration (one vendor-class interface, interrupt IN 0x81 of
/// 128 bytes and interrupt OUT 0x01 of 64 bytes, both every 1 ms at high speed).
std::vector<uint8_t> descriptors(const EmulatorOptions& o) {
  auto lo = [](uint16_t v) { return static_cast<uint8_t>(v & 0xff); };
  auto hi = [](uint16_t v) { return static_cast<uint8_t>(v >> 8); };
  return {// device: USB 2.0, class per interface, EP0 64 bytes, IDs, bcdDevice, strings 1/2/3
          0x12, 0x01, 0x00, 0x02, 0x00, 0x00, 0x00, 0x40, lo(o.vendor_id), hi(o.vendor_id),
          lo(o.product_id), hi(o.product_id), lo(o.bcd_device), hi(o.bcd_device), 0x01, 0x02, 0x03,
          0x01,
          // configuration 1: 32 bytes in all, one interface, bus powered, 500 mA
          0x09, 0x02, 0x20, 0x00, 0x01, 0x01, 0x00, 0x80, 0xfa,
          // interface 0: two endpoints, vendor specific
          0x09, 0x04, 0x00, 0x00, 0x02, 0xff, 0x00, 0x00, 0x00,
          // endpoint 0x81 interrupt IN, 128 bytes, bInterval 4 (2^3 microframes = 1 ms)
          0x07, 0x05, proto::kEndpointIn, 0x03, lo(proto::kMaxPacketIn), hi(proto::kMaxPacketIn),
          0x04,
          // endpoint 0x01 interrupt OUT, 64 bytes, 1 ms
          0x07, 0x05, proto::kEndpointOut, 0x03, 0x40, 0x00, 0x04};
}

std::vector<uint8_t> stringDescriptor(const std::string& s) {
  std::vector<uint8_t> d{static_cast<uint8_t>(2 + 2 * s.size()), 0x03};
  for (const char c : s) {
    d.push_back(static_cast<uint8_t>(c));
    d.push_back(0);
  }
  return d;
}

gboolean onIoctl(UMockdevIoctlBase*, UMockdevIoctlClient* client, gpointer self) {
  return static_cast<Mf2Emulator*>(self)->handleIoctl(client) ? TRUE : FALSE;
}

}  // namespace

Mf2Emulator::Mf2Emulator(const EmulatorOptions& options) : opt_(options), fw_(options.firmware) {
  const char* preload = std::getenv("LD_PRELOAD");
  if (preload == nullptr || std::strstr(preload, "umockdev-preload") == nullptr) {
    throw std::runtime_error(
        "the emulated MF-2 needs umockdev's preload library: run this under umockdev-wrapper");
  }
  testbed_ = umockdev_testbed_new();
  handler_ = umockdev_ioctl_base_new();
  g_signal_connect_after(handler_, "handle-ioctl", G_CALLBACK(onIoctl), this);
  // docs/facts.md: attach the handler before adding the sysfs device.
  GError* err = nullptr;
  if (!umockdev_testbed_attach_ioctl(testbed_, kDevNode, handler_, &err)) {
    const std::string msg = err ? err->message : "unknown";
    g_clear_error(&err);
    throw std::runtime_error("umockdev: cannot attach the ioctl handler: " + msg);
  }
  addDevice();
  // docs/facts.md: check /sys really is the testbed's, or libusb would talk to the host.
  std::ifstream marker(std::string(kSysPath) + "/telehand_emulated");
  std::string v;
  if (!(marker >> v) || v != "1") {
    throw std::runtime_error("umockdev: /sys is not the testbed's (is the preload active?)");
  }
}

Mf2Emulator::~Mf2Emulator() {
  {
    std::lock_guard lock(mu_);
    for (auto& u : pending_in_) release(u);
    for (auto& u : done_) release(u);
    pending_in_.clear();
    done_.clear();
    plugged_ = false;
  }
  umockdev_testbed_detach_ioctl(testbed_, kDevNode, nullptr);
  g_object_unref(handler_);
  g_object_unref(testbed_);
}

void Mf2Emulator::addDevice() {
  const std::string desc = hexBytes(descriptors(opt_));
  const std::string dev =
      "P: /devices/usb1\n"
      "N: bus/usb/001/001\n"
      "E: SUBSYSTEM=usb\n"
      "E: DRIVER=usb\n"
      "E: BUSNUM=001\n"
      "E: DEVNUM=001\n"
      "E: DEVNAME=/dev/bus/usb/001/001\n"
      "E: DEVTYPE=usb_device\n"
      "A: bConfigurationValue=1\\n\n"
      "A: busnum=1\\n\n"
      "A: devnum=1\\n\n"
      "A: speed=480\\n\n"
      "A: telehand_emulated=1\\n\n"
      "H: descriptors=" +
      desc + "\n";
  {
    std::lock_guard lock(mu_);
    fw_.reset();
    halted_in_ = halted_out_ = false;
    silent_until_ns_ = 0;
    prev_count_ = 0;
    next_due_ns_ = 0;
    plugged_ = true;
  }
  GError* err = nullptr;
  if (!umockdev_testbed_add_from_string(testbed_, dev.c_str(), &err)) {
    const std::string msg = err ? err->message : "unknown";
    g_clear_error(&err);
    throw std::runtime_error("umockdev: cannot add the MF-2: " + msg);
  }
}

void Mf2Emulator::unplug() {
  {
    std::lock_guard lock(mu_);
    if (!plugged_) return;
    plugged_ = false;
    // What the kernel does to URBs of a vanished device.
    for (auto& u : pending_in_) {
      u.status = -ESHUTDOWN;
      u.actual = 0;
      done_.push_back(u);
    }
    pending_in_.clear();
  }
  umockdev_testbed_uevent(testbed_, kSysPath, "remove");
  umockdev_testbed_remove_device(testbed_, kSysPath);
}

void Mf2Emulator::replug() {
  if (plugged()) return;
  addDevice();
}

bool Mf2Emulator::plugged() const {
  std::lock_guard lock(mu_);
  return plugged_;
}

void Mf2Emulator::stallIn() {
  std::lock_guard lock(mu_);
  halted_in_ = true;
}
void Mf2Emulator::stallOut() {
  std::lock_guard lock(mu_);
  halted_out_ = true;
}
void Mf2Emulator::silence(int64_t duration_ns) {
  std::lock_guard lock(mu_);
  silent_until_ns_ = monotonicNs() + duration_ns;
}
void Mf2Emulator::overflowNext(int count) {
  std::lock_guard lock(mu_);
  overflow_left_ = count;
}
void Mf2Emulator::corruptNext(Corruption kind, int count) {
  std::lock_guard lock(mu_);
  corruption_ = kind;
  corrupt_left_ = count;
}

Mf2Emulator::Counters Mf2Emulator::counters() const {
  std::lock_guard lock(mu_);
  return counters_;
}

void Mf2Emulator::release(Urb& u) {
  if (u.data) umockdev_ioctl_data_unref(u.data);
  if (u.client) g_object_unref(u.client);
  u.data = nullptr;
  u.client = nullptr;
}

void Mf2Emulator::complete(Urb& u, UMockdevIoctlData* arg, UMockdevIoctlClient* client) {
  auto* urb = reinterpret_cast<usbdevfs_urb*>(u.data->data);
  urb->status = u.status;
  urb->actual_length = u.actual;
  UMockdevIoctlData* ptr = umockdev_ioctl_data_resolve(arg, 0, sizeof(gpointer), nullptr);
  umockdev_ioctl_data_set_ptr(ptr, 0, u.data);
  umockdev_ioctl_client_complete(client, 0, 0);
  umockdev_ioctl_data_unref(ptr);
  release(u);
}

bool Mf2Emulator::produceIn(Urb& u, int64_t now_ns) {
  auto* urb = reinterpret_cast<usbdevfs_urb*>(u.data->data);
  if (halted_in_) {
    u.status = -EPIPE;
    u.actual = 0;
    return true;
  }
  if (now_ns < silent_until_ns_) return false;
  if (opt_.pace_ns > 0) {
    if (now_ns < next_due_ns_) return false;
    next_due_ns_ = std::max(next_due_ns_ + opt_.pace_ns, now_ns - 10 * opt_.pace_ns);
  }
  if (overflow_left_ > 0) {
    --overflow_left_;
    fw_.tick();  // the device moved on; this packet is lost to the host
    u.status = -EOVERFLOW;
    u.actual = urb->buffer_length;
    return true;
  }
  std::array<uint8_t, proto::kStateSize> pkt{};
  proto::encodeState(fw_.tick(), pkt);
  std::array<uint8_t, proto::kStateSize> out = pkt;
  std::size_t len = out.size();
  if (corrupt_left_ > 0) {
    --corrupt_left_;
    ++counters_.corrupted_sent;
    switch (corruption_) {
      case Corruption::kBitFlip:
        out[40] ^= 0x10;
        break;
      case Corruption::kShort:
        len = 60;
        break;
      case Corruption::kBadMagic:
        out[0] = 'X';
        break;
      case Corruption::kBadVersion: {
        proto::StatePacket s;
        proto::decodeState(pkt, s);
        proto::encodeState(s, out, 2);
        break;
      }
      case Corruption::kDuplicate:  // the last packet the host got, again
        if (prev_count_ >= 1) out = prev_;
        break;
      case Corruption::kOutOfOrder:  // the one before it
        if (prev_count_ >= 2) out = prev2_;
        break;
    }
  } else {
    ++counters_.states_sent;
    prev2_ = prev_;
    prev_ = pkt;
    ++prev_count_;
  }
  len = std::min<std::size_t>(len, static_cast<std::size_t>(urb->buffer_length));
  std::memcpy(urb->buffer, out.data(), len);
  u.status = 0;
  u.actual = static_cast<int>(len);
  return true;
}

bool Mf2Emulator::answerControl(Urb& u) {
  auto* urb = reinterpret_cast<usbdevfs_urb*>(u.data->data);
  auto* buf = static_cast<uint8_t*>(urb->buffer);
  if (urb->buffer_length < 8) return false;
  const uint8_t request_type = buf[0], request = buf[1];
  const uint16_t value = static_cast<uint16_t>(buf[2] | (buf[3] << 8));
  const uint16_t length = static_cast<uint16_t>(buf[6] | (buf[7] << 8));
  std::vector<uint8_t> reply;
  if (request_type == 0x80 && request == 0x06 && (value >> 8) == 0x03) {  // GET_DESCRIPTOR string
    switch (value & 0xff) {
      case 0:
        reply = {0x04, 0x03, 0x09, 0x04};
        break;  // English (US)
      case 1:
        reply = stringDescriptor("telehand");
        break;
      case 2:
        reply = stringDescriptor("MF-2 controller (emulated)");
        break;
      case 3:
        reply = stringDescriptor(opt_.serial);
        break;
      default:
        break;
    }
  }
  if (reply.empty()) {
    u.status = -EPIPE;  // a device stalls requests it does not support
    u.actual = 0;
    return true;
  }
  const std::size_t n = std::min<std::size_t>(
      {reply.size(), length, static_cast<std::size_t>(urb->buffer_length - 8)});
  std::memcpy(buf + 8, reply.data(), n);
  u.status = 0;
  u.actual = static_cast<int>(n);
  return true;
}

bool Mf2Emulator::handleIoctl(UMockdevIoctlClient* client) {
  const unsigned long request = umockdev_ioctl_client_get_request(client);
  UMockdevIoctlData* arg = umockdev_ioctl_client_get_arg(client);
  std::lock_guard lock(mu_);

  switch (request) {
    case USBDEVFS_GET_CAPABILITIES: {
      UMockdevIoctlData* d = umockdev_ioctl_data_resolve(arg, 0, sizeof(uint32_t), nullptr);
      const uint32_t caps = USBDEVFS_CAP_BULK_CONTINUATION | USBDEVFS_CAP_NO_PACKET_SIZE_LIM;
      std::memcpy(d->data, &caps, sizeof caps);
      umockdev_ioctl_client_complete(client, 0, 0);
      umockdev_ioctl_data_unref(d);
      return true;
    }
    case USBDEVFS_CLAIMINTERFACE:
    case USBDEVFS_RELEASEINTERFACE:
    case USBDEVFS_SETINTERFACE:
    case USBDEVFS_RESET:
    case USBDEVFS_RESETEP:
      if (plugged_) {
        umockdev_ioctl_client_complete(client, 0, 0);
      } else {
        umockdev_ioctl_client_complete(client, -1, ENODEV);
      }
      return true;
    case USBDEVFS_CLEAR_HALT: {
      if (!plugged_) {
        umockdev_ioctl_client_complete(client, -1, ENODEV);
        return true;
      }
      UMockdevIoctlData* d = umockdev_ioctl_data_resolve(arg, 0, sizeof(unsigned int), nullptr);
      unsigned int ep = 0;
      std::memcpy(&ep, d->data, sizeof ep);
      umockdev_ioctl_data_unref(d);
      if (ep == proto::kEndpointIn && halted_in_) {
        halted_in_ = false;
        ++counters_.stalls_cleared;
      } else if (ep == proto::kEndpointOut && halted_out_) {
        halted_out_ = false;
        ++counters_.stalls_cleared;
      }
      umockdev_ioctl_client_complete(client, 0, 0);
      return true;
    }
    case USBDEVFS_SUBMITURB: {
      if (!plugged_) {
        umockdev_ioctl_client_complete(client, -1, ENODEV);
        return true;
      }
      Urb u;
      u.data = umockdev_ioctl_data_resolve(arg, 0, sizeof(usbdevfs_urb), nullptr);
      auto* urb = reinterpret_cast<usbdevfs_urb*>(u.data->data);
      UMockdevIoctlData* buffer =
          umockdev_ioctl_data_resolve(u.data, offsetof(usbdevfs_urb, buffer),
                                      static_cast<std::size_t>(urb->buffer_length), nullptr);
      if (buffer) umockdev_ioctl_data_unref(buffer);  // the URB keeps it as its child
      u.client = static_cast<UMockdevIoctlClient*>(g_object_ref(client));
      u.addr = u.data->client_addr;
      u.endpoint = urb->endpoint;
      if (urb->type == USBDEVFS_URB_TYPE_CONTROL && urb->endpoint == 0) {
        answerControl(u);
        done_.push_back(u);
      } else if (urb->endpoint == proto::kEndpointIn) {
        pending_in_.push_back(u);
      } else if (urb->endpoint == proto::kEndpointOut) {
        ++counters_.commands_received;
        if (halted_out_) {
          u.status = -EPIPE;
          u.actual = 0;
        } else {
          fw_.receive({static_cast<const uint8_t*>(urb->buffer),
                       static_cast<std::size_t>(urb->buffer_length)});
          u.status = 0;
          u.actual = urb->buffer_length;
        }
        done_.push_back(u);
      } else {
        release(u);
        umockdev_ioctl_client_complete(client, -1, ENOENT);  // no such endpoint
        return true;
      }
      umockdev_ioctl_client_complete(client, 0, 0);
      return true;
    }
    case USBDEVFS_REAPURB:
    case USBDEVFS_REAPURBNDELAY: {
      for (auto it = done_.begin(); it != done_.end(); ++it) {
        if (it->client != client) continue;
        Urb u = *it;
        done_.erase(it);
        complete(u, arg, client);
        return true;
      }
      if (plugged_) {
        const int64_t now = monotonicNs();
        for (auto it = pending_in_.begin(); it != pending_in_.end(); ++it) {
          if (it->client != client) continue;
          if (!produceIn(*it, now)) break;  // the device has nothing to send yet
          Urb u = *it;
          pending_in_.erase(it);
          complete(u, arg, client);
          return true;
        }
      }
      umockdev_ioctl_client_complete(client, -1, plugged_ ? EAGAIN : ENODEV);
      return true;
    }
    case USBDEVFS_DISCARDURB: {
      unsigned long addr = 0;
      std::memcpy(&addr, arg->data, sizeof addr);
      for (auto it = pending_in_.begin(); it != pending_in_.end(); ++it) {
        if (it->client != client || it->addr != addr) continue;
        Urb u = *it;
        pending_in_.erase(it);
        u.status = -ENOENT;
        u.actual = 0;
        done_.push_back(u);
        ++counters_.discarded;
        umockdev_ioctl_client_complete(client, 0, 0);
        return true;
      }
      // Already completed (or unknown): the kernel answers EINVAL and the URB is reaped.
      umockdev_ioctl_client_complete(client, -1, EINVAL);
      return true;
    }
    default:
      ++counters_.unhandled_ioctls;
      return false;
  }
}

}  // namespace telehand::test::usb
