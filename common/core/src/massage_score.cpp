#include "telehand/core/massage_score.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace telehand::technique {

namespace {

struct CircleFit {
  double cx = 0, cy = 0, radius = 0;
  bool ok = false;
};

/// Least-squares circle through the points of `parts` (Kasa): x^2 + y^2 = a x + b y + c.
CircleFit kasa(const std::vector<Vec3>& p, const std::vector<Stretch>& parts) {
  CircleFit f;
  std::size_t count = 0;
  for (const Stretch& r : parts) count += r.end - r.begin;
  if (count < 3) return f;
  // Centred on the points' mean, for conditioning.
  double mx = 0, my = 0;
  for (const Stretch& r : parts) {
    for (std::size_t i = r.begin; i < r.end; ++i) {
      mx += p[i].x();
      my += p[i].y();
    }
  }
  const double n = static_cast<double>(count);
  mx /= n;
  my /= n;
  Eigen::Matrix3d ata = Eigen::Matrix3d::Zero();
  Eigen::Vector3d atb = Eigen::Vector3d::Zero();
  for (const Stretch& r : parts) {
    for (std::size_t i = r.begin; i < r.end; ++i) {
      const double x = p[i].x() - mx, y = p[i].y() - my;
      const Eigen::Vector3d row(x, y, 1.0);
      ata += row * row.transpose();
      atb += row * (x * x + y * y);
    }
  }
  const Eigen::Vector3d sol = ata.ldlt().solve(atb);
  const double cx = 0.5 * sol[0], cy = 0.5 * sol[1];
  const double r2 = sol[2] + cx * cx + cy * cy;
  if (!std::isfinite(r2) || !(r2 > 0.0)) return f;
  f.cx = cx + mx;
  f.cy = cy + my;
  f.radius = std::sqrt(r2);
  f.ok = true;
  return f;
}

/// The angle of each point round (cx, cy), unwrapped, from index lo.
std::vector<double> unwrappedAngles(const std::vector<Vec3>& p, std::size_t lo, std::size_t hi,
                                    double cx, double cy) {
  std::vector<double> a;
  a.reserve(hi - lo);
  double prev = 0.0, acc = 0.0;
  for (std::size_t i = lo; i < hi; ++i) {
    const double v = std::atan2(p[i].y() - cy, p[i].x() - cx);
    if (i > lo) acc += std::remainder(v - prev, 2.0 * kPi);
    prev = v;
    a.push_back(acc);
  }
  return a;
}

/// Least-squares slope of y over x with an offset per part: the angle of each part of
/// `parts`, unwrapped on its own (angles[k] for parts[k]), over time x. Each part's sums are
/// taken about its own means and added.
double slope(const std::vector<double>& x, const std::vector<Stretch>& parts,
             const std::vector<std::vector<double>>& angles) {
  double sxy = 0, sxx = 0;
  for (std::size_t k = 0; k < parts.size(); ++k) {
    const std::vector<double>& y = angles[k];
    const std::size_t x0 = parts[k].begin, n = y.size();
    if (n < 2) continue;
    double mx = 0, my = 0;
    for (std::size_t i = 0; i < n; ++i) {
      mx += x[x0 + i];
      my += y[i];
    }
    mx /= static_cast<double>(n);
    my /= static_cast<double>(n);
    double part_xy = 0, part_xx = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const double dx = x[x0 + i] - mx;
      part_xy += dx * (y[i] - my);
      part_xx += dx * dx;
    }
    sxy += part_xy;
    sxx += part_xx;
  }
  return sxx > 0.0 ? sxy / sxx : 0.0;
}

std::size_t seriesLength(const MassageSeries& s) {
  std::size_t n = s.t_s.size();
  for (int k = 0; k < 2; ++k) {
    n = std::min(
        {n, s.position_m[k].size(), s.normal_ref_n[k].size(), s.tangential_ref_n[k].size()});
  }
  return n;
}

/// v, or 0 when it prints as zero at `decimals` (no "-0.0" in a line).
double tidy(double v, int decimals) {
  return std::abs(v) < 0.5 * std::pow(10.0, -decimals) ? 0.0 : v;
}

}  // namespace

