#include "telehand/core/joint_model.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>

#include "telehand/core/knn_model.h"

namespace telehand {

double CubicCurve::eval(double deg) const noexcept {
  auto poly = [this](double a) {
    return ((coeffs[0] * a + coeffs[1]) * a + coeffs[2]) * a + coeffs[3];
  };
  if (deg > max_deg) {
    const double excess = deg - max_deg;
    return poly(max_deg) + (slope(max_deg) + kWallNPerDeg) * excess;
  }
  if (deg < min_deg) {
    const double excess = deg - min_deg;  // negative
    return poly(min_deg) + (slope(min_deg) + kWallNPerDeg) * excess;
  }
  return poly(deg);
}

double CubicCurve::slope(double deg) const noexcept {
  const double a = std::clamp(deg, min_deg, max_deg);
  return (3.0 * coeffs[0] * a + 2.0 * coeffs[1]) * a + coeffs[2];
}

std::optional<std::string> passiveCurveProblem(const CubicCurve& c) {
  char text[160];
  // The slope is a quadratic: its least value over the range is at an end or at its vertex.
  double at = c.min_deg;
  double least = c.slope(at);
  auto consider = [&](double deg) {
    const double s = c.slope(deg);
    if (std::isnan(s) || s < least) {
      least = s;
      at = deg;
    }
  };
  consider(c.max_deg);
  if (c.coeffs[0] != 0.0) {
    const double vertex = -c.coeffs[1] / (3.0 * c.coeffs[0]);
    if (vertex > c.min_deg && vertex < c.max_deg) consider(vertex);
  }
  if (!std::isfinite(least)) {
    std::snprintf(text, sizeof text, "slope is not finite at %g deg", at);
    return std::string(text);
  }
  if (!(least > 0.0)) {
    std::snprintf(text, sizeof text,
                  "falls at %g deg (slope %g N/deg): a passive joint's force must rise with the "
                  "angle",
                  at, least);
    return std::string(text);
  }
  // Rising, so its force is largest in magnitude at a range end.
  for (double deg : {c.min_deg, c.max_deg}) {
    const double f = c.eval(deg);
    if (!(std::abs(f) <= kMaxHoldingForceN)) {
      std::snprintf(text, sizeof text,
                    "holds %g N at %g deg, beyond the %g N any joint may take at the lever arm", f,
                    deg, kMaxHoldingForceN);
      return std::string(text);
    }
  }
  return std::nullopt;
}

JointModelParams healthyIndexMcp() {
  JointModelParams p;
  p.version = 1;
  // Paper eqs. 3-5 (docs/facts.md "The paper"); ranges from docs/facts.md "Index MCP biomechanics".
  p.axes[kFlexion] = {{1.834e-5, 0.0010338, 0.046382, 0.59057}, -45.0, 90.0};
  p.axes[kAbduction] = {{0.00017, 0.0012, 0.13, -0.49}, -20.0, 20.0};
  p.axes[kAxial] = {{0.0014, -0.014, 0.65, 0.09}, -10.0, 15.0};
  p.lever_arm_m = 0.01;
  p.force_scale = 0.25;
  p.damping_nms_per_rad = 0.002;
  constexpr char kName[] = "healthy";
  std::memcpy(p.case_name.data(), kName, sizeof(kName));
  return p;
}

JointModel::JointModel(const JointModelParams& params) : p_(params) {
  for (int i = 0; i < kAxes; ++i)
    rest_deg_[static_cast<std::size_t>(i)] = radToDeg(restAngleRad(i));
}

double JointModel::holdingForceN(int axis, double angle_rad) const noexcept {
  const auto i = static_cast<std::size_t>(axis);
  const CubicCurve& c = p_.axes[i];
  const double deg = radToDeg(angle_rad);
  const double zone = p_.neutral_zone_deg[i];
  if (zone <= 0.0) return c.eval(deg);
  // The band around rest is free; outside it, the curve resumes from the band's edge. The
  // end-of-range wall stays at min_deg/max_deg, where the server's hand stops the joint: the
  // shift applies to the curve, not to the range.
  const double in = std::clamp(deg, c.min_deg, c.max_deg);
  const double off = in - rest_deg_[i];
  const double shifted = std::abs(off) <= zone ? rest_deg_[i] : in - std::copysign(zone, off);
  const double excess = deg - in;
  if (excess == 0.0) return c.eval(shifted);
  return c.eval(shifted) + (c.slope(shifted) + kWallNPerDeg) * excess;
}

double stableDampingNsPerM(double mass_kg, int delay_ticks, double period_s) noexcept {
  if (!(mass_kg > 0.0) || !(period_s > 0.0) || delay_ticks < 0) return 0.0;
  // 2·cos(dπ/(2d + 1)), Levin & May's form of 2·sin(π/(2(2d + 1))): exactly 2 and 1 (to the
  // last bit) for d = 0 and 1.
  const double d = static_cast<double>(delay_ticks);
  return 2.0 * std::cos(d * kPi / (2.0 * d + 1.0)) * mass_kg / period_s;
}

double JointModel::maxDampingNmsPerRad() const noexcept {
  // Device damping B = force_scale · c / lever² for a joint damping c (force at the lever,
  // speed at the lever).
  const double lever = p_.lever_arm_m;
  if (!(lever > 0.0) || !(p_.force_scale > 0.0)) return 0.0;
  return device_damping_cap_ns_per_m_ * lever * lever / p_.force_scale;
}

void JointModel::setDeviceDampingCap(double ns_per_m) noexcept {
  device_damping_cap_ns_per_m_ =
      ns_per_m > 0.0 ? std::min(ns_per_m, kMaxDeviceDampingNsPerM) : kMaxDeviceDampingNsPerM;
}

double JointModel::viscousTorqueNm(double elastic_nm, double rate) const noexcept {
  // Stretching: moving the way the elastic torque resists (the stretched tissue lengthens).
  const bool stretching = elastic_nm * rate < 0.0;
  const double reflex =
      stretching ? p_.speed_gain_s_per_rad * std::abs(elastic_nm) : 0.0;  // N·m·s/rad
  const double c = std::min(p_.damping_nms_per_rad + reflex, maxDampingNmsPerRad());
  return -std::max(c, 0.0) * rate;
}

Vec3 JointModel::passiveTorqueNm(const Vec3& angles_rad, const Vec3& rates_rad_s) const noexcept {
  Vec3 tau;
  if (p_.knn) {
    // The samples inside the ranges; beyond them the nearest samples' torque plus the wall.
    Vec3 in;
    Vec3 excess_deg;
    for (int i = 0; i < kAxes; ++i) {
      const CubicCurve& c = p_.axes[static_cast<std::size_t>(i)];
      in[i] = std::clamp(angles_rad[i], degToRad(c.min_deg), degToRad(c.max_deg));
      excess_deg[i] = radToDeg(angles_rad[i] - in[i]);
    }
    const Vec3 knn = p_.knn->torqueNm(in);
    for (int i = 0; i < kAxes; ++i) {
      const double elastic = knn[i] - kWallNPerDeg * excess_deg[i] * p_.lever_arm_m;
      tau[i] = elastic + viscousTorqueNm(elastic, rates_rad_s[i]);
    }
    return tau;
  }
  for (int i = 0; i < kAxes; ++i) {
    const double elastic = -holdingForceN(i, angles_rad[i]) * p_.lever_arm_m;
    tau[i] = elastic + viscousTorqueNm(elastic, rates_rad_s[i]);
  }
  return tau;
}

Mat3 eulerToRotation(const Vec3& a) noexcept {
  return (Eigen::AngleAxisd(a[kFlexion], Vec3::UnitY()) *
          Eigen::AngleAxisd(a[kAxial], Vec3::UnitX()) *
          Eigen::AngleAxisd(a[kAbduction], Vec3::UnitZ()))
      .toRotationMatrix();
}

Vec3 eulerFromRotation(const Mat3& r) noexcept {
  // R = Ry(a) Rx(g) Rz(b): R12 = -sin g, (R10, R11) = cos g (sin b, cos b),
  // (R02, R22) = cos g (sin a, cos a).
  Vec3 a;
  a[kAxial] = std::asin(std::clamp(-r(1, 2), -1.0, 1.0));
  a[kAbduction] = std::atan2(r(1, 0), r(1, 1));
  a[kFlexion] = std::atan2(r(0, 2), r(2, 2));
  return a;
}

Mat3 eulerAxisBasis(const Vec3& a) noexcept {
  const Mat3 ry = Eigen::AngleAxisd(a[kFlexion], Vec3::UnitY()).toRotationMatrix();
  const Mat3 rx = Eigen::AngleAxisd(a[kAxial], Vec3::UnitX()).toRotationMatrix();
  Mat3 e;
  e.col(kFlexion) = Vec3::UnitY();
  e.col(kAxial) = ry * Vec3::UnitX();
  e.col(kAbduction) = ry * rx * Vec3::UnitZ();
  return e;
}

Mat3 JointModel::phalanxRotation(const Vec3& a) const noexcept {
  return p_.joint_orientation.toRotationMatrix() * eulerToRotation(a);
}

Vec3 JointModel::anglesFromRotation(const Mat3& r_device) const noexcept {
  return eulerFromRotation(p_.joint_orientation.toRotationMatrix().transpose() * r_device);
}

Mat3 JointModel::axisBasis(const Vec3& a) const noexcept {
  return p_.joint_orientation.toRotationMatrix() * eulerAxisBasis(a);
}

Vec3 JointModel::torqueVector(const Vec3& angles_rad, const Vec3& axis_torque_nm) const noexcept {
  // Generalized torques are e^T tau, so tau = e^-T tau_gen.
  return axisBasis(angles_rad).transpose().partialPivLu().solve(axis_torque_nm);
}

Vec3 JointModel::anglesFromGrip(const PerFinger<Vec3>& p) const noexcept {
  const Vec3 mid = 0.5 * (p[kThumb] + p[kIndex]) - p_.joint_origin_m;
  const double n = mid.norm();
  if (n < 1e-9) return Vec3::Zero();
  const Vec3 x = mid / n;
  // Dorsal direction: from the index (palmar side) to the thumb, across the phalanx axis.
  Vec3 z = p[kThumb] - p[kIndex];
  z -= x * x.dot(z);
  const double zn = z.norm();
  if (zn < 1e-9) return Vec3::Zero();
  z /= zn;
  Mat3 r;
  r.col(0) = x;
  r.col(1) = z.cross(x);
  r.col(2) = z;
  return anglesFromRotation(r);
}

PerFinger<Vec3> JointModel::gripFromAngles(const Vec3& angles_rad,
                                           double half_width_m) const noexcept {
  const Mat3 r = phalanxRotation(angles_rad);
  const Vec3 mid = p_.joint_origin_m + r.col(0) * p_.lever_arm_m;
  const Vec3 dorsal = r.col(2);
  return {mid + dorsal * half_width_m, mid - dorsal * half_width_m};
}

Quat JointModel::thimbleOrientation(int finger, const Vec3& angles_rad) const noexcept {
  const Mat3 r = phalanxRotation(angles_rad);
  Mat3 t;
  t.col(0) = r.col(0);
  t.col(2) = finger == kThumb ? Vec3(-r.col(2)) : Vec3(r.col(2));
  t.col(1) = t.col(2).cross(t.col(0));
  return Quat(t);
}

PerFinger<Vec3> JointModel::fingertipForces(const PerFinger<Vec3>& p, const Vec3& angles_rad,
                                            const Vec3& axis_torque_nm) const noexcept {
  const Vec3 tau = torqueVector(angles_rad, axis_torque_nm);
  const Vec3 mid = 0.5 * (p[kThumb] + p[kIndex]);
  const Vec3 r = mid - p_.joint_origin_m;
  const double r2 = r.squaredNorm();
  if (r2 < 1e-12 || !allFinite(tau)) return {Vec3::Zero(), Vec3::Zero()};
  const Vec3 u = r / std::sqrt(r2);
  const Vec3 tau_axial = u * u.dot(tau);
  const Vec3 s = p[kIndex] - mid;  // index offset from the grip centre; thumb is −s
  const Vec3 s_perp = s - u * u.dot(s);
  const double s2 = s_perp.squaredNorm();
  Vec3 couple = Vec3::Zero();
  if (s2 > 1e-12) couple = tau_axial.cross(s_perp) / (2.0 * s2);  // u·(2 s × couple) = u·tau
  // The net force carries the rest. When the pinch line leans along the phalanx (measured
  // thimbles), the couple's moment also has a part across the axis that this cancels.
  const Vec3 rest = tau - 2.0 * s.cross(couple);
  const Vec3 f_net = rest.cross(r) / r2;  // r × f_net = rest across r
  // Along the pinch line (index to thumb, dorsal), the load goes to the finger whose pad it
  // presses: the thumb's share t of the along-line force x blends from x/2 at x = 0 to all
  // of x, and neither finger takes more than kFingerLoadN of it while the other can.
  const double sn = std::sqrt(s.squaredNorm());
  Vec3 squeeze = Vec3::Zero();
  if (sn > 1e-9) {
    const Vec3 e = -s / sn;  // index -> thumb
    const double x = f_net.dot(e);
    double t = 0.5 * x * (1.0 + x / std::sqrt(x * x + kSplitBlendN * kSplitBlendN));
    if (std::abs(x) <= 2.0 * kFingerLoadN) {
      t = std::clamp(t, std::max(x - kFingerLoadN, -kFingerLoadN),
                     std::min(x + kFingerLoadN, kFingerLoadN));
    } else {
      t = 0.5 * x;
    }
    // Equal and opposite forces on the line through both pads: no net force, no moment.
    squeeze = (t - 0.5 * x) * e;
  }
  return {0.5 * f_net - couple + squeeze, 0.5 * f_net + couple - squeeze};
}

Vec3 JointModel::axisTorque(const PerFinger<Vec3>& p, const Vec3& angles_rad,
                            const PerFinger<Vec3>& f) const noexcept {
  const Vec3 c = p_.joint_origin_m;
  const Vec3 tau = (p[kThumb] - c).cross(f[kThumb]) + (p[kIndex] - c).cross(f[kIndex]);
  return axisBasis(angles_rad).transpose() * tau;
}

double JointModel::rangeExcessDeg(const Vec3& angles_rad) const noexcept {
  double excess = 0.0;
  for (int i = 0; i < kAxes; ++i) {
    const CubicCurve& c = p_.axes[static_cast<std::size_t>(i)];
    const double deg = radToDeg(angles_rad[i]);
    excess = std::max({excess, c.min_deg - deg, deg - c.max_deg});
  }
  return excess;
}

double JointModel::restAngleRad(int axis) const noexcept {
  const CubicCurve& c = p_.axes[static_cast<std::size_t>(axis)];
  double lo = c.min_deg, hi = c.max_deg;
  const double f_lo = c.eval(lo), f_hi = c.eval(hi);
  if (f_lo >= 0.0) return degToRad(lo);
  if (f_hi <= 0.0) return degToRad(hi);
  for (int i = 0; i < 60; ++i) {
    const double m = 0.5 * (lo + hi);
    (c.eval(m) < 0.0 ? lo : hi) = m;
  }
  return degToRad(0.5 * (lo + hi));
}

double JointModel::potentialEnergyJ(const Vec3& angles_rad) const noexcept {
  // Simpson's rule on each piece where the force is smooth: the cubic inside the range (exact
  // without a neutral zone) and the wall beyond it.
  auto integrate = [this](int axis, double from_deg, double to_deg) {
    constexpr int kIntervals = 16;
    const double h = (to_deg - from_deg) / kIntervals;
    if (h == 0.0) return 0.0;
    double sum = 0.0;
    for (int i = 0; i <= kIntervals; ++i) {
      const double w = (i == 0 || i == kIntervals) ? 1.0 : (i % 2 ? 4.0 : 2.0);
      sum += w * holdingForceN(axis, degToRad(from_deg + i * h));
    }
    return sum * h / 3.0;  // N·deg
  };
  double j = 0.0;
  for (int i = 0; i < kAxes; ++i) {
    const CubicCurve& c = p_.axes[static_cast<std::size_t>(i)];
    const double deg = radToDeg(angles_rad[i]);
    if (!std::isfinite(deg)) return 0.0;
    const double rest = rest_deg_[static_cast<std::size_t>(i)];
    const double in = std::clamp(deg, c.min_deg, c.max_deg);
    const double n_deg = integrate(i, rest, in) + integrate(i, in, deg);
    j += std::max(n_deg, 0.0) * degToRad(1.0) * p_.lever_arm_m;
  }
  return j * p_.force_scale;
}

Vec3 JointModel::guideTargetRad(double t_s, Vec3* rates_rad_s) const noexcept {
  const GuideParams& g = p_.guide;
  constexpr int n = GuideParams::kPoints;
  if (!(g.period_s > 0.0) || !std::isfinite(t_s)) {
    if (rates_rad_s) rates_rad_s->setZero();
    return g.path_rad[0];
  }
  double cycles = t_s / g.period_s;
  cycles -= std::floor(cycles);
  const double x = cycles * n;
  const int i = std::clamp(static_cast<int>(x), 0, n - 1);
  const int j = (i + 1) % n;
  const double f = x - i;
  const auto ui = static_cast<std::size_t>(i), uj = static_cast<std::size_t>(j);
  if (rates_rad_s) *rates_rad_s = (g.path_rad[uj] - g.path_rad[ui]) * (n / g.period_s);
  return (1.0 - f) * g.path_rad[ui] + f * g.path_rad[uj];
}

Vec3 JointModel::guideTorqueNm(const Vec3& angles_rad, const Vec3& rates_rad_s,
                               double t_s) const noexcept {
  const GuideParams& g = p_.guide;
  if (!g.active()) return Vec3::Zero();
  Vec3 target_rates;
  const Vec3 target = guideTargetRad(t_s, &target_rates);
  const double authority = std::clamp(g.authority, 0.0, 1.0);
  const double bound = std::clamp(g.max_force_n, 0.0, GuideParams::kMaxForceN);
  const double k = std::clamp(g.stiffness_n_per_deg, 0.0, GuideParams::kMaxStiffnessNPerDeg);
  Vec3 tau;
  for (int i = 0; i < kAxes; ++i) {
    const double f = k * radToDeg(target[i] - angles_rad[i]) +
                     k * GuideParams::kDampingS * radToDeg(target_rates[i] - rates_rad_s[i]);
    // NaN angles give NaN here; the safety gate zeroes non-finite forces.
    tau[i] = authority * std::clamp(f, -bound, bound) * p_.lever_arm_m;
  }
  return tau;
}

JointProxy::JointProxy(const JointModelParams& initial, int64_t blend_ns)
    : current_(initial), previous_(initial), pending_(initial), blend_ns_(blend_ns) {}

void JointProxy::startFade(int64_t now_ns) noexcept {
  // A guide where there was none starts at its path's beginning. A guide that follows one
  // keeps the phase the movement is at: every path starts at the same point of the movement
  // (an upward crossing of the force's mean level, technique::deriveTargets), so a new path
  // or period (a supervisor's take-over, refreshed as they move) goes on from where the old
  // one was, and the version faded out keeps its own clock: no step in either target.
  const GuideParams& was = current_.params().guide;
  const GuideParams& next = pending_.params().guide;
  prev_guide_t0_ns_ = guide_t0_ns_;
  if (next.active() && !was.active()) {
    guide_t0_ns_ = now_ns;
  } else if (next.active() && was.period_s > 0.0 && next.period_s > 0.0 &&
             was.period_s != next.period_s) {
    double cycles = static_cast<double>(now_ns - guide_t0_ns_) * 1e-9 / was.period_s;
    cycles -= std::floor(cycles);
    guide_t0_ns_ = now_ns - static_cast<int64_t>(std::llround(cycles * next.period_s * 1e9));
  }
  previous_ = current_;
  current_ = pending_;
  have_pending_ = false;
  weight_ = blend_ns_ > 0 ? 0.0 : 1.0;
  blending_ = blend_ns_ > 0;
  fade_ns_ = now_ns;
  fade_start_ns_ = now_ns;
}

void JointProxy::setModel(const JointModelParams& next) noexcept {
  // Switching targets mid-fade would step the force: the newest version waits for the fade
  // to end. One equal to the model being faded to (or rendered) is no change.
  have_pending_ = !(next == current_.params());
  if (have_pending_) {
    pending_ = JointModel(next);
    pending_.setDeviceDampingCap(device_damping_cap_ns_per_m_);
  }
}

void JointProxy::setDeviceDampingCap(double ns_per_m) noexcept {
  if (ns_per_m == device_damping_cap_ns_per_m_) return;
  device_damping_cap_ns_per_m_ = ns_per_m;
  for (JointModel* m : {&current_, &previous_, &pending_}) m->setDeviceDampingCap(ns_per_m);
}

ProxyOutput JointProxy::renderWith(const JointModel& m, const PerFinger<Vec3>& p,
                                   const Vec3& angles, const Vec3& rates,
                                   double guide_t_s) const noexcept {
  ProxyOutput out;
  out.angles_rad = angles;
  out.torque_ref_nm = m.passiveTorqueNm(angles, rates);
  out.guide_ref_nm = m.guideTorqueNm(angles, rates, guide_t_s);
  out.force_device_n =
      m.fingertipForces(p, angles, (out.torque_ref_nm + out.guide_ref_nm) * m.params().force_scale);
  return out;
}

ProxyOutput JointProxy::render(const PerFinger<Vec3>& p, int64_t now_ns) noexcept {
  if (!blending_ && have_pending_) startFade(now_ns);
  // Rates from the thimbles alone: a new drift correction moves the rendered angles, not the
  // finger.
  const Vec3 grip_angles = current_.anglesFromGrip(p);
  if (have_last_ && now_ns > last_ns_) {
    // First-order low-pass (5 ms) on the finite difference: encoder noise would otherwise
    // dominate the damping term.
    const double dt = static_cast<double>(now_ns - last_ns_) * 1e-9;
    constexpr double kTau = 0.005;
    const Vec3 raw = (grip_angles - last_angles_) / dt;
    rates_ += (dt / (kTau + dt)) * (raw - rates_);
  }
  have_last_ = true;
  last_ns_ = now_ns;
  last_angles_ = grip_angles;
  const Vec3 angles = grip_angles + current_.params().grip_offset_rad;

  const double guide_t_s = static_cast<double>(now_ns - guide_t0_ns_) * 1e-9;
  ProxyOutput out = renderWith(current_, p, angles, rates_, guide_t_s);
  const double v_current = current_.potentialEnergyJ(angles);
  out.potential_j = v_current;
  if (!blending_) return out;

  // The previous version renders with its own drift correction: a correction fades in like
  // any other model change.
  const Vec3 old_angles = previous_.proxyAngles(p);
  const ProxyOutput old = renderWith(previous_, p, old_angles, rates_,
                                     static_cast<double>(now_ns - prev_guide_t0_ns_) * 1e-9);
  double gap = 0.0, now_force = 0.0;
  for (int k = 0; k < 2; ++k) {
    gap = std::max(gap, (out.force_device_n[k] - old.force_device_n[k]).norm());
    now_force = std::max(
        now_force,
        (weight_ * out.force_device_n[k] + (1.0 - weight_) * old.force_device_n[k]).norm());
  }
  // The nominal pace: the whole fade in blend_ns.
  const double dt_ns = static_cast<double>(std::max<int64_t>(now_ns - fade_ns_, 0));
  fade_ns_ = std::max(fade_ns_, now_ns);
  double dw = std::min(dt_ns / static_cast<double>(blend_ns_), 1.0 - weight_);
  // No tick's force changes by more than the bound because of the update (0.9: margin for
  // the force itself moving within the tick).
  const double bound = 0.9 * updateStepBoundN(now_force);
  if (gap * dw > bound) dw = bound / gap;
  // A stiffer model stores more energy at these angles: that difference must be paid for.
  const double v_previous = previous_.potentialEnergyJ(old_angles);
  const double dv = v_current - v_previous;
  // A joint held where nothing dissipates would keep the old model for ever (a follower
  // feeling a capture would never get the fit): after kEnergyWaitNs the fade goes on at its
  // nominal pace, still under the step bound, and the passivity controller removes whatever
  // energy it adds once the operator takes it back.
  const bool waited_out = now_ns - fade_start_ns_ > kEnergyWaitNs;
  if (dv > 0.0 && dw * dv > energy_budget_j_ && !waited_out)
    dw = std::max(energy_budget_j_, 0.0) / dv;
  dw = std::max(dw, 0.0);
  weight_ += dw;
  if (dv > 0.0) out.unpaid_energy_j = std::max(dw * dv - std::max(energy_budget_j_, 0.0), 0.0);
  energy_budget_j_ -= dw * dv;
  out.update_step_n = dw * gap;
  out.blend_energy_j = dw * dv;
  if (weight_ >= 1.0 - 1e-9) {
    weight_ = 1.0;
    blending_ = false;
    return out;  // exactly the new model from here on
  }
  const double w = weight_;
  out.potential_j = w * v_current + (1.0 - w) * v_previous;
  out.torque_ref_nm = w * out.torque_ref_nm + (1.0 - w) * old.torque_ref_nm;
  out.guide_ref_nm = w * out.guide_ref_nm + (1.0 - w) * old.guide_ref_nm;
  for (int k = 0; k < 2; ++k) {
    out.force_device_n[k] = w * out.force_device_n[k] + (1.0 - w) * old.force_device_n[k];
  }
  out.blending = true;
  return out;
}

}  // namespace telehand
