#pragma once
// The MF-2 controller board's firmware, as the emulated device runs it: a 1 kHz tick that
// integrates the commanded motor currents through a simple dynamic model (each actuator a
// rotating inertia with viscous friction and end stops, driven by its motor and by the
// operator's hand), produces the state packet, and honours the enable bit, the command
// watchdog and the emergency stop. It knows the hardware (encoder scales, motor constants,
// FSR amplifiers), not the kinematics. Not thread-safe: the emulator serializes access.
#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "telehand/devices/mf2_calibration.h"
#include "telehand/devices/mf2_protocol.h"

namespace telehand::test::usb {

namespace proto = devices::proto;

struct FirmwareParams {
  std::array<double, proto::kActuators> counts_per_rad{};
  std::array<double, proto::kActuators> zero_counts{};
  std::array<double, proto::kActuators> min_rad{}, max_rad{};
  std::array<double, proto::kActuators> nm_per_amp{};
  double max_current_a = 6.0;  ///< the motor driver clamps here and flags overcurrent
  double inertia_kgm2 = 5e-4;  ///< per joint (firmwareFor: Mf2Motors::inertia_kgm2)
  double damping_nm_s_per_rad = 5e-3;
  std::array<double, proto::kFsrs> fsr_zero_counts{}, fsr_counts_per_n{};
  std::array<int32_t, proto::kActuators> start_counts{};
  std::array<int32_t, proto::kGimbals> gimbal_counts{};
  // A hand on the thimbles: a sinusoidal torque on one actuator (amplitude 0: none).
  int operator_actuator = 1;
  double operator_amplitude_nm = 0.0;
  double operator_hz = 1.0;
};

/// Firmware parameters for the hardware a device file and motor constants describe, with
/// the thimbles resting on the grip of the default index MCP joint at `flexion_rad`.
FirmwareParams firmwareFor(const mf2::Mf2Description& device, const devices::Mf2Motors& motors = {},
                           double flexion_rad = 20.0 * 3.14159265358979 / 180.0);

class Mf2Firmware {
 public:
  explicit Mf2Firmware(const FirmwareParams& p = firmwareFor(mf2::defaultMf2()));

  /// Power-up: counters from zero, actuators disabled, watchdog expired, e-stop clear.
  void reset();
  /// One 1 kHz tick; returns this tick's state packet.
  proto::StatePacket tick();
  /// A command packet arrived; false (and rx_errors + 1) if it failed its checks.
  bool receive(std::span<const uint8_t> bytes);

  // The operator and the hardware.
  void setFsrForces(const std::array<double, proto::kFsrs>& n) { fsr_n_ = n; }
  void setExternalTorque(int actuator, double nm) { external_nm_[actuator] = nm; }
  /// A hand that holds a position as well as pushing: a spring of `nm_per_rad` toward the
  /// actuator's present angle adds to the external torque, so that a loop that stops
  /// rendering lets the thimbles drift to where the push and the spring balance, not away.
  void holdHere(int actuator, double nm_per_rad) {
    hold_nm_per_rad_[actuator] = nm_per_rad;
    hold_rad_[actuator] = q_[actuator];
  }
  void pressEstopButton(bool pressed) { estop_button_ = pressed; }
  /// An encoder lost count (status bit 6) until cleared.
  void setEncoderFault(bool on) { encoder_fault_ = on; }
  /// An encoder that lost count without saying so: its counts reported `counts` off.
  void setCountOffset(int actuator, int32_t counts) { count_offset_[actuator] = counts; }

  // What happened (tests check content against these).
  const std::vector<proto::CommandPacket>& commands() const { return commands_; }
  /// For each accepted command, how many state packets had been produced when it arrived.
  const std::vector<uint64_t>& commandTicks() const { return command_ticks_; }
  const std::vector<proto::StatePacket>& states() const { return states_; }
  void keepHistory(bool on) { keep_history_ = on; }
  const std::array<double, proto::kActuators>& appliedCurrentA() const { return applied_a_; }
  double angleRad(int actuator) const { return q_[actuator]; }
  bool enabled() const { return enabled_; }
  bool estopLatched() const { return estop_latched_; }
  bool watchdogExpired() const { return watchdog_expired_; }
  uint32_t rxErrors() const { return rx_errors_; }
  uint64_t ticks() const { return tick_; }
  const FirmwareParams& params() const { return p_; }

 private:
  FirmwareParams p_;
  uint64_t tick_ = 0;
  std::array<double, proto::kActuators> q_{}, v_{}, applied_a_{}, external_nm_{};
  std::array<double, proto::kActuators> hold_nm_per_rad_{}, hold_rad_{};
  std::array<double, proto::kFsrs> fsr_n_{};
  proto::CommandPacket last_{};
  bool have_command_ = false;
  uint64_t last_command_tick_ = 0;
  bool enabled_ = false, estop_latched_ = false, estop_button_ = false;
  bool watchdog_expired_ = true, overcurrent_ = false, last_rejected_ = false;
  bool encoder_fault_ = false;
  std::array<int32_t, proto::kActuators> count_offset_{};
  uint32_t rx_errors_ = 0;
  bool keep_history_ = true;
  std::vector<proto::CommandPacket> commands_;
  std::vector<uint64_t> command_ticks_;
  std::vector<proto::StatePacket> states_;
};

}  // namespace telehand::test::usb