MassageSeries massageSeriesFromSamples(std::span<const Sample> samples, double force_scale) {
  MassageSeries s;
  s.t_s.reserve(samples.size());
  for (int k = 0; k < 2; ++k) {
    s.position_m[k].reserve(samples.size());
    s.normal_ref_n[k].reserve(samples.size());
    s.tangential_ref_n[k].reserve(samples.size());
  }
  for (const Sample& x : samples) {
    double t = static_cast<double>(x.source_time_ns - samples.front().source_time_ns) * 1e-9;
    // A loop faster than its device records each device sample once a tick, with the same
    // time: it is taken once (spacing the copies 1 ms apart would stretch the trial's time).
    if (!s.t_s.empty() && t == s.t_s.back()) continue;
    if (!s.t_s.empty() && !(t > s.t_s.back())) t = s.t_s.back() + 1e-3;
    s.t_s.push_back(t);
    const PerFinger<Vec3> p = thimblePositions(x);
    for (int k = 0; k < 2; ++k) {
      s.position_m[k].push_back(p[k]);
      s.normal_ref_n[k].push_back(static_cast<double>(x.fingers[k].normal_n) / force_scale);
      s.tangential_ref_n[k].push_back(static_cast<double>(x.fingers[k].tangential_n) / force_scale);
    }
  }
  return s;
}

