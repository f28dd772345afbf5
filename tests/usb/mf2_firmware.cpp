#include "mf2_firmware.h"

#include <algorithm>
#include <cmath>

#include "telehand/core/joint_model.h"

namespace telehand::test::usb {

namespace {
constexpr double kDt = 1e-3;
}

FirmwareParams firmwareFor(const mf2::Mf2Description& d, const devices::Mf2Motors& motors,
                           double flexion_rad) {
  FirmwareParams p;
  for (int i = 0; i < proto::kActuators; ++i) {
    const auto& e = d.actuator_encoders[i];
    p.counts_per_rad[i] = e.counts_per_rad;
    p.zero_counts[i] = static_cast<double>(e.zero_counts);
    p.min_rad[i] = e.min_rad;
    p.max_rad[i] = e.max_rad;
    p.nm_per_amp[i] = motors.nm_per_amp[i];
  }
  p.max_current_a = motors.max_current_a;
  p.inertia_kgm2 = motors.inertia_kgm2;
  for (int k = 0; k < 2; ++k) {
    for (int j = 0; j < 4; ++j) {
      p.fsr_zero_counts[4 * k + j] = d.thimbles[k].fsr[j].zero_counts;
      p.fsr_counts_per_n[4 * k + j] = d.thimbles[k].fsr[j].counts_per_n;
    }
  }
  // Where the device model puts the thimbles on the default joint's grip.
  const JointModel joint(healthyIndexMcp());
  const Vec3 angles(flexion_rad, 0.0, 0.0);
  const PerFinger<Vec3> grip = joint.gripFromAngles(angles, 0.008);
  PerFinger<mf2::ThimblePose> target;
  for (int k = 0; k < 2; ++k) {
    target[k].position_m = grip[k];
    target[k].orientation = joint.thimbleOrientation(k, angles);
  }
  const mf2::Mf2Kinematics kin(d);
  mf2::JointAngles q;
  if (kin.inverse(target, 0.0, q)) {
    const mf2::EncoderCounts c = kin.countsFromAngles(q);
    for (int i = 0; i < proto::kActuators; ++i)
      p.start_counts[i] = static_cast<int32_t>(c.actuators[i]);
    for (int k = 0; k < 2; ++k) {
      for (int j = 0; j < 3; ++j) p.gimbal_counts[3 * k + j] = static_cast<int32_t>(c.gimbal[k][j]);
    }
  }
  return p;
}

Mf2Firmware::Mf2Firmware(const FirmwareParams& p) : p_(p) { reset(); }

void Mf2Firmware::reset() {
  tick_ = 0;
  for (int i = 0; i < proto::kActuators; ++i) {
    q_[i] = (p_.start_counts[i] - p_.zero_counts[i]) / p_.counts_per_rad[i];
    v_[i] = applied_a_[i] = 0.0;
  }
  last_ = {};
  have_command_ = false;
  last_command_tick_ = 0;
  enabled_ = estop_latched_ = overcurrent_ = last_rejected_ = encoder_fault_ = false;
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
  if ((c.flags & proto::kCommandClearFault) && !(c.flags & proto::kCommandEstop) &&
      !estop_button_) {
    estop_latched_ = false;
  }
  last_ = c;
  have_command_ = true;
  last_command_tick_ = tick_;
  last_rejected_ = false;
  if (keep_history_) {
    commands_.push_back(c);
    command_ticks_.push_back(tick_);
  }
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
  for (int i = 0; i < proto::kActuators; ++i) {
    double tau = p_.nm_per_amp[i] * applied_a_[i] + external_nm_[i] -
                 p_.damping_nm_s_per_rad * v_[i] + hold_nm_per_rad_[i] * (hold_rad_[i] - q_[i]);
    if (i == p_.operator_actuator) {
      tau += p_.operator_amplitude_nm * std::sin(2.0 * M_PI * p_.operator_hz * t_s);
    }
    v_[i] += tau / p_.inertia_kgm2 * kDt;  // semi-implicit Euler
    q_[i] += v_[i] * kDt;
    if (q_[i] < p_.min_rad[i] || q_[i] > p_.max_rad[i]) {  // end stop
      q_[i] = std::clamp(q_[i], p_.min_rad[i], p_.max_rad[i]);
      v_[i] = 0.0;
    }
  }

  proto::StatePacket s;
  s.seq = static_cast<uint32_t>(tick_);
  s.device_time_us = tick_ * 1000u;
  for (int i = 0; i < proto::kActuators; ++i) {
    s.actuator_counts[i] =
        static_cast<int32_t>(std::lround(p_.zero_counts[i] + q_[i] * p_.counts_per_rad[i])) +
        count_offset_[i];
  }
  s.gimbal_counts = p_.gimbal_counts;
  for (int i = 0; i < proto::kFsrs; ++i) {
    // One count of ADC noise, as a powered FSR channel always shows.
    const double noise =
        static_cast<double>(static_cast<int>((tick_ + static_cast<uint64_t>(i)) % 3) - 1);
    const double c = std::round(p_.fsr_zero_counts[i] + p_.fsr_counts_per_n[i] * fsr_n_[i]) + noise;
    s.fsr_raw[i] =
        static_cast<uint16_t>(std::clamp(c, 0.0, static_cast<double>(proto::kFsrMaxRaw)));
  }
  s.status = static_cast<uint16_t>((enabled_ ? proto::kStatusEnabled : 0) |
                                   (estop_button_ ? proto::kStatusEstopButton : 0) |
                                   (estop_latched_ ? proto::kStatusEstopLatched : 0) |
                                   (watchdog_expired_ ? proto::kStatusWatchdogExpired : 0) |
                                   (overcurrent_ ? proto::kStatusOvercurrent : 0) |
                                   (encoder_fault_ ? proto::kStatusEncoderFault : 0) |
                                   (last_rejected_ ? proto::kStatusCommandRejected : 0));
  s.rx_errors = static_cast<uint16_t>(std::min<uint32_t>(rx_errors_, 0xffff));
  s.last_command_seq = last_.seq;
  if (keep_history_) states_.push_back(s);
  ++tick_;
  return s;
}

}  // namespace telehand::test::usb
