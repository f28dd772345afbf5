#pragma once
/// The seam between the MF-2's raw readings (encoder and ADC counts of a state packet) and
/// the loop's units (thimble poses, FSR forces in newtons), and back from thimble forces to
/// motor currents. Mf2ModelCalibration does it with the MF-2 device model of common/
/// (forward kinematics, Jacobian transpose, the thimbles' FSR calibration) and a device file
/// (deploy/devices/mf2.toml). Called on the USB thread for every packet: noexcept,
/// allocation-free.
#include <array>
#include <cstdint>

#include "telehand/devices/device.h"
#include "telehand/devices/mf2_device.h"
#include "telehand/devices/mf2_protocol.h"

namespace telehand::devices {

using CurrentsMa = std::array<int16_t, proto::kActuators>;

class Mf2Calibration {
 public:
  virtual ~Mf2Calibration() = default;
  /// Thimble poses and FSR forces from one state packet; false when the counts describe no
  /// pose of the linkage (past a stop, or a five-bar that cannot close): the packet is then
  /// not to be trusted. Keeps per-stream state
  /// (stuck FSR channels): one caller thread.
  virtual bool toFingers(const proto::StatePacket& raw, PerFinger<FingerSample>& out) noexcept = 0;
  /// Motor currents that produce `force_n` at the thimbles in the pose of `raw`.
  virtual void toCurrents(const PerFinger<Vec3>& force_n, const proto::StatePacket& raw,
                          CurrentsMa& out) const noexcept = 0;
  /// The lightest mass the device moves at the thimbles in the pose of `raw`, along any
  /// direction, kg; 0 when the calibration does not know it.
  virtual double lightestMassKg(const proto::StatePacket& raw) const noexcept {
    (void)raw;
    return 0.0;
  }
  /// Forget per-stream state (a new connection).
  virtual void reset() noexcept {}
};

/// The motors behind the actuators. Not in the device file yet; the defaults are stated
/// assumptions: a 23.4 mN·m/A DC motor through the device file's 10:1 capstan is 0.234 N·m/A
/// at the joint, a 6 A driver limit covers the device file's largest torque (1.2 N·m), and
/// each actuator moves 5·10⁻⁴ kg·m² at its joint (motor, capstan and link: about 50 g at a
/// 10 cm crank).
struct Mf2Motors {
  std::array<double, proto::kActuators> nm_per_amp{0.234, 0.234, 0.234, 0.234, 0.234, 0.234, 0.234};
  double max_current_a = 6.0;
  double inertia_kgm2 = 5e-4;  ///< per actuator, joint side
};

/// Wire order = the device model's order: actuator 0 is the base joint, 1-3 the thumb's
/// (yaw, crank 1, crank 2), 4-6 the index's; gimbals 0-2 thumb, 3-5 index; FSRs 0-3 thumb
/// sensors 1-4, 4-7 index sensors 1-4.
class Mf2ModelCalibration final : public Mf2Calibration {
 public:
  explicit Mf2ModelCalibration(const mf2::Mf2Description& device, const Mf2Motors& motors = {});
  bool toFingers(const proto::StatePacket& raw, PerFinger<FingerSample>& out) noexcept override;
  void toCurrents(const PerFinger<Vec3>& force_n, const proto::StatePacket& raw,
                  CurrentsMa& out) const noexcept override;
  /// From the actuators' inertia I and the Jacobian J: 1 / λmax(J·Jᵀ / I) (the thimbles'
  /// mobility's largest eigenvalue). Allocation-free.
  double lightestMassKg(const proto::StatePacket& raw) const noexcept override;
  void reset() noexcept override;

  /// How far past a mechanical stop an angle may read (encoder zero calibration) before the
  /// packet is taken as corrupt.
  static constexpr double kStopSlackRad = 5.0 * kPi / 180.0;

  const mf2::Mf2Kinematics& kinematics() const noexcept { return kin_; }
  const Mf2Motors& motors() const noexcept { return motors_; }
  static mf2::EncoderCounts encoderCounts(const proto::StatePacket& raw) noexcept;

 private:
  mf2::Mf2Kinematics kin_;
  Mf2Motors motors_;
  PerFinger<mf2::FsrMonitor> fsr_;
};

}  // namespace telehand::devices
