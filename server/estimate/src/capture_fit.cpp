#include "telehand/server/estimate/capture_fit.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>

#include "telehand/core/thimble.h"

namespace telehand::server::estimate {

std::optional<CapturePoint> capturePoint(const JointModel& geometry, const Sample& s, bool valid,
                                         CaptureCounts& counts) {
  if (!valid) {
    ++counts.invalid;
    return std::nullopt;
  }
  if ((s.flags >> sample_flags::kFsrFaultShift) & 0xFFu) {
    ++counts.fsr_fault;
    return std::nullopt;
  }
  if (!(s.flags & sample_flags::kCapture)) {
    // With the actuators on, the thimbles measure the user against the rendered model, not
    // a real joint.
    ++counts.not_capture;
    return std::nullopt;
  }
  CapturePoint c;
  c.seq = s.seq;
  c.t_ns = s.source_time_ns;
  const PerFinger<Vec3> p = thimblePositions(s);
  c.angles_rad = geometry.anglesFromGrip(p);
  PerFinger<Vec3> f;
  for (int k = 0; k < 2; ++k) {
    const auto& fi = s.fingers[k];
    const Quat q(fi.orientation_q[0], fi.orientation_q[1], fi.orientation_q[2],
                 fi.orientation_q[3]);
    f[k] = thimbleForceVector({fi.tangential_n, fi.normal_n}, q.normalized());
  }
  c.axis_force_n = geometry.axisTorque(p, c.angles_rad, f) / geometry.params().lever_arm_m;
  if (!allFinite(c.angles_rad) || !allFinite(c.axis_force_n)) {
    ++counts.invalid;
    return std::nullopt;
  }
  ++counts.used;
  return c;
}

JointModelParams captureGeometry(const JointModelParams& joint) {
  JointModelParams g = joint;
  g.force_scale = 1.0;
  g.knn = nullptr;
  return g;
}

CaptureFitter::CaptureFitter(const JointModelParams& geometry, const FitOptions& options)
    : geometry_(geometry), options_(options) {}

bool CaptureFitter::add(const Sample& s, bool valid) {
  auto c = capturePoint(geometry_, s, valid, counts_);
  if (!c) return false;
  if (!points_.empty() && c->seq <= points_.back().seq) {
    // Out of order (a retried chunk): keep the list sorted, drop duplicates.
    auto it = std::lower_bound(points_.begin(), points_.end(), c->seq,
                               [](const CapturePoint& a, uint64_t seq) { return a.seq < seq; });
    if (it != points_.end() && it->seq == c->seq) return false;
    points_.insert(it, *c);
    return true;
  }
  points_.push_back(*c);
  return true;
}

std::vector<Vec3> CaptureFitter::rates() const {
  const std::size_t n = points_.size();
  std::vector<Vec3> out(n, Vec3::Zero());
  const auto h = static_cast<std::size_t>(std::max(options_.rate_half_window, 1));
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t lo = i >= h ? i - h : 0;
    const std::size_t hi = std::min(i + h, n - 1);
    if (hi == lo) continue;
    const double dt = static_cast<double>(points_[hi].t_ns - points_[lo].t_ns) * 1e-9;
    // Across a gap (samples left out) the difference would not be a rate.
    if (!(dt > 0.0) || dt > 3e-3 * static_cast<double>(hi - lo)) continue;
    out[i] = (points_[hi].angles_rad - points_[lo].angles_rad) / dt;
  }
  return out;
}

namespace {

/// The band around rest where the curve stays within ±threshold.
void neutralZone(const CubicCurve& c, double threshold, double& lo, double& hi) {
  // Rest: the zero crossing in range, else the range end nearest to zero force.
  double rest = std::abs(c.eval(c.min_deg)) < std::abs(c.eval(c.max_deg)) ? c.min_deg : c.max_deg;
  constexpr double kStep = 0.05;
  for (double a = c.min_deg; a + kStep <= c.max_deg; a += kStep) {
    if ((c.eval(a) <= 0.0) != (c.eval(a + kStep) <= 0.0)) {
      rest = a + kStep * c.eval(a) / (c.eval(a) - c.eval(a + kStep));
      break;
    }
  }
  lo = hi = rest;
  if (std::abs(c.eval(rest)) > threshold) return;
  while (lo - kStep >= c.min_deg && std::abs(c.eval(lo - kStep)) <= threshold) lo -= kStep;
  while (hi + kStep <= c.max_deg && std::abs(c.eval(hi + kStep)) <= threshold) hi += kStep;
}

}  // namespace

