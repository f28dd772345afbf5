#pragma once
/// The seam between the MF-2's raw readings (encoder and ADC counts) and the loop's units
/// (thimble poses, FSR forces in newtons), and back from thimble forces to motor currents.
/// The MF-2's kinematics and its FSR calibration belong to the device model in common/;
/// this interface is how the USB driver uses them. Implementations are called on the USB
/// event thread for every packet: noexcept, allocation-free.
#include <array>
#include <cstdint>

#include "client/device/device.h"
#include "client/device/mf2_protocol.h"

namespace telehand::client::device {

using CurrentsMa = std::array<int16_t, proto::kActuators>;

class Mf2Calibration {
 public:
  virtual ~Mf2Calibration() = default;
  /// Thimble positions, orientations and FSR forces from one state packet.
  virtual void toFingers(const proto::StatePacket& raw, PerFinger<FingerSample>& out) const noexcept = 0;
  /// Motor currents that produce `force_n` at the thimbles in the pose of `raw`.
  virtual void toCurrents(const PerFinger<Vec3>& force_n, const proto::StatePacket& raw,
                          CurrentsMa& out) const noexcept = 0;
};

/// Bench calibration: each finger's three actuated encoders read its thimble position along
/// the device axes x, y, z (counts_per_m from origin_m), its gimbal encoders the Z-Y-X angles
/// of the thimble, FSRs are linear in ADC counts, and each actuator pushes its axis with
/// n_per_amp. It is exact for the emulated MF-2 of the tests (a Cartesian stand-in), not
/// for the MF-2's 5-bar linkage: the real device needs the device model's forward
/// kinematics and Jacobian behind this same interface.
struct LinearMf2CalibrationParams {
  double counts_per_m = 100'000.0;                 ///< 10 um per count
  double counts_per_rad = 16384.0 / (2.0 * kPi);   ///< 14-bit gimbal encoders
  PerFinger<Vec3> origin_m{Vec3::Zero(), Vec3::Zero()};
  double fsr_n_per_count = 20.0 / 4095.0;          ///< 0-20 N over the 12-bit ADC
  std::array<uint16_t, proto::kFsrs> fsr_zero_counts{};  ///< ADC counts at no load
  double n_per_amp = 2.0;                          ///< thimble force per motor amp
  double max_current_a = 3.0;                      ///< the motor driver's limit
};

class LinearMf2Calibration final : public Mf2Calibration {
 public:
  explicit LinearMf2Calibration(const LinearMf2CalibrationParams& p = {}) : p_(p) {}
  void toFingers(const proto::StatePacket& raw, PerFinger<FingerSample>& out) const noexcept override;
  void toCurrents(const PerFinger<Vec3>& force_n, const proto::StatePacket& raw,
                  CurrentsMa& out) const noexcept override;
  const LinearMf2CalibrationParams& params() const noexcept { return p_; }

 private:
  LinearMf2CalibrationParams p_;
};

}  // namespace telehand::client::device
