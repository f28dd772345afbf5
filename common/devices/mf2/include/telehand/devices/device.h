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

/// What bounds a damping the loop may add at the thimbles (the passivity controller's): a
/// damper b acting on a mass m through a loop of period T and a delay of d ticks is stable
/// only while b·T/m stays under 2·sin(π / (2(2d + 1))) (docs/teleoperation.md).
struct DeviceDynamics {
  /// The lightest mass the device moves at the thimbles, along any direction, kg (0: unknown).
  double lightest_mass_kg = 0.0;
  /// Whole ticks between the loop's write of a force and the device acting on it, beyond the
  /// tick it is held for: 0 when the next tick already feels it, 1 when it leaves with the
  /// next USB packet.
  int command_delay_ticks = 0;
};

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
  /// The device's moving mass and delay as far as it knows them (real-time safe).
  virtual DeviceDynamics dynamics() const noexcept { return {}; }
};

}  // namespace telehand::devices
