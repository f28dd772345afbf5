#pragma once
/// The device seam: the haptic loop talks to any MF-2 (simulated, USB) through this.
#include <array>
#include <cstdint>
#include <string_view>

#include "telehand/core/math.h"
#include "telehand/core/thimble.h"

namespace telehand::devices {

struct FingerSample {
  Vec3 position_m = Vec3::Zero();  ///< thimble centre, device frame
  Quat orientation = Quat::Identity();
  FsrReadings fsr_n{};
  /// Bit i: FSR i+1 is flagged saturated or dead (mf2::FsrMonitor); its reading is not to
  /// be trusted.
  uint8_t fsr_fault_mask = 0;
};

struct DeviceSample {
  uint64_t seq = 0;     ///< the device's own sample counter
  int64_t time_ns = 0;  ///< when it was taken, on the loop's clock
  PerFinger<FingerSample> fingers{};
};

struct ForceCommand {
  PerFinger<Vec3> force_n{Vec3::Zero(), Vec3::Zero()};
};

enum class DeviceStatus { kOk, kNotReady, kDisconnected, kFault };

/// read/write are called from the real-time thread: implementations must not allocate, lock
/// or block.
class Device {
 public:
  virtual ~Device() = default;
  /// Latest sample; false when none is available (the loop's watchdog handles staleness).
  virtual bool read(DeviceSample& out) noexcept = 0;
  /// Apply a force command (already through the safety gate).
  virtual bool write(const ForceCommand& cmd) noexcept = 0;
  virtual DeviceStatus status() const noexcept = 0;
  virtual std::string_view name() const noexcept = 0;
};

}  // namespace telehand::devices
