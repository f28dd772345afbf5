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
constexpr uint64_t kProtocolSeed = 0x7072'6f74'6f63'0004ULL;

/// smoothRamp's value, slope and curvature at u of a ramp over `width`.
struct Ramp {
  double v, dv, ddv;
};
Ramp ramp(double u, double width) noexcept {
  if (!(width > 0.0) || u >= width) return {1.0, 0.0, 0.0};
  if (u <= 0.0) return {0.0, 0.0, 0.0};
  const double x = u / width;
  return {x * x * (3.0 - 2.0 * x), 6.0 * x * (1.0 - x) / width,
          6.0 * (1.0 - 2.0 * x) / (width * width)};
}

/// A stroke's phase: the angular speed omega built up and let down over `r` at both ends of
/// a stroke of `T` seconds (T ≥ 2r): angle, rate, acceleration at u.
struct StrokePhase {
  double angle, rate, accel;
};
StrokePhase strokePhase(double u, double T, double omega, double r) noexcept {
  auto rampUp = [&](double x) {  // the angle over the first ramp, and its rate and slope
    const double v = x / r;
    return StrokePhase{omega * r * (v * v * v - 0.5 * v * v * v * v),
                       omega * v * v * (3.0 - 2.0 * v), omega * 6.0 * v * (1.0 - v) / r};
  };
  if (u <= 0.0) return {0.0, 0.0, 0.0};
  if (u >= T) return {omega * (T - r), 0.0, 0.0};
  if (u < r) return rampUp(u);
  if (u > T - r) {
    const StrokePhase e = rampUp(T - u);
    return {omega * (T - r) - e.angle, e.rate, -e.accel};
  }
  return {omega * (u - 0.5 * r), omega, 0.0};
}

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

