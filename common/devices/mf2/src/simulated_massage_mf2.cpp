#include "telehand/devices/simulated_massage_mf2.h"

#include <algorithm>
#include <cmath>
#include <random>

namespace telehand::devices {

namespace {
constexpr int64_t kStepNs = 1'000'000;  // the device's internal 1 kHz
constexpr int kMaxCatchUpSteps = 200;   // a stalled caller skips ahead instead of spinning
constexpr uint64_t kTremorSeed = 0x7265'6d6f'7254'0002ULL;
constexpr uint64_t kWanderSeed = 0x7265'6477'6e61'0003ULL;
constexpr std::array<double, 2> kWanderRatio = {0.7, 1.3};

/// Which way a finger presses into the web, in the web frame: the thumb from the dorsal side
/// (−z), the index from the palmar side (+z).
double pressSign(int finger) noexcept { return finger == kThumb ? -1.0 : 1.0; }
}  // namespace

SimulatedMassageMf2::SimulatedMassageMf2(const TissueParams& web, const OperatorConfig& op,
                                         const Clock& clock, double force_scale,
                                         const MassagePlan& plan,
                                         const SimulatedMassageDynamics& dyn,
                                         const mf2::Mf2Description& device)
    : web_(web),
      op_(op),
      clock_(clock),
      force_scale_(force_scale),
      plan_(plan),
      dyn_(dyn),
      radius_m_(plan.radius_m * op.amplitude_scale),
      freq_hz_((plan.frequency_hz + op.frequency_error_hz) * (plan.counter_clockwise ? 1.0 : -1.0)),
      hw_(device, dyn.pad_angle_deg),
      noise_(op.seed),
      tremor_noise_(op.seed ^ kTremorSeed),
      start_ns_(clock.nowNs()),
      sim_ns_(start_ns_) {
  std::mt19937_64 rng(op.seed ^ kWanderSeed);
  std::uniform_real_distribution<double> phase(0.0, 2.0 * kPi);
  for (double& w : wander_phase_) w = phase(rng);
  // Thimble frames: x along the web, z (the pad normal) into it.
  const Quat& q = web.orientation;
  thimble_[kIndex] = q;
  thimble_[kThumb] = q * Quat(Eigen::AngleAxisd(kPi, Vec3::UnitX()));
  // From rest at the circle's start point, touching the surface.
  const Vec3 start = targetPointW(0.0);
  const double surface = 0.5 * web.thickness_m + web.pad_radius_m;
  for (int k = 0; k < 2; ++k) {
    p_[k] = web_.fromWeb(Vec3(start.x(), start.y(), -pressSign(k) * surface));
  }
}

void SimulatedMassageMf2::setPatient(const TissueParams& truth) noexcept {
  patient_ = TissueModel(truth);
  capturing_ = true;
  anchor_ = {};
  hw_.off();
}

double SimulatedMassageMf2::targetPressN(double t_s) const noexcept {
  double wander = 0.0;
  for (std::size_t i = 0; i < wander_phase_.size(); ++i) {
    wander += std::sin(2.0 * kPi * kWanderRatio[i] * plan_.wander_hz * t_s + wander_phase_[i]);
  }
  // Each sine has RMS 1/sqrt(2): the two together have RMS 1.
  wander *= plan_.wander_n;
  return smoothRamp(t_s, plan_.ramp_s) * (plan_.normal_force_n + op_.force_bias_n + wander);
}

SimulatedMassageMf2::Phase SimulatedMassageMf2::phaseAt(double t_s) const noexcept {
  // The angular speed builds up as smoothRamp (3u^2 - 2u^3 of u = t / T); its integral is
  // T (u^3 - u^4 / 2), T / 2 at u = 1.
  const double w = 2.0 * kPi * freq_hz_;
  const double ramp = plan_.ramp_s;
  if (!(ramp > 0.0) || t_s >= ramp) return {w * (t_s - 0.5 * std::max(ramp, 0.0)), w, 0.0};
  if (t_s <= 0.0) return {0.0, 0.0, 0.0};
  const double u = t_s / ramp;
  return {w * ramp * (u * u * u - 0.5 * u * u * u * u), w * u * u * (3.0 - 2.0 * u),
          w * 6.0 * u * (1.0 - u) / ramp};
}

Vec3 SimulatedMassageMf2::targetPointW(double t_s) const noexcept {
  const double a = phaseAt(t_s).angle;
  return {plan_.centre_x_m + radius_m_ * std::cos(a), plan_.centre_y_m + radius_m_ * std::sin(a),
          0.0};
}

void SimulatedMassageMf2::integrate(double dt) noexcept {
  const bool perform = performing_.load(std::memory_order_acquire);
  if (perform != was_performing_) {
    was_performing_ = perform;
    start_ns_ = sim_ns_;
    learned_ = {};
  }
  // At rest the operator's time stays at 0: no press, the target still at the start point.
  const double t_s = perform ? static_cast<double>(sim_ns_ - start_ns_) * 1e-9 : 0.0;
  const double s = operatorScale();
  const Quat& q = web_.params().orientation;
  const Phase ph = phaseAt(t_s);
  const double c = std::cos(ph.angle), sn = std::sin(ph.angle);
  const Vec3 target(plan_.centre_x_m + radius_m_ * c, plan_.centre_y_m + radius_m_ * sn, 0.0);
  const Vec3 target_v = radius_m_ * ph.rate * Vec3(-sn, c, 0.0);
  const Vec3 target_a =
      radius_m_ * (ph.accel * Vec3(-sn, c, 0.0) - ph.rate * ph.rate * Vec3(c, sn, 0.0));
  const double press = targetPressN(t_s);

  // The tremor of each finger and web axis (reference N), ramped in with the press.
  PerFinger<Vec3> tremor{Vec3::Zero(), Vec3::Zero()};
  if (op_.tremor_n > 0.0) {
    const double gain = smoothRamp(t_s, plan_.ramp_s) * op_.tremor_n;
    for (int k = 0; k < 2; ++k) {
      for (int a = 0; a < 3; ++a) tremor[k][a] = gain * tremor_[k][a].step(tremor_noise_());
    }
  }

  for (int k = 0; k < 2; ++k) {
    const double d = pressSign(k);
    const Vec3 pw = web_.toWeb(p_[k]);
    const Vec3 vw = q.conjugate() * v_[k];
    // The hand: a controlled press along the normal with a little damping, a spring and
    // damper to the circle's target across it plus the drag it has learned, and the
    // feed-forward of its own inertia.
    const double ex = target.x() - pw.x(), ey = target.y() - pw.y();
    if (dyn_.adapt_s > 0.0) {
      const double gain = dyn_.hand_stiffness_n_per_m / dyn_.adapt_s * dt;
      learned_[k][0] += gain * (ex * c + ey * sn);
      learned_[k][1] += gain * (-ex * sn + ey * c);
    }
    const double lx = learned_[k][0] * c - learned_[k][1] * sn;
    const double ly = learned_[k][0] * sn + learned_[k][1] * c;
    Vec3 fw;
    fw.x() = s * (dyn_.hand_stiffness_n_per_m * ex +
                  dyn_.hand_damping_n_s_per_m * (target_v.x() - vw.x()) + lx + tremor[k].x()) +
             dyn_.mass_kg * target_a.x();
    fw.y() = s * (dyn_.hand_stiffness_n_per_m * ey +
                  dyn_.hand_damping_n_s_per_m * (target_v.y() - vw.y()) + ly + tremor[k].y()) +
             dyn_.mass_kg * target_a.y();
    fw.z() = d * s * (press + tremor[k].z() - dyn_.press_damping_n_s_per_m * d * vw.z());
    operator_force_[k] = q * fw;

    Vec3 external;
    if (capturing_) {
      contact_[k] = tissueContact(patient_, k, p_[k], v_[k], anchor_[k]);
      external = contact_[k].force();
    } else {
      external = hw_.rendered()[k];
    }
    v_[k] += (operator_force_[k] + external) / dyn_.mass_kg * dt;  // semi-implicit Euler
    p_[k] += v_[k] * dt;
  }
}

void SimulatedMassageMf2::advanceTo(int64_t t_ns) noexcept {
  int steps = 0;
  while (sim_ns_ + kStepNs <= t_ns) {
    if (++steps > kMaxCatchUpSteps) {
      sim_ns_ = t_ns - (t_ns - sim_ns_) % kStepNs;
      break;
    }
    integrate(static_cast<double>(kStepNs) * 1e-9);
    sim_ns_ += kStepNs;
    ++seq_;
  }
}

bool SimulatedMassageMf2::read(DeviceSample& out) noexcept {
  if (!reading_) {
    // The clinician puts the fingers on the web when the loop starts reading: before that
    // nothing is rendered (the session is being opened), and pressing into a web that does
    // not push back would sink the fingers deep before the first force (40 clamped ticks).
    // The first read is the clinician's first step.
    reading_ = true;
    start_ns_ = sim_ns_ = clock_.nowNs() - kStepNs;
  }
  advanceTo(clock_.nowNs());
  PerFinger<mf2::ThimblePose> truth, pose;
  for (int k = 0; k < 2; ++k) {
    truth[k].position_m = p_[k];
    truth[k].orientation = thimble_[k];
  }
  if (!hw_.measurePoses(truth, pose)) return false;  // out of the linkage's reach
  out.seq = seq_;
  out.time_ns = sim_ns_;
  for (int k = 0; k < 2; ++k) {
    out.fingers[k].position_m = pose[k].position_m;
    out.fingers[k].orientation = pose[k].orientation;
    Vec3 pressed = operator_force_[k];
    if (force_noise_n_ > 0.0) {
      // Along the pad normal and the thimble's side axis (the ones eqs. 1-2 measure).
      pressed += thimble_[k] * Vec3(0.0, force_noise_n_ * noise_(), force_noise_n_ * noise_());
    }
    hw_.readFsr(k, thimble_[k], pressed, op_.sensor_noise_n, noise_, out.fingers[k]);
  }
  return true;
}

bool SimulatedMassageMf2::write(const ForceCommand& cmd) noexcept {
  if (capturing_) {
    hw_.off();  // a capture runs with the actuators off
    return true;
  }
  if (!hw_.hasPose()) {
    PerFinger<mf2::ThimblePose> truth, pose;
    for (int k = 0; k < 2; ++k) {
      truth[k].position_m = p_[k];
      truth[k].orientation = thimble_[k];
    }
    if (!hw_.measurePoses(truth, pose)) return false;
  }
  return hw_.render(cmd.force_n);
}

}  // namespace telehand::devices
