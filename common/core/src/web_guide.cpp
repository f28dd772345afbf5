#include "telehand/core/web_guide.h"

#include <algorithm>
#include <cmath>

namespace telehand {

void WebGuide::set(const GuideParams& g, int64_t t_ns) noexcept {
  if (g == current_) return;
  previous_ = current_;
  previous_start_ns_ = start_ns_;
  current_ = g;
  start_ns_ = t_ns;
  adopted_ns_ = t_ns;
  fading_ = previous_.active();
}

void WebGuide::target(const GuideParams& g, double t_s, Vec3& point, Vec3& velocity) noexcept {
  constexpr int n = GuideParams::kPoints;
  double u = std::fmod(t_s / g.period_s, 1.0);
  if (u < 0.0) u += 1.0;
  const double x = u * n;
  const int i = std::min(static_cast<int>(x), n - 1);
  const int j = (i + 1) % n;
  const double f = x - i;
  const Vec3& a = g.path_rad[static_cast<std::size_t>(i)];
  const Vec3& b = g.path_rad[static_cast<std::size_t>(j)];
  point = Vec3(a.x() + f * (b.x() - a.x()), a.y() + f * (b.y() - a.y()), 0.0);
  velocity = Vec3((b.x() - a.x()) * n / g.period_s, (b.y() - a.y()) * n / g.period_s, 0.0);
}

namespace {

/// One guide's force on the contact point, web frame, reference scale.
Vec3 springW(const GuideParams& g, double t_s, const Vec3& mid_w, const Vec3& v_w) noexcept {
  if (!g.active()) return Vec3::Zero();
  Vec3 point, velocity;
  WebGuide::target(g, t_s, point, velocity);
  const double k = g.stiffness_n_per_deg * 1000.0;  // N/mm -> N/m
  Vec3 f = Vec3::Zero();
  for (int a = 0; a < 2; ++a) {
    const double spring =
        k * (point[a] - mid_w[a]) + k * GuideParams::kDampingS * (velocity[a] - v_w[a]);
    f[a] = g.authority * std::clamp(spring, -g.max_force_n, g.max_force_n);
  }
  return f;
}

}  // namespace

PerFinger<Vec3> WebGuide::force(const TissueModel& web, const PerFinger<Vec3>& p_device,
                                const PerFinger<Vec3>& v_device, int64_t t_ns,
                                double force_scale) const noexcept {
  PerFinger<Vec3> out{Vec3::Zero(), Vec3::Zero()};
  last_ref_n_ = 0.0;
  if (!current_.active() && !fading_) return out;
  const Quat& q = web.params().orientation;
  const Vec3 mid_w = web.toWeb(0.5 * (p_device[kThumb] + p_device[kIndex]));
  const Vec3 v_w = q.conjugate() * (0.5 * (v_device[kThumb] + v_device[kIndex]));
  auto seconds = [&](int64_t from) { return static_cast<double>(t_ns - from) * 1e-9; };
  Vec3 f_w = springW(current_, seconds(start_ns_), mid_w, v_w);
  const double w = std::clamp(static_cast<double>(t_ns - adopted_ns_) / kFadeNs, 0.0, 1.0);
  if (fading_ && w < 1.0) {
    f_w = w * f_w + (1.0 - w) * springW(previous_, seconds(previous_start_ns_), mid_w, v_w);
  } else if (!current_.active()) {
    return out;
  }
  if (!std::isfinite(f_w.x()) || !std::isfinite(f_w.y())) return out;
  last_ref_n_ = f_w.norm();
  // Shared by the two fingers: half on each moves the contact point with the whole force.
  const Vec3 half = 0.5 * force_scale * (q * f_w);
  out[kThumb] = half;
  out[kIndex] = half;
  return out;
}

}  // namespace telehand