void SimulatedMassageMf2::setCaptureProtocol(const MassageCaptureProtocol& protocol) {
  protocol_ = protocol;
  indents_.clear();
  strokes_.clear();
  std::mt19937_64 rng(protocol.seed ^ op_.seed ^ kProtocolSeed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  auto uniform = [&](const double(&r)[2]) { return r[0] + (r[1] - r[0]) * unit(rng); };
  auto logUniform = [&](const double(&r)[2]) {
    return std::exp(std::log(r[0]) + (std::log(r[1]) - std::log(r[0])) * unit(rng));
  };
  const Vec3 start = targetPointW(0.0);
  const double gap = protocol.air_gap_m;
  // Indentations, after a first lift into the air (0.2 s).
  double t = 0.2;
  while (t < protocol.indent_s) {
    Step st;
    st.start_s = t;
    st.x = plan_.centre_x_m + (2.0 * unit(rng) - 1.0) * protocol.spot_m;
    st.y = plan_.centre_y_m + (2.0 * unit(rng) - 1.0) * protocol.spot_m;
    st.depth_m = uniform(protocol.indent_depth_m);
    st.in_s = 1.5 * (st.depth_m + gap) / logUniform(protocol.indent_speed_m_s);
    st.hold_s = uniform(protocol.indent_hold_s);
    st.out_s = 1.5 * (st.depth_m + gap) / logUniform(protocol.indent_speed_m_s);
    st.end_s = t + st.in_s + st.hold_s + st.out_s + uniform(protocol.indent_air_s);
    indents_.push_back(st);
    t = st.end_s;
  }
  // Strokes through the circle's start point, from the last indentation's end.
  const double stroke_end = t + protocol.stroke_s;
  constexpr double kStrokeRamp = 0.3;
  while (protocol.stroke_s > 0.0 && t < stroke_end) {
    Step st;
    st.start_s = t;
    st.x = start.x();
    st.y = start.y();
    st.force_n = uniform(protocol.stroke_force_n);
    st.dir = kPi * unit(rng);
    st.half_m = protocol.stroke_half_m;
    const double T = std::max(uniform(protocol.stroke_contact_s), 2.0 * kStrokeRamp + 0.1);
    // Whole strokes (back where it started): the peak speed as drawn, rounded to them.
    const double laps = std::max(1.0, std::round(uniform(protocol.stroke_speed_m_s) *
                                                 (T - kStrokeRamp) / (2.0 * kPi * st.half_m)));
    st.omega = 2.0 * kPi * laps / (T - kStrokeRamp);
    st.end_s = t + T;
    strokes_.push_back(st);
    t = st.end_s;
  }
  massage_start_s_ = t;
}

SimulatedMassageMf2::Aim SimulatedMassageMf2::protocolAim(double t_s) const noexcept {
  Aim a;
  const Vec3 start = targetPointW(0.0);
  const double gap = protocol_.air_gap_m;
  if (!indents_.empty() && t_s < indents_.back().end_s) {
    a.depth_control = true;
    if (t_s < indents_.front().start_s) {
      // Lift into the air and glide to the first spot.
      const Ramp r = ramp(t_s, indents_.front().start_s);
      a.depth = -gap * r.v;
      a.depth_rate = -gap * r.dv;
      a.depth_accel = -gap * r.ddv;
      const Vec3 to(indents_.front().x, indents_.front().y, 0.0);
      a.point = start + (to - start) * r.v;
      a.velocity = (to - start) * r.dv;
      a.accel = (to - start) * r.ddv;
      return a;
    }
    std::size_t i = 0;
    while (i + 1 < indents_.size() && t_s >= indents_[i].end_s) ++i;
    const Step& st = indents_[i];
    const double u = t_s - st.start_s, span = st.depth_m + gap;
    a.point = Vec3(st.x, st.y, 0.0);
    if (u < st.in_s) {
      const Ramp r = ramp(u, st.in_s);
      a.depth = -gap + span * r.v;
      a.depth_rate = span * r.dv;
      a.depth_accel = span * r.ddv;
    } else if (u < st.in_s + st.hold_s) {
      a.depth = st.depth_m;
    } else if (u < st.in_s + st.hold_s + st.out_s) {
      const Ramp r = ramp(u - st.in_s - st.hold_s, st.out_s);
      a.depth = st.depth_m - span * r.v;
      a.depth_rate = -span * r.dv;
      a.depth_accel = -span * r.ddv;
    } else {
      a.depth = -gap;
      // In the air: glide to the next spot (or to the strokes' centre).
      const double air0 = st.start_s + st.in_s + st.hold_s + st.out_s;
      const Vec3 to =
          i + 1 < indents_.size() ? Vec3(indents_[i + 1].x, indents_[i + 1].y, 0.0) : start;
      const Vec3 from(st.x, st.y, 0.0);
      const Ramp r = ramp(t_s - air0, st.end_s - air0);
      a.point = from + (to - from) * r.v;
      a.velocity = (to - from) * r.dv;
      a.accel = (to - from) * r.ddv;
    }
    return a;
  }
  a.point = start;
  if (strokes_.empty()) return a;
  std::size_t j = 0;
  while (j + 1 < strokes_.size() && t_s >= strokes_[j].end_s) ++j;
  const Step& st = strokes_[j];
  const double u = t_s - st.start_s;
  // The press moves from the previous stroke's to this one's over 0.2 s.
  const double before = j > 0 ? strokes_[j - 1].force_n : st.force_n;
  a.press = before + (st.force_n - before) * smoothRamp(u, 0.2);
  const StrokePhase ph = strokePhase(u, st.end_s - st.start_s, st.omega, 0.3);
  const Vec3 e(std::cos(st.dir), std::sin(st.dir), 0.0);
  const double sn = std::sin(ph.angle), cs = std::cos(ph.angle);
  a.point = Vec3(st.x, st.y, 0.0) + st.half_m * sn * e;
  a.velocity = st.half_m * cs * ph.rate * e;
  a.accel = st.half_m * (cs * ph.accel - sn * ph.rate * ph.rate) * e;
  return a;
}

void SimulatedMassageMf2::integrate(double dt) noexcept {
  const bool perform = performing_.load(std::memory_order_acquire);
  if (perform != was_performing_) {
    was_performing_ = perform;
    start_ns_ = sim_ns_;
    learned_ = {};
  }
  // At rest the operator's time stays at the massage's start: no press, the target still at
  // the start point.
  const double t_all = perform ? static_cast<double>(sim_ns_ - start_ns_) * 1e-9 : massage_start_s_;
  const bool characterising = t_all < massage_start_s_;
  const double t_s = t_all - massage_start_s_;  // the massage's own time
  const double s = operatorScale();
  const Quat& q = web_.params().orientation;
  const Phase ph = phaseAt(t_s);
  double c = std::cos(ph.angle), sn = std::sin(ph.angle);
  Vec3 target(plan_.centre_x_m + radius_m_ * c, plan_.centre_y_m + radius_m_ * sn, 0.0);
  Vec3 target_v = radius_m_ * ph.rate * Vec3(-sn, c, 0.0);
  Vec3 target_a = radius_m_ * (ph.accel * Vec3(-sn, c, 0.0) - ph.rate * ph.rate * Vec3(c, sn, 0.0));
  double press = targetPressN(t_s);
  Aim aim;
  if (characterising) {
    aim = protocolAim(t_all);
    target = aim.point;
    target_v = aim.velocity;
    target_a = aim.accel;
    press = aim.press;
    c = 1.0;
    sn = 0.0;
  }

  // The tremor of each finger and web axis (reference N), ramped in with the press.
  PerFinger<Vec3> tremor{Vec3::Zero(), Vec3::Zero()};
  if (op_.tremor_n > 0.0) {
    const double gain = smoothRamp(t_all, plan_.ramp_s) * op_.tremor_n;
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
    if (dyn_.adapt_s > 0.0 && !characterising) {
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
    if (characterising && aim.depth_control) {
      // Indenting: the hand drives the depth (a stiff spring and damper to the planned depth
      // and the feed-forward of its inertia), pressing no harder than the protocol allows.
      const double depth = web_.depthOf(k, p_[k]), rate = d * vw.z();
      const double kp = protocol_.press_stiffness_n_per_m;
      // Damped at 0.7 of critical: more, and the 1 kHz step rings (the damper's share of a
      // step, kd·dt/m, near 1).
      const double kd = 1.4 * std::sqrt(kp * dyn_.mass_kg);
      const double push = kp * (aim.depth - depth) + kd * (aim.depth_rate - rate) +
                          dyn_.mass_kg * aim.depth_accel + tremor[k].z();
      fw.z() = d * std::clamp(push, -protocol_.indent_max_force_n, protocol_.indent_max_force_n);
    } else {
      fw.z() = d * s * (press + tremor[k].z() - dyn_.press_damping_n_s_per_m * d * vw.z());
    }
    operator_force_[k] = q * fw;

    Vec3 external;
    if (capturing_) {
      contact_[k] = tissueContact(patient_, k, p_[k], v_[k], anchor_[k]);
      external = contact_[k].force();
    } else {
      external = hw_.rendered()[k];
    }
    // The forces of this step are those of the state it starts from: a capture's sample
    // reports that state, so that the thimble's force and its position are of one instant
    // (one step apart, the damping λ·δ̇ would read off by n·dt/δ, as much as λ itself).
    sampled_p_[k] = p_[k];
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
    truth[k].position_m = capturing_ && seq_ > 0 ? sampled_p_[k] : p_[k];
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
