#include "client/device/simulated_mf2.h"

#include <algorithm>

namespace telehand::client::device {

namespace {
constexpr int64_t kStepNs = 1'000'000;  // the device's internal 1 kHz
constexpr int kMaxCatchUpSteps = 200;   // a stalled caller skips ahead instead of spinning
}  // namespace

SimulatedMf2::SimulatedMf2(const JointModelParams& geometry, const OperatorConfig& op,
                           const Clock& clock, const SimulatedMf2Dynamics& dyn)
    : geometry_(geometry),
      op_(op),
      clock_(clock),
      dyn_(dyn),
      rng_(op.seed),
      start_ns_(clock.nowNs()),
      sim_ns_(start_ns_) {}

double SimulatedMf2::targetForceN(double t_s) const noexcept {
  const double ramp = op_.ramp_s > 0.0 ? std::clamp(t_s / op_.ramp_s, 0.0, 1.0) : 1.0;
  const double smooth = ramp * ramp * (3.0 - 2.0 * ramp);
  const double mid = 0.5 * (op_.band_min_n + op_.band_max_n);
  const double amp = 0.5 * (op_.band_max_n - op_.band_min_n);
  return smooth * (mid + amp * std::sin(2.0 * kPi * op_.frequency_hz * t_s));
}

void SimulatedMf2::integrate(double dt) noexcept {
  const JointModelParams& g = geometry_.params();
  const double lever = g.lever_arm_m;
  const double inertia = dyn_.mass_kg * lever * lever;
  const double b = dyn_.operator_damping * lever * lever;
  const double k = dyn_.operator_stiffness * lever * lever;
  const double t_s = static_cast<double>(sim_ns_ - start_ns_) * 1e-9;

  Vec3 tau_op;
  tau_op[kFlexion] = targetForceN(t_s) * g.force_scale * lever;
  tau_op[kAbduction] = -k * angles_[kAbduction];
  tau_op[kAxial] = -k * angles_[kAxial];

  const PerFinger<Vec3> p = geometry_.gripFromAngles(angles_, dyn_.half_width_m);
  // What the operator's fingers press on the thimbles (FSRs see this, not the damping).
  operator_force_ = geometry_.fingertipForces(p, angles_, tau_op);
  const Vec3 tau_render = geometry_.axisTorque(p, angles_, command_.force_n);

  const Vec3 acc = (tau_op + tau_render - b * rates_) / inertia;
  rates_ += acc * dt;  // semi-implicit Euler
  angles_ += rates_ * dt;
}

void SimulatedMf2::advanceTo(int64_t t_ns) noexcept {
  int steps = 0;
  while (sim_ns_ + kStepNs <= t_ns) {
    if (++steps > kMaxCatchUpSteps) {
      sim_ns_ = t_ns - (t_ns - sim_ns_) % kStepNs;
      break;
    }
    integrate(1e-3);
    sim_ns_ += kStepNs;
    ++seq_;
  }
}

FsrReadings SimulatedMf2::fsrFor(int finger, const Vec3& force_device) noexcept {
  const Quat q = geometry_.thimbleOrientation(finger, angles_);
  const Vec3 local = q.conjugate() * force_device;
  const double normal = std::max(local.z(), 0.0);  // FSRs only sense pressure
  const double pad = degToRad(dyn_.pad_angle_deg);
  const std::array<double, 4> truth = {normal * std::sin(pad), std::max(local.y(), 0.0),
                                       std::max(-local.y(), 0.0), normal * std::cos(pad)};
  FsrReadings out{};
  for (std::size_t i = 0; i < 4; ++i) {
    const double v = truth[i] + op_.sensor_noise_n * noise_(rng_);
    out[i] = static_cast<float>(std::max(v, 0.0));
  }
  return out;
}

bool SimulatedMf2::read(DeviceSample& out) noexcept {
  advanceTo(clock_.nowNs());
  out.seq = seq_;
  out.time_ns = sim_ns_;
  const PerFinger<Vec3> p = geometry_.gripFromAngles(angles_, dyn_.half_width_m);
  // The net push goes through whichever finger's pad faces it; the axial couple is shared.
  const Vec3 net = operator_force_[kThumb] + operator_force_[kIndex];
  const Vec3 couple = operator_force_[kIndex] - 0.5 * net;
  const Vec3 thumb_normal = geometry_.thimbleOrientation(kThumb, angles_) * Vec3::UnitZ();
  const bool thumb_pushes = net.dot(thumb_normal) >= 0.0;
  const PerFinger<Vec3> pressed = thumb_pushes ? PerFinger<Vec3>{net - couple, couple}
                                               : PerFinger<Vec3>{-couple, net + couple};
  for (int k = 0; k < 2; ++k) {
    out.fingers[k].position_m = p[k];
    out.fingers[k].orientation = geometry_.thimbleOrientation(k, angles_);
    out.fingers[k].fsr_n = fsrFor(k, pressed[k]);
  }
  return true;
}

bool SimulatedMf2::write(const ForceCommand& cmd) noexcept {
  command_ = cmd;
  return true;
}

}  // namespace telehand::client::device