MassageFigures analyseMassage(const MassageSeries& s, const TissueParams& web, double band_min_n,
                              double band_max_n, double settle_s) {
  MassageFigures f;
  const std::size_t n = seriesLength(s);
  if (n < 2) return f;
  const double t0 = s.t_s.front();
  f.duration_s = s.t_s[n - 1] - t0;
  std::size_t i0 = 0;
  while (i0 < n && s.t_s[i0] - t0 < settle_s) ++i0;
  if (i0 >= n) return f;
  const double m = static_cast<double>(n - i0);

  // The press.
  double tangential = 0.0, normal = 0.0, var = 0.0;
  int in_band = 0, touching = 0;
  const double contact_n = std::max(0.5, 0.5 * band_min_n);
  for (int k = 0; k < 2; ++k) {
    double sum = 0.0;
    for (std::size_t i = i0; i < n; ++i) {
      const double v = s.normal_ref_n[k][i];
      sum += v;
      tangential += std::abs(s.tangential_ref_n[k][i]);
      in_band += v >= band_min_n && v <= band_max_n ? 1 : 0;
      touching += v >= contact_n ? 1 : 0;
    }
    const double mean = sum / m;
    double ss = 0.0;
    for (std::size_t i = i0; i < n; ++i)
      ss += (s.normal_ref_n[k][i] - mean) * (s.normal_ref_n[k][i] - mean);
    f.finger_normal_mean_n[k] = mean;
    f.finger_normal_sd_n[k] = std::sqrt(ss / m);
    normal += sum;
    var += ss / m;
  }
  f.normal_mean_n = 0.5 * (f.finger_normal_mean_n[kThumb] + f.finger_normal_mean_n[kIndex]);
  f.normal_sd_n = std::sqrt(0.5 * var);
  f.time_in_band = in_band / (2.0 * m);
  f.contact_share = touching / (2.0 * m);
  f.tangential_ratio = normal > 0.0 ? tangential / normal : 0.0;

  // The circle of the contact point, in the web frame.
  const TissueModel model(web);
  std::vector<Vec3> pw(n, Vec3::Zero());
  std::vector<double> t(n);
  for (std::size_t i = 0; i < n; ++i) {
    pw[i] = model.toWeb(0.5 * (s.position_m[kThumb][i] + s.position_m[kIndex][i]));
    t[i] = s.t_s[i] - t0;
  }
  // The stretches without a gap, from the settle on: nothing is taken across a gap.
  const std::vector<Stretch> all = stretchesOf(std::span<const double>(t));
  f.stretches = all.size();
  const std::vector<Stretch> judged = stretchesFrom(all, i0);
  double judged_s = 0.0;
  for (const Stretch& p : judged) judged_s += s.t_s[p.end - 1] - s.t_s[p.begin];
  f.judged_s = judged_s;
  const CircleFit first = kasa(pw, {{i0, n}});
  if (!first.ok) return f;
  // Each stretch's whole laps: from its first sample to the end of its last whole lap.
  std::vector<Stretch> laps;  // the whole laps' samples, per stretch that has one
  std::vector<double> laps_of(judged.size(), 0.0);  // each judged stretch's laps' time
  double whole = 0.0;
  for (std::size_t j = 0; j < judged.size(); ++j) {
    const Stretch& p = judged[j];
    const std::vector<double> a = unwrappedAngles(pw, p.begin, p.end, first.cx, first.cy);
    const double w = std::floor(std::abs(a.back()) / (2.0 * kPi));
    if (w < 1.0) continue;
    std::size_t i1 = p.begin;  // one past the end of the stretch's last whole lap
    while (i1 < p.end && std::abs(a[i1 - p.begin]) <= w * 2.0 * kPi) ++i1;
    laps.push_back({p.begin, i1});
    laps_of[j] = s.t_s[i1 - 1] - s.t_s[p.begin];
    whole += w;
  }
  if (whole < 1.0) return f;
  const CircleFit c = kasa(pw, laps);
  if (!c.ok) return f;
  double k = 0.0;
  double r_sum = 0.0;
  double sxx = 0, syy = 0, sxy = 0;
  for (const Stretch& p : laps) {
    k += static_cast<double>(p.end - p.begin);
    for (std::size_t i = p.begin; i < p.end; ++i) {
      const double dx = pw[i].x() - c.cx, dy = pw[i].y() - c.cy;
      r_sum += std::hypot(dx, dy);
      sxx += dx * dx;
      syy += dy * dy;
      sxy += dx * dy;
    }
  }
  if (!(r_sum / k >= kMinCircleRadiusM)) return f;
  std::vector<std::vector<double>> angles;
  for (const Stretch& p : laps) angles.push_back(unwrappedAngles(pw, p.begin, p.end, c.cx, c.cy));
  f.centre_w = Vec3(c.cx, c.cy, 0.0);
  f.laps = whole;
  f.frequency_hz = slope(t, laps, angles) / (2.0 * kPi);
  f.radius_m = r_sum / k;
  double r_var = 0.0;
  for (const Stretch& p : laps) {
    for (std::size_t i = p.begin; i < p.end; ++i) {
      const double d = std::hypot(pw[i].x() - c.cx, pw[i].y() - c.cy) - f.radius_m;
      r_var += d * d;
    }
  }
  f.radial_rms_m = std::sqrt(r_var / k);
  // The time circling: per stretch its whole laps and the lap under way at its end (one
  // mean lap period), at most the stretch's own time.
  double laps_s = 0.0;
  for (const double x : laps_of) laps_s += x;
  const double period_s = laps_s / std::max(whole, 1.0);
  double circling_s = 0.0;
  for (std::size_t j = 0; j < judged.size(); ++j) {
    const double stretch_s = s.t_s[judged[j].end - 1] - s.t_s[judged[j].begin];
    circling_s += std::min(stretch_s, laps_of[j] + period_s);
  }
  f.circling_share = judged_s > 0.0 ? std::min(1.0, circling_s / judged_s) : 0.0;
  // Eigenvalues of the 2x2 covariance.
  const double half_tr = 0.5 * (sxx + syy) / k;
  const double det_part = std::hypot(0.5 * (sxx - syy) / k, sxy / k);
  const double major = half_tr + det_part, minor = std::max(half_tr - det_part, 0.0);
  f.circularity = major > 0.0 ? std::sqrt(minor / major) : 0.0;
  return f;
}