CaptureFit CaptureFitter::fit(const std::function<void(int, double)>& progress) const {
  CaptureFit out;
  out.counts = counts_;
  const std::vector<Vec3> rate = rates();
  const std::size_t n = points_.size();
  std::vector<double> x(n), y(n), v(n);
  for (int axis = 0; axis < kAxes; ++axis) {
    if (progress) progress(axis, 0.0);
    for (std::size_t i = 0; i < n; ++i) {
      x[i] = radToDeg(points_[i].angles_rad[axis]);
      y[i] = points_[i].axis_force_n[axis];
      v[i] = rate[i][axis];
    }
    AxisFit& a = out.axes[static_cast<std::size_t>(axis)];
    a.samples = n;
    if (n < options_.min_samples) continue;
    const auto [lo, hi] = std::minmax_element(x.begin(), x.end());
    if (*hi - *lo < options_.min_span_deg) continue;
    const CubicFitResult r = fitCubic(x, y, v);
    if (progress) progress(axis, 1.0);
    if (!r.ok) continue;
    a.ok = true;
    a.curve.coeffs = r.coeffs;
    a.curve.min_deg = r.x_min;
    a.curve.max_deg = r.x_max;
    a.rms_n = r.rms;
    // F = ... + d * rate at the lever arm: torque d * lever per rad/s.
    a.damping_nms_per_rad = r.extra * geometry_.params().lever_arm_m;
    neutralZone(a.curve, options_.neutral_force_n, a.neutral_min_deg, a.neutral_max_deg);
  }
  return out;
}

JointModelParams CaptureFit::model(const JointModelParams& base) const {
  JointModelParams p = base;
  double damping = 0.0;
  int fitted = 0;
  for (std::size_t i = 0; i < kAxes; ++i) {
    if (!axes[i].ok) continue;
    p.axes[i] = axes[i].curve;
    p.neutral_zone_deg[i] = 0.0;  // the cubic carries the lax zone itself
    damping += axes[i].damping_nms_per_rad;
    ++fitted;
  }
  if (fitted > 0) p.damping_nms_per_rad = std::clamp(damping / fitted, 0.0, 0.5);
  p.speed_gain_s_per_rad = 0.0;
  return p;
}

std::string patientCaseToml(const CaptureFit& fit, const JointModelParams& model,
                            const std::string& name, const std::string& description,
                            const std::string& source) {
  std::ostringstream o;
  char buf[256];
  o << "# Fitted from a capture (telehand-records fit): per axis, a least-squares cubic of the\n"
       "# force (N) at the lever arm against the angle (deg), over the range reached.\n";
  o << "[case]\n";
  o << "name = \"" << name << "\"\n";
  o << "description = \"" << description << "\"\n";
  o << "source = \"" << source << "\"\n";
  std::snprintf(buf, sizeof buf, "damping_nms_per_rad = %.6g\n", model.damping_nms_per_rad);
  o << buf << "speed_gain_s_per_rad = 0.0\n";
  for (std::size_t i = 0; i < kAxes; ++i) {
    const AxisFit& a = fit.axes[i];
    const CubicCurve& c = model.axes[i];
    o << "\n[" << kAxisNames[i] << "]";
    if (a.ok) {
      std::snprintf(
          buf, sizeof buf,
          "   # RMS residual %.3f N over %zu samples; lax zone (|F| < 1 N) %.1f..%.1f deg", a.rms_n,
          a.samples, a.neutral_min_deg, a.neutral_max_deg);
      o << buf;
    } else {
      o << "   # not fitted (too few samples or too small a range): the base model's curve";
    }
    std::snprintf(buf, sizeof buf, "\ncoeffs = [%.9g, %.9g, %.9g, %.9g]\n", c.coeffs[0],
                  c.coeffs[1], c.coeffs[2], c.coeffs[3]);
    o << buf;
    std::snprintf(buf, sizeof buf, "min_deg = %.3f\nmax_deg = %.3f\nneutral_zone_deg = %.3f\n",
                  c.min_deg, c.max_deg, model.neutral_zone_deg[i]);
    o << buf;
  }
  o << "\n";
  return o.str();
}

}  // namespace telehand::server::estimate
