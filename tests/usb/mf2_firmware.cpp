#include "mf2_firmware.h"

#include <algorithm>
#include <cmath>

namespace telehand::test::usb {

namespace {
constexpr double kDt = 1e-3;
}

Mf2Firmware::Mf2Firmware(const FirmwareParams& p) : p_(p) { reset(); }

void Mf2Firmware::reset() {
  tick_ = 0;
  for (int i = 0; i < proto::kActuators; ++i) {
    x0_[i] = x_[i] = p_.start_counts[i] / p_.counts_per_m;
    v_[i] = applied_a_[i] = 0.0;
  }
  last_ = {};
  have_command_ = false;
  last_command_tick_ = 0;
  enabled_ = estop_latched_ = overcurrent_ = last_rejected_ = false;
  watchdog_expired_ = true;
  rx_errors_ = 0;
}

bool Mf2Firmware::receive(std::span<const uint8_t> bytes) {
  proto::CommandPacket c;
  if (proto::decodeCommand(bytes, c) != proto::DecodeError::kOk) {
    ++rx_errors_;
    last_rejected_ = true;
    return false;
  }
  if (c.flags & proto::kCommandEstop) estop_latched_ = true;
  if ((c.flags & proto::kCommandClearFault) && !(c.flags & proto::kCommandEstop) && !estop_button_) {
    estop_latched_ = false;
  }
  last_ = c;
  have_command_ = true;
  last_command_tick_ = tick_;
  last_rejected_ = false;
  if (keep_history_) commands_.push_back(c);
  return true;
}

proto::StatePacket Mf2Firmware::tick() {
  if (estop_button_) estop_latched_ = true;
  watchdog_expired_ = !have_command_ || tick_ - last_command_tick_ >= last_.watchdog_ms;
  enabled_ = have_command_ && (last_.flags & proto::kCommandEnable) && !estop_latched_ &&
             !watchdog_expired_;
  overcurrent_ = false;
  for (int i = 0; i < proto::kActuators; ++i) {
    double a = enabled_ ? last_.current_ma[i] / 1000.0 : 0.0;
    if (std::abs(a) > p_.max_current_a) {
      a = std::clamp(a, -p_.max_current_a, p_.max_current_a);
      overcurrent_ = true;
    }
    applied_a_[i] = a;
  }
  const double t_s = static_cast<double>(tick_) * kDt;
  for (int i = 0; i < 6; ++i) {  // the base joint (6) is held by its brake in this model
    double f = p_.n_per_amp * applied_a_[i] + external_n_[i] - p_.damping_n_s_per_m * v_[i];
    if (i == p_.operator_axis) f += p_.operator_amplitude_n * std::sin(2.0 * M_PI * p_.operator_hz * t_s);
    v_[i] += f / p_.mass_kg * kDt;
    x_[i] += v_[i] * kDt;
    const double lo = x0_[i] - p_.travel_m, hi = x0_[i] + p_.travel_m;
    if (x_[i] < lo || x_[i] > hi) {
      x_[i] = std::clamp(x_[i], lo, hi);
      v_[i] = 0.0;
    }
  }

  proto::StatePacket s;
  s.seq = static_cast<uint32_t>(tick_);
  s.device_time_us = tick_ * 1000u;
  for (int i = 0; i < proto::kActuators; ++i) {
    s.actuator_counts[i] = static_cast<int32_t>(std::lround(x_[i] * p_.counts_per_m));
  }
  s.gimbal_counts = p_.gimbal_counts;
  for (int i = 0; i < proto::kFsrs; ++i) {
    const long c = std::lround(fsr_n_[i] * p_.fsr_counts_per_n);
    s.fsr_raw[i] = static_cast<uint16_t>(std::clamp<long>(c, 0, proto::kFsrMaxRaw));
  }
  s.status = static_cast<uint16_t>((enabled_ ? proto::kStatusEnabled : 0) |
                                   (estop_button_ ? proto::kStatusEstopButton : 0) |
                                   (estop_latched_ ? proto::kStatusEstopLatched : 0) |
                                   (watchdog_expired_ ? proto::kStatusWatchdogExpired : 0) |
                                   (overcurrent_ ? proto::kStatusOvercurrent : 0) |
                                   (last_rejected_ ? proto::kStatusCommandRejected : 0));
  s.rx_errors = static_cast<uint16_t>(std::min<uint32_t>(rx_errors_, 0xffff));
  s.last_command_seq = last_.seq;
  if (keep_history_) states_.push_back(s);
  ++tick_;
  return s;
}

}  // namespace telehand::test::usb