MassageTargets deriveMassageTargets(const MassageSeries& demo, const TissueParams& web,
                                    double settle_s) {
  MassageTargets tg;
  const MassageFigures first = analyseMassage(demo, web, -1e300, 1e300, settle_s);
  const double half = std::max(2.0 * first.normal_sd_n, 1.0);
  tg.band_min_n = std::max(first.normal_mean_n - half, 0.0);  // a press is never below 0 N
  tg.band_max_n = first.normal_mean_n + half;
  const MassageFigures f = analyseMassage(demo, web, tg.band_min_n, tg.band_max_n, settle_s);
  tg.normal_mean_n = f.normal_mean_n;
  tg.normal_sd_n = f.normal_sd_n;
  tg.time_in_band = f.time_in_band;
  tg.tangential_ratio = f.tangential_ratio;
  tg.centre_w = f.centre_w;
  tg.radius_m = f.radius_m;
  tg.frequency_hz = f.frequency_hz;
  tg.circularity = f.circularity;
  tg.radial_rms_m = f.radial_rms_m;
  tg.laps = f.laps;
  return tg;
}

MassageScore scoreMassage(const MassageSeries& attempt, const MassageTargets& t,
                          const TissueParams& web, double settle_s) {
  MassageScore r;
  r.figures = analyseMassage(attempt, web, t.band_min_n, t.band_max_n, settle_s);
  const MassageFigures& f = r.figures;
  r.not_scored = whyNotJudged(std::span<const double>(attempt.t_s.data(), seriesLength(attempt)),
                              settle_s, 1.0 / std::max(std::abs(t.frequency_hz), 0.1), 0.0);
  if (!r.not_scored.empty() || !(f.laps >= 1.0)) return r;
  r.normal_error_n = f.normal_mean_n - t.normal_mean_n;
  r.spread_delta_n = f.normal_sd_n - t.normal_sd_n;
  r.frequency_error_hz = f.frequency_hz - t.frequency_hz;
  r.radius_ratio = t.radius_m > 0.0 ? f.radius_m / t.radius_m : 0.0;
  r.circularity_delta = f.circularity - t.circularity;
  r.tangential_ratio_error = f.tangential_ratio - t.tangential_ratio;
  r.centre_offset_m = (f.centre_w - t.centre_w).norm();

  r.overall = overallScore({
      {std::abs(r.normal_error_n), 1.0, 0.25},
      {std::max(0.0, r.spread_delta_n), 0.5, 0.10},
      {std::abs(r.frequency_error_hz), std::max(0.05, 0.1 * std::abs(t.frequency_hz)), 0.20},
      {std::abs(r.radius_ratio - 1.0), 0.15, 0.20},
      {std::max(0.0, -r.circularity_delta), 0.1, 0.10},
      {std::abs(r.tangential_ratio_error), 0.05, 0.10},
      {r.centre_offset_m, std::max(0.0005, 0.25 * t.radius_m), 0.05},
  });
  r.overall *= f.circling_share * f.contact_share;
  return r;
}

std::string massageSummaryLine(const MassageScore& s) {
  if (!s.not_scored.empty()) return "massage: not scored: " + s.not_scored;
  const MassageFigures& f = s.figures;
  char buf[320];
  std::snprintf(buf, sizeof buf,
                "massage: press %.1f N (%+.1f) sd %.1f N (%+.1f), %.2f Hz (%+.2f), radius %.1f "
                "mm (x%.2f), circularity %.2f (%+.2f), tangential %.2f (%+.2f), %.0f laps, "
                "score %.0f",
                f.normal_mean_n, tidy(s.normal_error_n, 1), f.normal_sd_n,
                tidy(s.spread_delta_n, 1), f.frequency_hz, tidy(s.frequency_error_hz, 2),
                f.radius_m * 1e3, s.radius_ratio, f.circularity, tidy(s.circularity_delta, 2),
                f.tangential_ratio, tidy(s.tangential_ratio_error, 2), f.laps, s.overall);
  std::string line = buf;
  if (f.laps >= 1.0 && (f.circling_share < 0.995 || f.contact_share < 0.995)) {
    // Why the score is lower than its terms: part of the trial was not the technique.
    std::snprintf(buf, sizeof buf, " (circling %.0f %% of the time, on the web %.0f %%)",
                  100.0 * f.circling_share, 100.0 * f.contact_share);
    line += buf;
  }
  return line;
}

}  // namespace telehand::technique
