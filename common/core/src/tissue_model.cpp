#include "telehand/core/tissue_model.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "telehand/core/sample.h"

namespace telehand {

const char* techniqueName(Technique t) noexcept {
  return t == Technique::kMassage ? "massage" : "mobilization";
}

bool parseTechnique(const char* text, Technique* out) noexcept {
  if (text == nullptr) return false;
  if (std::strcmp(text, "mobilization") == 0) {
    *out = Technique::kMobilization;
    return true;
  }
  if (std::strcmp(text, "massage") == 0) {
    *out = Technique::kMassage;
    return true;
  }
  return false;
}

namespace {
bool in(double v, double lo, double hi) { return std::isfinite(v) && v >= lo && v <= hi; }
double smoothstep(double e0, double e1, double x) noexcept {
  if (e1 <= e0) return x < e0 ? 0.0 : 1.0;
  const double t = std::clamp((x - e0) / (e1 - e0), 0.0, 1.0);
  return t * t * (3.0 - 2.0 * t);
}
// d smoothstep / dx.
double smoothstepSlope(double e0, double e1, double x) noexcept {
  if (e1 <= e0 || x <= e0 || x >= e1) return 0.0;
  const double t = (x - e0) / (e1 - e0);
  return 6.0 * t * (1.0 - t) / (e1 - e0);
}
// A stiffer patch stores more energy at the same depth: its rim pushes the finger out of it
// with the slope of that energy (-dV/dx), or the web would return more energy than it took
// from a finger that presses beside the patch and lets go inside it. Web frame.
Vec3 rimForce(const TissueModel& m, double depth, const Vec3& w) noexcept {
  const TissueParams& p = m.params();
  return -(p.patch_stiffness_factor - 1.0) * p.stiffness_n_per_m_pow *
         std::pow(depth, p.exponent + 1.0) / (p.exponent + 1.0) * m.patchGradient(w.x(), w.y());
}
}  // namespace

const char* invalidTissueParam(const TissueParams& p) noexcept {
  using P = TissueParams;
  if (!allFinite(p.origin_m) || p.origin_m.cwiseAbs().maxCoeff() > 1.0) return "origin_m";
  const double qn = p.orientation.coeffs().norm();
  if (!std::isfinite(qn) || std::abs(qn - 1.0) > 1e-3) return "orientation";
  if (!in(p.thickness_m, 0.0, P::kMaxLengthM)) return "thickness_m";
  if (!in(p.pad_radius_m, 0.0, P::kMaxLengthM)) return "pad_radius_m";
  if (!in(p.half_extent_m, 0.001, P::kMaxLengthM)) return "half_extent_m";
  if (!in(p.stiffness_n_per_m_pow, 0.0, P::kMaxStiffness)) return "stiffness";
  if (!in(p.exponent, P::kMinExponent, P::kMaxExponent)) return "exponent";
  if (!in(p.damping_s_per_m, 0.0, P::kMaxDamping)) return "damping";
  if (!in(p.lateral_stiffness_n_per_m, 0.0, P::kMaxLateral)) return "lateral_stiffness";
  if (!in(p.mu_static, 0.0, P::kMaxMu)) return "mu_static";
  if (!in(p.mu_kinetic, 0.0, p.mu_static)) return "mu_kinetic";
  if (!in(p.viscous_n_s_per_m, 0.0, P::kMaxViscous)) return "viscous";
  if (!in(p.patch_x_m, -P::kMaxLengthM, P::kMaxLengthM)) return "patch_x_m";
  if (!in(p.patch_y_m, -P::kMaxLengthM, P::kMaxLengthM)) return "patch_y_m";
  if (!in(p.patch_radius_m, 0.0, P::kMaxLengthM)) return "patch_radius_m";
  if (!in(p.patch_stiffness_factor, 0.1, P::kMaxPatchFactor)) return "patch_stiffness_factor";
  if (!in(p.patch_friction_factor, 0.1, P::kMaxPatchFactor)) return "patch_friction_factor";
  if (!in(p.patch_rim_m, 0.0, P::kMaxLengthM)) return "patch_rim_m";
  // A patch that changes the web needs a rim to blend over: at a step the force out of the
  // patch (the energy's slope) is zero, and the web gives more energy back than it took.
  if (p.patchChangesWeb() && p.patch_rim_m < P::kMinPatchRimM) {
    return "patch_rim_m";
  }
  return nullptr;
}

TissueParams tissueCase(const char* name) noexcept {
  // docs/massage.md "Cases": healthy is anchored at the paper's 10 N at a 6 mm press
  // (k = 10 / 0.006^1.5); the others are stated departures from it.
  TissueParams p;
  if (name == nullptr) return p;
  if (std::strcmp(name, "oedema") == 0) {
    p.thickness_m = 0.018;
    p.stiffness_n_per_m_pow = 2.5e5;
    p.exponent = 2.0;  // soft at first, stiffening sooner as the fluid is pushed aside
    p.damping_s_per_m = 1.2;
    p.lateral_stiffness_n_per_m = 500.0;
  } else if (std::strcmp(name, "scar") == 0) {
    p.patch_x_m = 0.004;
    p.patch_y_m = -0.003;
    p.patch_radius_m = 0.006;
    p.patch_stiffness_factor = 2.5;
    p.patch_friction_factor = 2.0;
    // A rim narrower than this pushes a circling finger sideways harder than the device
    // renders (5 N asked on a 6 mm circle with a 2 mm rim).
    p.patch_rim_m = 0.0045;
  } else if (std::strcmp(name, "hypertonic") == 0) {
    p.stiffness_n_per_m_pow = 4.0e4;
    p.exponent = 1.4;
    p.damping_s_per_m = 0.5;
    p.lateral_stiffness_n_per_m = 1200.0;
    p.mu_static = 0.6;
    p.mu_kinetic = 0.45;
  }
  return p;
}

Vec3 TissueModel::toWeb(const Vec3& p_device) const noexcept {
  return p_.orientation.conjugate() * (p_device - p_.origin_m);
}

Vec3 TissueModel::fromWeb(const Vec3& p_web) const noexcept {
  return p_.origin_m + p_.orientation * p_web;
}

Vec3 TissueModel::normalAxis() const noexcept { return p_.orientation * Vec3::UnitZ(); }

double TissueModel::depthOf(int finger, const Vec3& p_device) const noexcept {
  const Vec3 w = toWeb(p_device);
  const double surface = 0.5 * p_.thickness_m + p_.pad_radius_m;
  // Thumb on the dorsal surface (from +z), index on the palmar one (from −z).
  return finger == kThumb ? surface - w.z() : w.z() + surface;
}

double TissueModel::patchWeight(double x_m, double y_m) const noexcept {
  if (p_.patch_radius_m <= 0.0) return 0.0;
  const double r = std::hypot(x_m - p_.patch_x_m, y_m - p_.patch_y_m);
  const double half = 0.5 * p_.patch_rim_m;
  return 1.0 - smoothstep(p_.patch_radius_m - half, p_.patch_radius_m + half, r);
}

Vec3 TissueModel::patchGradient(double x_m, double y_m) const noexcept {
  if (p_.patch_radius_m <= 0.0) return Vec3::Zero();
  const double dx = x_m - p_.patch_x_m, dy = y_m - p_.patch_y_m;
  const double r = std::hypot(dx, dy);
  if (r <= 0.0) return Vec3::Zero();
  const double half = 0.5 * p_.patch_rim_m;
  const double s = -smoothstepSlope(p_.patch_radius_m - half, p_.patch_radius_m + half, r);
  return Vec3(s * dx / r, s * dy / r, 0.0);
}

double TissueModel::normalForceN(double depth_m, double depth_rate_m_s, double x_m,
                                 double y_m) const noexcept {
  if (!(depth_m > 0.0)) return 0.0;
  const double w = patchWeight(x_m, y_m);
  const double k = p_.stiffness_n_per_m_pow * (1.0 + w * (p_.patch_stiffness_factor - 1.0));
  const double elastic = k * std::pow(depth_m, p_.exponent);
  return std::max(elastic * (1.0 + p_.damping_s_per_m * depth_rate_m_s), 0.0);
}

double TissueModel::normalEnergyJ(double depth_m, double x_m, double y_m) const noexcept {
  if (!(depth_m > 0.0)) return 0.0;
  const double w = patchWeight(x_m, y_m);
  const double k = p_.stiffness_n_per_m_pow * (1.0 + w * (p_.patch_stiffness_factor - 1.0));
  return k * std::pow(depth_m, p_.exponent + 1.0) / (p_.exponent + 1.0);
}

double TissueModel::depthForForce(double force_n, double x_m, double y_m) const noexcept {
  if (!(force_n > 0.0)) return 0.0;
  const double w = patchWeight(x_m, y_m);
  const double k = p_.stiffness_n_per_m_pow * (1.0 + w * (p_.patch_stiffness_factor - 1.0));
  if (!(k > 0.0)) return 0.0;
  return std::pow(force_n / k, 1.0 / p_.exponent);
}

TissueContact tissueContact(const TissueModel& m, int finger, const Vec3& p_device,
                            const Vec3& v_device, TissueAnchor& anchor) noexcept {
  const TissueParams& p = m.params();
  TissueContact c;
  const Vec3 w = m.toWeb(p_device);
  const Vec3 v = p.orientation.conjugate() * v_device;
  const double depth = m.depthOf(finger, p_device);
  const bool over = std::abs(w.x()) <= p.half_extent_m && std::abs(w.y()) <= p.half_extent_m;
  c.point_w = Vec3(w.x(), w.y(), finger == kThumb ? 0.5 * p.thickness_m : -0.5 * p.thickness_m);
  if (!(depth > 0.0) || !over || !allFinite(w) || !allFinite(v)) {
    anchor.attached = false;
    return c;
  }
  // + pressing in: the thumb moves toward −z, the index toward +z.
  const double rate = finger == kThumb ? -v.z() : v.z();
  c.depth_m = depth;
  c.depth_rate_m_s = rate;
  const double fn = m.normalForceN(depth, rate, w.x(), w.y());
  const double side = finger == kThumb ? 1.0 : -1.0;  // the skin pushes the finger back out
  c.normal_n = p.orientation * Vec3(0.0, 0.0, side * fn);

  if (!anchor.attached) {
    anchor.x_m = w.x();
    anchor.y_m = w.y();
    anchor.attached = true;
  }
  const Vec3 rim = rimForce(m, depth, w);
  const double g = 1.0 + m.patchWeight(w.x(), w.y()) * (p.patch_friction_factor - 1.0);
  const double kt = p.lateral_stiffness_n_per_m;
  const double limit_static = p.mu_static * g * fn;
  const double limit_kinetic = p.mu_kinetic * g * fn;
  double sx = w.x() - anchor.x_m, sy = w.y() - anchor.y_m;
  const double stretch = std::hypot(sx, sy);
  c.sticking = true;
  if (kt * stretch > limit_static) {
    // Slip: the anchor follows to where the spring pulls with the kinetic limit.
    c.sticking = false;
    const double keep = kt > 0.0 && stretch > 0.0 ? limit_kinetic / (kt * stretch) : 0.0;
    sx *= keep;
    sy *= keep;
    anchor.x_m = w.x() - sx;
    anchor.y_m = w.y() - sy;
  }
  const Vec3 ft_w(-kt * sx - p.viscous_n_s_per_m * v.x() + rim.x(),
                  -kt * sy - p.viscous_n_s_per_m * v.y() + rim.y(), 0.0);
  c.tangential_n = p.orientation * ft_w;
  return c;
}

TissueProxy::TissueProxy(const TissueParams& initial, double force_scale, int64_t blend_ns) noexcept
    : current_(initial), previous_(initial), scale_(force_scale), blend_ns_(blend_ns) {}

void TissueProxy::setParams(const TissueParams& next, double force_scale) noexcept {
  scale_ = force_scale;
  if (next == current_.params()) return;
  previous_ = current_;
  current_ = TissueModel(next);
  blending_ = blend_ns_ > 0;
  fade_started_ = false;
}

void TissueProxy::reset() noexcept {
  anchor_ = {};
  have_last_ = false;
  v_ = {Vec3::Zero(), Vec3::Zero()};
}

TissueOutput TissueProxy::render(const PerFinger<Vec3>& p, int64_t t_ns) noexcept {
  if (have_last_ && t_ns > last_ns_) {
    const double dt = static_cast<double>(t_ns - last_ns_) * 1e-9;
    constexpr double kTau = 0.005;  // as the joint proxy's rates: encoder noise
    for (int k = 0; k < 2; ++k) v_[k] += (dt / (kTau + dt)) * ((p[k] - last_p_[k]) / dt - v_[k]);
  } else if (have_last_ && t_ns < last_ns_) {
    v_ = {Vec3::Zero(), Vec3::Zero()};
  }
  if (!have_last_ || t_ns != last_ns_) {
    have_last_ = true;
    last_ns_ = t_ns;
    last_p_ = p;
  }
  return renderWith(p, v_, t_ns);
}

TissueOutput TissueProxy::renderWith(const PerFinger<Vec3>& p, const PerFinger<Vec3>& v,
                                     int64_t t_ns) noexcept {
  TissueOutput out;
  double weight = 1.0;
  if (blending_) {
    if (!fade_started_) {
      fade_started_ = true;
      fade_start_ns_ = t_ns;
    }
    weight = std::clamp(static_cast<double>(t_ns - fade_start_ns_) / static_cast<double>(blend_ns_),
                        0.0, 1.0);
    if (weight >= 1.0) blending_ = false;
  }
  out.blending = blending_;
  for (int k = 0; k < 2; ++k) {
    // The previous set sees the same anchor (a copy: the current set advances it).
    TissueAnchor old_anchor = anchor_[k];
    TissueContact c = tissueContact(current_, k, p[k], v[k], anchor_[k]);
    if (weight < 1.0) {
      const TissueContact o = tissueContact(previous_, k, p[k], v[k], old_anchor);
      c.normal_n = weight * c.normal_n + (1.0 - weight) * o.normal_n;
      c.tangential_n = weight * c.tangential_n + (1.0 - weight) * o.tangential_n;
    }
    out.contact[k] = c;
    out.force_device_n[k] = c.force() * scale_;
    const TissueParams& tp = current_.params();
    const double stretch2 = anchor_[k].attached ? std::pow(c.point_w.x() - anchor_[k].x_m, 2) +
                                                      std::pow(c.point_w.y() - anchor_[k].y_m, 2)
                                                : 0.0;
    out.potential_j += scale_ * (current_.normalEnergyJ(c.depth_m, c.point_w.x(), c.point_w.y()) +
                                 0.5 * tp.lateral_stiffness_n_per_m * stretch2);
  }
  return out;
}

bool TissueProxy::resync(int finger, const Vec3& force_device_n) noexcept {
  if (finger != kThumb && finger != kIndex) return false;
  if (!have_last_ || blending_ || !allFinite(force_device_n)) return false;
  const auto k = static_cast<std::size_t>(finger);
  const TissueParams& p = current_.params();
  const double kt = p.lateral_stiffness_n_per_m;
  const Vec3 w = current_.toWeb(last_p_[k]);
  Vec3 v = p.orientation.conjugate() * v_[k];
  const double depth = current_.depthOf(finger, last_p_[k]);
  const bool over = std::abs(w.x()) <= p.half_extent_m && std::abs(w.y()) <= p.half_extent_m;
  if (!(depth > 0.0) || !over || !(kt > 0.0) || !allFinite(w) || !allFinite(v)) return false;
  const Vec3 f_w = p.orientation.conjugate() * force_device_n;
  // The depth rate, from the normal part: F_n = k·δ^n·(1 + λ·δ̇), within kMaxRateStepMps of
  // this proxy's own (+ pressing in: the thumb moves toward −z, the index toward +z).
  const double side = finger == kThumb ? 1.0 : -1.0;
  double rate = -side * v.z();
  const double elastic = current_.normalForceN(depth, 0.0, w.x(), w.y());
  const double claimed = side * f_w.z();
  if (p.damping_s_per_m > 0.0 && elastic > 0.0 && claimed > 0.0) {
    rate = std::clamp((claimed / elastic - 1.0) / p.damping_s_per_m, rate - kMaxRateStepMps,
                      rate + kMaxRateStepMps);
    v.z() = -side * rate;
  }
  // The stretch, from the tangential part as tissueContact() renders it:
  // F_t = -kt·s - b·v + rim, s the stretch from the anchor.
  const double fn = current_.normalForceN(depth, rate, w.x(), w.y());
  const Vec3 rim = rimForce(current_, depth, w);
  double sx = (-f_w.x() - p.viscous_n_s_per_m * v.x() + rim.x()) / kt;
  double sy = (-f_w.y() - p.viscous_n_s_per_m * v.y() + rim.y()) / kt;
  // Inside the static limit (by a hair, so that the next render at this sample sticks).
  const double g = 1.0 + current_.patchWeight(w.x(), w.y()) * (p.patch_friction_factor - 1.0);
  const double limit = (1.0 - 1e-9) * p.mu_static * g * fn / kt;
  const double stretch = std::hypot(sx, sy);
  if (!std::isfinite(stretch) || !allFinite(v)) return false;
  if (stretch > limit) {
    const double keep = stretch > 0.0 ? std::max(limit, 0.0) / stretch : 0.0;
    sx *= keep;
    sy *= keep;
  }
  anchor_[k] = {w.x() - sx, w.y() - sy, true};
  v_[k] = p.orientation * v;
  return true;
}

namespace {
constexpr double kProxyStateMagic = 7711.0;  // the first number of a saved proxy
constexpr std::size_t kParamsSize = 23;

void putParams(const TissueParams& p, std::vector<double>& out) {
  for (int i = 0; i < 3; ++i) out.push_back(p.origin_m[i]);
  out.insert(out.end(), {p.orientation.w(),
                         p.orientation.x(),
                         p.orientation.y(),
                         p.orientation.z(),
                         p.thickness_m,
                         p.pad_radius_m,
                         p.half_extent_m,
                         p.stiffness_n_per_m_pow,
                         p.exponent,
                         p.damping_s_per_m,
                         p.lateral_stiffness_n_per_m,
                         p.mu_static,
                         p.mu_kinetic,
                         p.viscous_n_s_per_m,
                         p.patch_x_m,
                         p.patch_y_m,
                         p.patch_radius_m,
                         p.patch_stiffness_factor,
                         p.patch_friction_factor,
                         p.patch_rim_m});
}

TissueParams getParams(const double* d) noexcept {
  TissueParams p;
  p.origin_m = Vec3(d[0], d[1], d[2]);
  p.orientation = Quat(d[3], d[4], d[5], d[6]);
  double* fields[] = {&p.thickness_m,
                      &p.pad_radius_m,
                      &p.half_extent_m,
                      &p.stiffness_n_per_m_pow,
                      &p.exponent,
                      &p.damping_s_per_m,
                      &p.lateral_stiffness_n_per_m,
                      &p.mu_static,
                      &p.mu_kinetic,
                      &p.viscous_n_s_per_m,
                      &p.patch_x_m,
                      &p.patch_y_m,
                      &p.patch_radius_m,
                      &p.patch_stiffness_factor,
                      &p.patch_friction_factor,
                      &p.patch_rim_m};
  for (std::size_t i = 0; i < std::size(fields); ++i) *fields[i] = d[7 + i];
  return p;
}

// A nanosecond time as two doubles that hold it exactly (a double holds 53 bits).
void putTime(int64_t t, std::vector<double>& out) {
  const auto u = static_cast<uint64_t>(t);
  out.push_back(static_cast<double>(static_cast<int32_t>(static_cast<uint32_t>(u >> 32))));
  out.push_back(static_cast<double>(u & 0xffffffffu));
}

bool getTime(const double* d, int64_t* t) noexcept {
  if (!(d[0] >= -2147483648.0 && d[0] <= 2147483647.0 && d[0] == std::floor(d[0]))) return false;
  if (!(d[1] >= 0.0 && d[1] <= 4294967295.0 && d[1] == std::floor(d[1]))) return false;
  const auto hi = static_cast<uint64_t>(static_cast<int64_t>(d[0]));
  *t = static_cast<int64_t>((hi << 32) | static_cast<uint64_t>(d[1]));
  return true;
}

bool isFlag(double x) noexcept { return x == 0.0 || x == 1.0; }
}  // namespace

void TissueProxy::saveState(std::vector<double>& out) const {
  out.push_back(kProxyStateMagic);
  for (const TissueAnchor& a : anchor_)
    out.insert(out.end(), {a.x_m, a.y_m, a.attached ? 1.0 : 0.0});
  out.push_back(have_last_ ? 1.0 : 0.0);
  putTime(last_ns_, out);
  for (const Vec3& p : last_p_) out.insert(out.end(), {p.x(), p.y(), p.z()});
  for (const Vec3& v : v_) out.insert(out.end(), {v.x(), v.y(), v.z()});
  out.push_back(blending_ ? 1.0 : 0.0);
  out.push_back(fade_started_ ? 1.0 : 0.0);
  putTime(fade_start_ns_, out);
  putParams(previous_.params(), out);
  putParams(current_.params(), out);
}

bool TissueProxy::restoreState(std::span<const double> s) noexcept {
  if (s.size() != kStateSize || s[0] != kProxyStateMagic) return false;
  // Every number finite; positions, anchors and flags within what a render can leave.
  for (double x : s) {
    if (!std::isfinite(x)) return false;
  }
  const double* d = s.data() + 1;
  PerFinger<TissueAnchor> anchor{};
  for (std::size_t k = 0; k < 2; ++k, d += 3) {
    if (std::abs(d[0]) > 2.0 * sample_bounds::kPositionM ||
        std::abs(d[1]) > 2.0 * sample_bounds::kPositionM || !isFlag(d[2])) {
      return false;
    }
    anchor[k] = {d[0], d[1], d[2] == 1.0};
  }
  if (!isFlag(d[0])) return false;
  const bool have_last = d[0] == 1.0;
  int64_t last_ns = 0;
  if (!getTime(d + 1, &last_ns)) return false;
  d += 3;
  PerFinger<Vec3> last_p, v;
  for (std::size_t k = 0; k < 2; ++k, d += 3) {
    last_p[k] = Vec3(d[0], d[1], d[2]);
    if (last_p[k].cwiseAbs().maxCoeff() > sample_bounds::kPositionM) return false;
  }
  for (std::size_t k = 0; k < 2; ++k, d += 3) v[k] = Vec3(d[0], d[1], d[2]);
  if (!isFlag(d[0]) || !isFlag(d[1])) return false;
  const bool blending = d[0] == 1.0, fade_started = d[1] == 1.0;
  int64_t fade_start_ns = 0;
  if (!getTime(d + 2, &fade_start_ns)) return false;
  d += 4;
  const TissueParams previous = getParams(d);
  const TissueParams saved = getParams(d + kParamsSize);
  if (invalidTissueParam(previous) != nullptr || invalidTissueParam(saved) != nullptr) return false;

  anchor_ = anchor;
  have_last_ = have_last;
  last_ns_ = last_ns;
  last_p_ = last_p;
  v_ = v;
  if (saved == current_.params()) {
    previous_ = TissueModel(previous);
    blending_ = blending && blend_ns_ > 0;
    fade_started_ = fade_started;
    fade_start_ns_ = fade_start_ns;
  } else {
    // Saved before the model changed: fade from the one it was saved under.
    previous_ = TissueModel(saved);
    blending_ = blend_ns_ > 0;
    fade_started_ = false;
    fade_start_ns_ = 0;
  }
  return true;
}

}  // namespace telehand
