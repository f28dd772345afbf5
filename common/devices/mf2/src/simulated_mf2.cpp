#include "telehand/devices/simulated_mf2.h"

#include <algorithm>
#include <cmath>

namespace telehand::devices {

namespace {
constexpr int64_t kStepNs = 1'000'000;  // the device's internal 1 kHz
constexpr int kMaxCatchUpSteps = 200;   // a stalled caller skips ahead instead of spinning
// Physiological tremor of the hand: 8-12 Hz (docs/facts.md "Tremor and smoothness").
constexpr double kTremorLowHz = 8.0;
constexpr double kTremorHighHz = 12.0;
}  // namespace

SimulatedMf2::SimulatedMf2(const JointModelParams& geometry, const OperatorConfig& op,
                           const Clock& clock, const SimulatedMf2Dynamics& dyn,
                           const mf2::Mf2Description& device)
    : geometry_(geometry),
      kin_(device),
      fsr_{mf2::FsrMonitor(device.thimbles[kThumb]), mf2::FsrMonitor(device.thimbles[kIndex])},
      op_(op),
      clock_(clock),
      dyn_(dyn),
      pad_sin_(std::sin(degToRad(dyn.pad_angle_deg))),
      pad_cos_(std::cos(degToRad(dyn.pad_angle_deg))),
      rng_(op.seed),
      tremor_rng_(op.seed ^ 0x7265'6d6f'7254'0001ULL),
      start_ns_(clock.nowNs()),
      sim_ns_(start_ns_) {
  // Band-pass: two identical constant 0 dB peak gain biquads in cascade (the skirts of one
  // alone let through far more than the band), centred on the band's geometric mean, each
  // sqrt(sqrt(2) - 1) times narrower than its 3 dB width so that the pair's 3 dB band is
  // 8-12 Hz, at the device's 1 kHz step; the gain makes the response to unit white noise
  // unit RMS (the sum of the squared impulse response).
  const double dt = static_cast<double>(kStepNs) * 1e-9;
  const double f0 = std::sqrt(kTremorLowHz * kTremorHighHz);
  const double q = f0 * std::sqrt(std::sqrt(2.0) - 1.0) / (kTremorHighHz - kTremorLowHz);
  const double w0 = 2.0 * kPi * f0 * dt;
  const double alpha = std::sin(w0) / (2.0 * q);
  const double a0 = 1.0 + alpha;
  tb0_ = alpha / a0;
  tb2_ = -alpha / a0;
  ta1_ = -2.0 * std::cos(w0) / a0;
  ta2_ = (1.0 - alpha) / a0;
  double energy = 0;
  for (int i = 0; i < 20000; ++i) {
    const double y = tremorStep(i == 0 ? 1.0 : 0.0);
    energy += y * y;
  }
  tremor_state_ = {};
  tremor_gain_ = energy > 0.0 ? 1.0 / std::sqrt(energy) : 0.0;
}

double SimulatedMf2::tremorStep(double x) noexcept {
  for (auto& st : tremor_state_) {
    const double y = tb0_ * x + tb2_ * st[1] - ta1_ * st[2] - ta2_ * st[3];
    st[1] = st[0];
    st[0] = x;
    st[3] = st[2];
    st[2] = y;
    x = y;
  }
  return x;
}

void SimulatedMf2::setPatient(const JointModelParams& truth) {
  patient_ = JointModel(truth);
  has_patient_ = true;
}

double SimulatedMf2::targetForceN(double t_s) const noexcept {
  const double smooth = smoothRamp(t_s, op_.ramp_s);
  const double mid = 0.5 * (op_.band_min_n + op_.band_max_n) + op_.force_bias_n;
  const double amp = 0.5 * (op_.band_max_n - op_.band_min_n) * op_.amplitude_scale;
  const double freq = op_.frequency_hz + op_.frequency_error_hz;
  return smooth * (mid + amp * std::sin(2.0 * kPi * freq * t_s));
}

void SimulatedMf2::integrate(double dt) noexcept {
  const JointModelParams& g = geometry_.params();
  const double lever = g.lever_arm_m;
  const double inertia = dyn_.mass_kg * lever * lever;
  const double b = dyn_.operator_damping * lever * lever;
  const double k = dyn_.operator_stiffness * lever * lever;
  const double t_s = static_cast<double>(sim_ns_ - start_ns_) * 1e-9;

  Vec3 tau_op;
  // The operator's tremor runs whoever scripts the push (a script may add tremorN()).
  if (op_.tremor_n > 0.0) {
    const double y = tremorStep(tremor_noise_(tremor_rng_));
    tremor_n_ = smoothRamp(t_s, op_.ramp_s) * op_.tremor_n * tremor_gain_ * y;
  }
  if (script_) {
    tau_op = script_->torqueNm(t_s, angles_, rates_);
  } else {
    tau_op[kFlexion] = (targetForceN(t_s) + tremor_n_) * g.force_scale * lever;
    tau_op[kAbduction] = -k * angles_[kAbduction];
    tau_op[kAxial] = -k * angles_[kAxial];
  }

  const PerFinger<Vec3> p = geometry_.gripFromAngles(angles_, dyn_.half_width_m);
  // What the operator's fingers press on the thimbles (FSRs see this, not the damping), as
  // the thimbles measure it.
  Vec3 tau_seen = tau_op;
  if (axis_noise_n_ > 0.0) {
    for (int i = 0; i < kAxes; ++i) tau_seen[i] += axis_noise_n_ * lever * noise_(rng_);
  }
  // fingertipForces gives the forces the phalanx exerts on the fingers; the fingers press
  // the opposite of those for the opposite torque (so the finger whose pad pushes carries it).
  const PerFinger<Vec3> reaction = geometry_.fingertipForces(p, angles_, -tau_seen);
  operator_force_ = {-reaction[kThumb], -reaction[kIndex]};
  const Vec3 tau_render = geometry_.axisTorque(p, angles_, rendered_);
  const Vec3 tau_patient = custom_patient_ ? custom_patient_->passiveTorqueNm(angles_, rates_)
                           : has_patient_  ? patient_.passiveTorqueNm(angles_, rates_)
                                           : Vec3::Zero();

  const Vec3 acc = (tau_op + tau_render + tau_patient - b * rates_) / inertia;
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

void SimulatedMf2::fsrFor(int finger, const Quat& thimble, const Vec3& force_device,
                          FingerSample& out) noexcept {
  const Vec3 local = thimble.conjugate() * force_device;
  const double normal = std::max(local.z(), 0.0);  // FSRs only sense pressure
  const std::array<double, 4> truth = {normal * pad_sin_, std::max(local.y(), 0.0),
                                       std::max(-local.y(), 0.0), normal * pad_cos_};
  // Raw 12-bit ADC counts through the thimble's calibration (noise in newtons first).
  std::array<uint16_t, mf2::kFsrPerThimble> counts{};
  const auto& cal = fsr_[finger].calibration();
  for (std::size_t i = 0; i < 4; ++i) {
    const double v = truth[i] + op_.sensor_noise_n * noise_(rng_);
    const double c = std::clamp(std::round(cal.fsr[i].countsFor(std::max(v, 0.0))), 0.0, 4095.0);
    counts[i] = static_cast<uint16_t>(c);
  }
  const mf2::ThimbleReading r = fsr_[finger].update(counts);
  out.fsr_n = r.fsr_n;
  out.fsr_fault_mask = r.faultMask();
}

PerFinger<Quat> SimulatedMf2::thimbleOrientations() const noexcept {
  return {geometry_.thimbleOrientation(kThumb, angles_),
          geometry_.thimbleOrientation(kIndex, angles_)};
}

bool SimulatedMf2::updatePose(const PerFinger<Quat>& thimbles,
                              PerFinger<mf2::ThimblePose>& measured) noexcept {
  // The thimbles where the phalanx holds them -> joint angles -> encoder counts, and back
  // through the forward kinematics as a driver would.
  const PerFinger<Vec3> p = geometry_.gripFromAngles(angles_, dyn_.half_width_m);
  PerFinger<mf2::ThimblePose> truth;
  for (int k = 0; k < 2; ++k) {
    truth[k].position_m = p[k];
    truth[k].orientation = thimbles[k];
  }
  mf2::JointAngles q;
  if (!kin_.inverse(truth, 0.0, q)) return false;
  const mf2::JointAngles read = kin_.anglesFromCounts(kin_.countsFromAngles(q));
  if (!kin_.forward(read, measured)) return false;
  q_act_ = read.actuators;
  have_q_ = true;
  return true;
}

bool SimulatedMf2::read(DeviceSample& out) noexcept {
  advanceTo(clock_.nowNs());
  const PerFinger<Quat> thimbles = thimbleOrientations();
  PerFinger<mf2::ThimblePose> pose;
  if (!updatePose(thimbles, pose)) return false;  // out of the linkage's reach
  out.seq = seq_;
  out.time_ns = sim_ns_;
  // A pad can only push: where the shared split would pull on a pad, the clinician squeezes
  // (equal and opposite forces along the line between the pads: no net force, no moment).
  // A flexion push then goes through the pad that faces it; side forces stay shared.
  const Vec3 n_thumb = thimbles[kThumb] * Vec3::UnitZ();
  const Vec3 n_index = thimbles[kIndex] * Vec3::UnitZ();
  const double squeeze =
      std::max({0.0, -operator_force_[kThumb].dot(n_thumb), -operator_force_[kIndex].dot(n_index)});
  const PerFinger<Vec3> pressed{operator_force_[kThumb] + squeeze * n_thumb,
                                operator_force_[kIndex] + squeeze * n_index};
  for (int k = 0; k < 2; ++k) {
    out.fingers[k].position_m = pose[k].position_m;
    out.fingers[k].orientation = pose[k].orientation;
    fsrFor(k, thimbles[k], pressed[k], out.fingers[k]);
  }
  return true;
}

bool SimulatedMf2::write(const ForceCommand& cmd) noexcept {
  // Through the actuators: torques J^T F, scaled down together if one exceeds its limit
  // (the direction is kept), and the fingertip forces those torques actually make.
  if (!have_q_) {
    PerFinger<mf2::ThimblePose> pose;
    if (!updatePose(thimbleOrientations(), pose)) return false;
  }
  mf2::ActuatorTorques tau;
  if (!kin_.actuatorTorques(q_act_, cmd.force_n, tau)) {
    rendered_ = {Vec3::Zero(), Vec3::Zero()};
    tau_act_.setZero();
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

}  // namespace telehand::devices
