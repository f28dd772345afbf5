#pragma once
// The MF-2 controller board's firmware, as the emulated device runs it: a 1 kHz tick that
// integrates the commanded motor currents through a simple dynamic model (each actuated
// axis a mass with viscous friction and end stops, pushed by its motor and by the operator),
// produces the state packet, and honours the enable bit, the command watchdog and the
// emergency stop. Not thread-safe: the emulator serializes access.
#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "client/device/mf2_protocol.h"

namespace telehand::test::usb {

namespace proto = client::device::proto;

struct FirmwareParams {
  double counts_per_m = 100'000.0;   ///< matches LinearMf2CalibrationParams
  double n_per_amp = 2.0;            ///< motor force constant at the thimble
  double max_current_a = 3.0;        ///< the motor driver clamps here and flags overcurrent
  double mass_kg = 0.05;             ///< moving mass per axis
  double damping_n_s_per_m = 3.0;    ///< viscous friction per axis
  double travel_m = 0.05;            ///< end stops at +-travel from the start position
  double fsr_counts_per_n = 4095.0 / 20.0;
  std::array<int32_t, proto::kActuators> start_counts{};
  std::array<int32_t, proto::kGimbals> gimbal_counts{};
  // A hand on the thimbles: a sinusoidal push on one axis (amplitude 0: none).
  int operator_axis = 0;
  double operator_amplitude_n = 0.0;
  double operator_hz = 1.0;
};

class Mf2Firmware {
 public:
  explicit Mf2Firmware(const FirmwareParams& p = {});

  /// Power-up: counters from zero, actuators disabled, watchdog expired, e-stop clear.
  void reset();
  /// One 1 kHz tick; returns this tick's state packet.
  proto::StatePacket tick();
  /// A command packet arrived; false (and rx_errors + 1) if it failed its checks.
  bool receive(std::span<const uint8_t> bytes);

  // The operator and the hardware.
  void setFsrForces(const std::array<double, proto::kFsrs>& n) { fsr_n_ = n; }
  void setExternalForce(int actuator, double n) { external_n_[actuator] = n; }
  void pressEstopButton(bool pressed) { estop_button_ = pressed; }

  // What happened (tests check content against these).
  const std::vector<proto::CommandPacket>& commands() const { return commands_; }
  const std::vector<proto::StatePacket>& states() const { return states_; }
  void keepHistory(bool on) { keep_history_ = on; }
  const std::array<double, proto::kActuators>& appliedCurrentA() const { return applied_a_; }
  double positionM(int actuator) const { return x_[actuator]; }
  bool enabled() const { return enabled_; }
  bool estopLatched() const { return estop_latched_; }
  bool watchdogExpired() const { return watchdog_expired_; }
  uint32_t rxErrors() const { return rx_errors_; }
  uint64_t ticks() const { return tick_; }
  const FirmwareParams& params() const { return p_; }

 private:
  FirmwareParams p_;
  uint64_t tick_ = 0;
  std::array<double, proto::kActuators> x_{}, v_{}, x0_{}, applied_a_{}, external_n_{};
  std::array<double, proto::kFsrs> fsr_n_{};
  proto::CommandPacket last_{};
  bool have_command_ = false;
  uint64_t last_command_tick_ = 0;
  bool enabled_ = false, estop_latched_ = false, estop_button_ = false;
  bool watchdog_expired_ = true, overcurrent_ = false, last_rejected_ = false;
  uint32_t rx_errors_ = 0;
  bool keep_history_ = true;
  std::vector<proto::CommandPacket> commands_;
  std::vector<proto::StatePacket> states_;
};

}  // namespace telehand::test::usb
