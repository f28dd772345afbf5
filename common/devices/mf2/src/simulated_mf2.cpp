#include "telehand/devices/simulated_mf2.h"

#include <algorithm>
#include <cmath>

namespace telehand::devices {

namespace {
constexpr int64_t kStepNs = 1'000'000;  // the device's internal 1 kHz
constexpr int kMaxCatchUpSteps = 200;   // a stalled caller skips ahead instead of spinning
}  // namespace

SimulatedMf2::SimulatedMf2(const JointModelParams& geometry, const OperatorConfig& op,
                           const Clock& clock, const SimulatedMf2Dynamics& dyn,
                           const mf2::Mf2Description& device)
    : geometry_(geometry),
      hw_(device, dyn.pad_angle_deg),
      op_(op),
      clock_(clock),
      dyn_(dyn),
      noise_(op.seed),
      tremor_noise_(op.seed ^ 0x7265'6d6f'7254'0001ULL),
      tremor_(static_cast<double>(kStepNs) * 1e-9),
      start_ns_(clock.nowNs()),
      sim_ns_(start_ns_) {}

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

void SimulatedMf2::integrate(double dt, double into_s, bool sampled) noexcept {
  const JointModelParams& g = geometry_.params();
  const double lever = g.lever_arm_m;
  const double inertia = dyn_.mass_kg * lever * lever;
  const double b = dyn_.operator_damping * lever * lever;
  const double k = dyn_.operator_stiffness * lever * lever;
  const double t_s = static_cast<double>(sim_ns_ - start_ns_) * 1e-9 + into_s;

  Vec3 tau_op;
  // The operator's tremor runs whoever scripts the push (a script may add tremorN()).
  if (sampled && op_.tremor_n > 0.0) {
    tremor_n_ = smoothRamp(t_s, op_.ramp_s) * op_.tremor_n * tremor_.step(tremor_noise_());
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
  if (sampled && axis_noise_n_ > 0.0) {
    for (int i = 0; i < kAxes; ++i) tau_seen[i] += axis_noise_n_ * lever * noise_();
  }
  // fingertipForces gives the forces the phalanx exerts on the fingers; the fingers press
  // the opposite of those for the opposite torque (so the finger whose pad pushes carries it).
  const PerFinger<Vec3> reaction = geometry_.fingertipForces(p, angles_, -tau_seen);
  operator_force_ = {-reaction[kThumb], -reaction[kIndex]};
  const Vec3 tau_render = geometry_.axisTorque(p, angles_, hw_.rendered());
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
    // What the FSRs see is the force of the last substep: the sample's instant.
    const int n = std::max(1, dyn_.substeps);
    for (int i = 0; i < n; ++i) integrate(1e-3 / n, 1e-3 * i / n, i == n - 1);
    sim_ns_ += kStepNs;
    ++seq_;
  }
}

PerFinger<Quat> SimulatedMf2::thimbleOrientations() const noexcept {
  return {geometry_.thimbleOrientation(kThumb, angles_),
          geometry_.thimbleOrientation(kIndex, angles_)};
}

bool SimulatedMf2::updatePose(const PerFinger<Quat>& thimbles,
                              PerFinger<mf2::ThimblePose>& measured) noexcept {
  // The thimbles where the phalanx holds them, as the encoders read them.
  const PerFinger<Vec3> p = geometry_.gripFromAngles(angles_, dyn_.half_width_m);
  PerFinger<mf2::ThimblePose> truth;
  for (int k = 0; k < 2; ++k) {
    truth[k].position_m = p[k];
    truth[k].orientation = thimbles[k];
  }
  return hw_.measurePoses(truth, measured);
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
    hw_.readFsr(k, thimbles[k], pressed[k], op_.sensor_noise_n, noise_, out.fingers[k]);
  }
  return true;
}

bool SimulatedMf2::write(const ForceCommand& cmd) noexcept {
  if (!hw_.hasPose()) {
    PerFinger<mf2::ThimblePose> pose;
    if (!updatePose(thimbleOrientations(), pose)) return false;
  }
  return hw_.render(cmd.force_n);
}

}  // namespace telehand::devices
