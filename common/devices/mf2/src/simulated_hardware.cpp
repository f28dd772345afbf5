#include "telehand/devices/simulated_hardware.h"

#include <algorithm>
#include <cmath>

namespace telehand::devices {

TremorFilter::TremorFilter(double step_s) noexcept {
  // Band-pass: two identical constant 0 dB peak gain biquads in cascade (the skirts of one
  // alone let through far more than the band), centred on the band's geometric mean, each
  // sqrt(sqrt(2) - 1) times narrower than its 3 dB width so that the pair's 3 dB band is
  // 8-12 Hz; the gain makes the response to unit white noise unit RMS (the sum of the
  // squared impulse response).
  const double f0 = std::sqrt(kLowHz * kHighHz);
  const double q = f0 * std::sqrt(std::sqrt(2.0) - 1.0) / (kHighHz - kLowHz);
  const double w0 = 2.0 * kPi * f0 * step_s;
  const double alpha = std::sin(w0) / (2.0 * q);
  const double a0 = 1.0 + alpha;
  b0_ = alpha / a0;
  b2_ = -alpha / a0;
  a1_ = -2.0 * std::cos(w0) / a0;
  a2_ = (1.0 - alpha) / a0;
  double energy = 0;
  for (int i = 0; i < 20000; ++i) {
    const double y = raw(i == 0 ? 1.0 : 0.0);
    energy += y * y;
  }
  state_ = {};
  gain_ = energy > 0.0 ? 1.0 / std::sqrt(energy) : 0.0;
}

double TremorFilter::raw(double x) noexcept {
  for (auto& st : state_) {
    const double y = b0_ * x + b2_ * st[1] - a1_ * st[2] - a2_ * st[3];
    st[1] = st[0];
    st[0] = x;
    st[3] = st[2];
    st[2] = y;
    x = y;
  }
  return x;
}

SimulatedMf2Hardware::SimulatedMf2Hardware(const mf2::Mf2Description& device, double pad_angle_deg)
    : kin_(device),
      fsr_{mf2::FsrMonitor(device.thimbles[kThumb]), mf2::FsrMonitor(device.thimbles[kIndex])},
      pad_sin_(std::sin(degToRad(pad_angle_deg))),
      pad_cos_(std::cos(degToRad(pad_angle_deg))) {}

bool SimulatedMf2Hardware::measurePoses(const PerFinger<mf2::ThimblePose>& truth,
                                        PerFinger<mf2::ThimblePose>& measured) noexcept {
  // Poses -> joint angles -> encoder counts, and back through the forward kinematics as a
  // driver would.
  mf2::JointAngles q;
  if (!kin_.inverse(truth, 0.0, q)) return false;
  const mf2::JointAngles read = kin_.anglesFromCounts(kin_.countsFromAngles(q));
  if (!kin_.forward(read, measured)) return false;
  q_act_ = read.actuators;
  have_q_ = true;
  return true;
}

void SimulatedMf2Hardware::readFsr(int finger, const Quat& thimble, const Vec3& pressed_device,
                                   double sigma_n, GaussianNoise& noise,
                                   FingerSample& out) noexcept {
  const Vec3 local = thimble.conjugate() * pressed_device;
  const double normal = std::max(local.z(), 0.0);  // FSRs only sense pressure
  const std::array<double, 4> truth = {normal * pad_sin_, std::max(local.y(), 0.0),
                                       std::max(-local.y(), 0.0), normal * pad_cos_};
  // Raw 12-bit ADC counts through the thimble's calibration (noise in newtons first).
  std::array<uint16_t, mf2::kFsrPerThimble> counts{};
  const auto& cal = fsr_[finger].calibration();
  for (std::size_t i = 0; i < 4; ++i) {
    const double v = truth[i] + sigma_n * noise();
    const double c = std::clamp(std::round(cal.fsr[i].countsFor(std::max(v, 0.0))), 0.0, 4095.0);
    counts[i] = static_cast<uint16_t>(c);
  }
  const mf2::ThimbleReading r = fsr_[finger].update(counts);
  out.fsr_n = r.fsr_n;
  out.fsr_fault_mask = r.faultMask();
}

bool SimulatedMf2Hardware::render(const PerFinger<Vec3>& force_n) noexcept {
  mf2::ActuatorTorques tau;
  if (!have_q_ || !kin_.actuatorTorques(q_act_, force_n, tau)) {
    off();
    return false;
  }
  const auto& limit = kin_.description().max_torque_nm;
  double scale = 1.0;
  for (int i = 0; i < mf2::kActuators; ++i) {
    if (std::abs(tau[i]) > limit[i]) scale = std::min(scale, limit[i] / std::abs(tau[i]));
  }
  tau_act_ = tau * scale;
  PerFinger<Vec3> f;
  if (!kin_.fingertipForces(q_act_, tau_act_, f)) {
    rendered_ = {Vec3::Zero(), Vec3::Zero()};
    return false;
  }
  rendered_ = f;
  return true;
}

void SimulatedMf2Hardware::off() noexcept {
  rendered_ = {Vec3::Zero(), Vec3::Zero()};
  tau_act_.setZero();
}

}  // namespace telehand::devices
