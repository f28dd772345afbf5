#include "telehand/core/fit.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>

namespace telehand {

std::array<double, 4> expandScaledCubic(const std::array<double, 4>& b, double m,
                                        double s) noexcept {
  // p(t) = b0 + b1 t + b2 t^2 + b3 t^3 with t = (x - m) / s = u x + v.
  const double u = 1.0 / s, v = -m / s;
  // t^k expanded in x (low power first).
  const double t1[2] = {v, u};
  const double t2[3] = {v * v, 2 * u * v, u * u};
  const double t3[4] = {v * v * v, 3 * u * v * v, 3 * u * u * v, u * u * u};
  double c[4] = {b[0], 0, 0, 0};
  for (int i = 0; i < 2; ++i) c[i] += b[1] * t1[i];
  for (int i = 0; i < 3; ++i) c[i] += b[2] * t2[i];
  for (int i = 0; i < 4; ++i) c[i] += b[3] * t3[i];
  return {c[3], c[2], c[1], c[0]};
}

CubicFitResult fitCubic(std::span<const double> x, std::span<const double> y,
                        std::span<const double> extra) {
  CubicFitResult r;
  const std::size_t n = std::min(x.size(), y.size());
  const bool with_extra = !extra.empty() && extra.size() >= n;
  const int cols = with_extra ? 5 : 4;
  r.n = n;
  if (n < static_cast<std::size_t>(cols) + 1) return r;
  const auto [lo, hi] = std::minmax_element(x.begin(), x.begin() + static_cast<std::ptrdiff_t>(n));
  r.x_min = *lo;
  r.x_max = *hi;
  const double centre = 0.5 * (r.x_min + r.x_max);
  const double scale = 0.5 * (r.x_max - r.x_min);
  if (!(scale > 0.0) || !std::isfinite(scale)) return r;
  double extra_scale = 1.0;
  if (with_extra) {
    double m = 0.0;
    for (std::size_t i = 0; i < n; ++i) m = std::max(m, std::abs(extra[i]));
    extra_scale = m > 0.0 ? m : 1.0;
  }
  Eigen::MatrixXd a(static_cast<Eigen::Index>(n), cols);
  Eigen::VectorXd b(static_cast<Eigen::Index>(n));
  for (std::size_t i = 0; i < n; ++i) {
    const auto row = static_cast<Eigen::Index>(i);
    const double t = (x[i] - centre) / scale;  // in [-1, 1]
    a(row, 0) = 1.0;
    a(row, 1) = t;
    a(row, 2) = t * t;
    a(row, 3) = t * t * t;
    if (with_extra) a(row, 4) = extra[i] / extra_scale;
    b(row) = y[i];
  }
  const Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(a);
  if (qr.rank() < cols) return r;
  const Eigen::VectorXd sol = qr.solve(b);
  if (!sol.allFinite()) return r;
  r.coeffs = expandScaledCubic({sol(0), sol(1), sol(2), sol(3)}, centre, scale);
  r.extra = with_extra ? sol(4) / extra_scale : 0.0;
  const Eigen::VectorXd res = a * sol - b;
  r.rms = std::sqrt(res.squaredNorm() / static_cast<double>(n));
  r.ok = true;
  return r;
}

}  // namespace telehand

namespace telehand {

double PiecewiseCubic::eval(double x) const noexcept {
  const double in = std::clamp(x, min_deg, max_deg);
  double s = in;
  if (zone_deg > 0.0) {
    const double off = in - rest_deg;
    s = std::abs(off) <= zone_deg ? rest_deg : in - std::copysign(zone_deg, off);
  }
  const double excess = x - in;
  if (excess == 0.0) return poly(s);
  return poly(s) + (polySlope(s) + wall_n_per_deg) * excess;
}

namespace {

constexpr int kMaxCols = 8;

/// Samples pooled per angle bin: what every trial of the nonlinear parameters needs.
struct Pooled {
  int m = 0;                           // extra regressors
  std::vector<double> x, cnt, sy, se;  // se: m per bin
  double ee[kMaxCols][kMaxCols] = {};
  double ey[kMaxCols] = {};
  double yy = 0.0;
  double n = 0.0;
  double centre = 0.0, scale = 1.0;  // of the polynomial's variable
};

struct Shape {
  double lo = 0.0, hi = 0.0, zone = 0.0, rest = 0.0;
};

struct Trial {
  bool ok = false;
  double rss = 1e300;
  int p = 4;  // polynomial columns
  std::array<double, kMaxCols> theta{};
  std::array<double, kMaxCols> var{};  // diagonal of the inverse normal matrix
};

/// The normal equations' bin sums for a trial: P polynomial columns (3 with a zone, else 4)
/// and M extra regressors (M < 0: d.m, not known at compile time). Known sizes let the
/// compiler keep the sums in registers (the shape searches spend most of a capture fit
/// here); the arithmetic and its order are the same for every instantiation.
template <int P, int M>
void accumulateBins(const Pooled& d, const Shape& sh, double wall, double (&mm)[kMaxCols][kMaxCols],
                    double (&rhs)[kMaxCols], double& yy_out) {
  // Fills mm's first P rows, rhs and yy_out, from the extra regressors' own sums in d.
  constexpr bool zone = P == 3;
  const int m = M < 0 ? d.m : M;
  const auto ms = static_cast<std::size_t>(m);
  double acc[P][P + (M < 0 ? kMaxCols - P : M)] = {};
  double r[P + (M < 0 ? kMaxCols - P : M)] = {};
  for (int j = 0; j < m; ++j) r[P + j] = d.ey[j];
  double yy = d.yy;
  const double tr = (sh.rest - d.centre) / d.scale;
  const double tr2 = tr * tr, tr3 = tr2 * tr;
  const std::size_t nb = d.x.size();
  for (std::size_t b = 0; b < nb; ++b) {
    const double x = d.x[b], c = d.cnt[b];
    const double in = std::clamp(x, sh.lo, sh.hi);
    double s = in;
    if constexpr (zone) {
      const double off = in - sh.rest;
      s = std::abs(off) <= sh.zone ? sh.rest : in - std::copysign(sh.zone, off);
    }
    const double e = x - in;
    const double u = (s - d.centre) / d.scale, u2 = u * u;
    const double de = e / d.scale;  // d(u)/d(x) times the excess
    double phi[P];
    if constexpr (zone) {
      phi[0] = u - tr + de;
      phi[1] = u2 - tr2 + 2.0 * u * de;
      phi[2] = u2 * u - tr3 + 3.0 * u2 * de;
    } else {
      phi[0] = 1.0;
      phi[1] = u + de;
      phi[2] = u2 + 2.0 * u * de;
      phi[3] = u2 * u + 3.0 * u2 * de;
    }
    const double* se = d.se.data() + b * ms;
    double sy = d.sy[b];
    if (e != 0.0) {
      // The wall's own stiffness is known: it moves to the left-hand side.
      yy += -2.0 * wall * e * sy + wall * wall * e * e * c;
      sy -= wall * e * c;
      for (int j = 0; j < m; ++j) r[P + j] -= wall * e * se[j];
    }
#pragma GCC unroll 4
    for (int i = 0; i < P; ++i) {
      r[i] += phi[i] * sy;
#pragma GCC unroll 4
      for (int j = i; j < P; ++j) acc[i][j] += c * phi[i] * phi[j];
#pragma GCC unroll 4
      for (int j = 0; j < m; ++j) acc[i][P + j] += phi[i] * se[j];
    }
  }
  for (int i = 0; i < P; ++i) {
    rhs[i] = r[i];
    for (int j = i; j < P + m; ++j) mm[i][j] = acc[i][j];
  }
  for (int j = 0; j < m; ++j) rhs[P + j] = r[P + j];
  yy_out = yy;
}

template <int P>
void accumulateBins(const Pooled& d, const Shape& sh, double wall, double (&mm)[kMaxCols][kMaxCols],
                    double (&rhs)[kMaxCols], double& yy) {
  switch (d.m) {
    case 1:
      return accumulateBins<P, 1>(d, sh, wall, mm, rhs, yy);
    case 2:
      return accumulateBins<P, 2>(d, sh, wall, mm, rhs, yy);
    case 3:
      return accumulateBins<P, 3>(d, sh, wall, mm, rhs, yy);
    default:
      return accumulateBins<P, -1>(d, sh, wall, mm, rhs, yy);
  }
}

Trial solve(const Pooled& d, const Shape& sh, double wall) {
  Trial t;
  const bool zone = sh.zone > 0.0;
  t.p = zone ? 3 : 4;
  const int p = t.p, k = p + d.m;
  double mm[kMaxCols][kMaxCols] = {};
  double rhs[kMaxCols] = {};
  double yy = 0.0;
  if (zone) {
    accumulateBins<3>(d, sh, wall, mm, rhs, yy);
  } else {
    accumulateBins<4>(d, sh, wall, mm, rhs, yy);
  }
  for (int i = 0; i < d.m; ++i)
    for (int j = i; j < d.m; ++j) mm[p + i][p + j] = d.ee[i][j];
  Eigen::MatrixXd a(k, k);
  Eigen::VectorXd r(k), dg(k);
  for (int i = 0; i < k; ++i) dg(i) = mm[i][i] > 0.0 ? 1.0 / std::sqrt(mm[i][i]) : 1.0;
  for (int i = 0; i < k; ++i) {
    r(i) = rhs[i] * dg(i);
    for (int j = i; j < k; ++j) a(i, j) = a(j, i) = mm[i][j] * dg(i) * dg(j);
  }
  // A trial whose normal matrix is nearly singular is no trial: its residual, yy less the
  // fitted part, loses about κ·ε of yy, and at κ of 1e15 the loss is larger than the residual
  // itself. Such shapes exist: a zone that reaches both walls leaves the cubic held by a
  // sliver of samples (random patient 199 at 6 Hz, seed 10, 15 s an axis: a 24° zone between
  // walls at its edges, its residual read as 0.96 N RMS for 2.13 N, flexion 3,369 N off). At a
  // pivot ratio of 1e-10 (κ about 1e10) the loss is about 1e-6 of yy, a few N² against a
  // penalty of tens.
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(a.rows(), a.cols());
  qr.setThreshold(1e-10);
  qr.compute(a);
  if (qr.rank() < k) return t;
  const Eigen::VectorXd sol = qr.solve(r);
  if (!sol.allFinite()) return t;
  const Eigen::MatrixXd inv = qr.inverse();
  double fit_dot = 0.0;
  for (int i = 0; i < k; ++i) {
    t.theta[static_cast<std::size_t>(i)] = sol(i) * dg(i);
    t.var[static_cast<std::size_t>(i)] = inv(i, i) * dg(i) * dg(i);
    fit_dot += t.theta[static_cast<std::size_t>(i)] * rhs[i];
  }
  t.rss = std::max(yy - fit_dot, 0.0);
  t.ok = true;
  return t;
}

/// P's coefficients (highest power first, in x) from a trial.
std::array<double, 4> polyOf(const Pooled& d, const Shape& sh, const Trial& t) {
  std::array<double, 4> b{};
  if (t.p == 3) {
    const double tr = (sh.rest - d.centre) / d.scale;
    b = {-(t.theta[0] * tr + t.theta[1] * tr * tr + t.theta[2] * tr * tr * tr), t.theta[0],
         t.theta[1], t.theta[2]};
  } else {
    b = {t.theta[0], t.theta[1], t.theta[2], t.theta[3]};
  }
  return expandScaledCubic(b, d.centre, d.scale);
}

/// P's zero in [lo, hi] (the rest angle), by a scan and bisection; NaN if none.
double rootIn(const std::array<double, 4>& c, double lo, double hi) {
  auto f = [&](double x) { return ((c[0] * x + c[1]) * x + c[2]) * x + c[3]; };
  constexpr double kStep = 0.25;
  for (double a = lo; a < hi; a += kStep) {
    double l = a, h = std::min(a + kStep, hi);
    if ((f(l) <= 0.0) == (f(h) <= 0.0)) continue;
    for (int i = 0; i < 50; ++i) {
      const double m = 0.5 * (l + h);
      ((f(m) <= 0.0) == (f(l) <= 0.0) ? l : h) = m;
    }
    return 0.5 * (l + h);
  }
  return std::nan("");
}

}  // namespace

PiecewiseFitResult fitPiecewiseCubic(std::span<const double> x, std::span<const double> y,
                                     std::span<const std::span<const double>> extras,
                                     const PiecewiseFitOptions& o) {
  PiecewiseFitResult out;
  const std::size_t n = std::min(x.size(), y.size());
  out.n = n;
  Pooled d;
  d.m = static_cast<int>(std::min<std::size_t>(extras.size(), kMaxCols - 4));
  for (int j = 0; j < d.m; ++j) {
    if (extras[static_cast<std::size_t>(j)].size() < n) return out;
  }
  if (n < 10) return out;
  const auto [lo_it, hi_it] =
      std::minmax_element(x.begin(), x.begin() + static_cast<std::ptrdiff_t>(n));
  const double x0 = *lo_it, x1 = *hi_it;
  out.x_min = x0;
  out.x_max = x1;
  if (!(x1 > x0) || !std::isfinite(x1 - x0)) return out;
  d.centre = 0.5 * (x0 + x1);
  d.scale = 0.5 * (x1 - x0);
  const double bin = o.bin_deg > 0.0 ? o.bin_deg : 0.05;
  const auto nbins = static_cast<std::size_t>((x1 - x0) / bin) + 1;
  std::vector<double> sx(nbins, 0.0), cnt(nbins, 0.0), sy(nbins, 0.0),
      se(nbins * static_cast<std::size_t>(d.m), 0.0);
  const auto m = static_cast<std::size_t>(d.m);
  // With a curve scale s_i, a bin's curve column is s_i · φ(x_bin): the bin pools Σ s²
  // (as the count), Σ s·y and Σ s·extra.
  const bool scaled = o.curve_scale.size() >= n;
  std::vector<double> nx(nbins, 0.0);
  for (std::size_t i = 0; i < n; ++i) {
    const auto b = std::min(static_cast<std::size_t>((x[i] - x0) / bin), nbins - 1);
    const double sc = scaled ? o.curve_scale[i] : 1.0;
    sx[b] += x[i];
    nx[b] += 1.0;
    cnt[b] += sc * sc;
    sy[b] += sc * y[i];
    d.yy += y[i] * y[i];
    for (std::size_t j = 0; j < m; ++j) {
      const double ej = extras[j][i];
      se[b * m + j] += sc * ej;
      d.ey[j] += ej * y[i];
      for (std::size_t l = j; l < m; ++l) d.ee[j][l] += ej * extras[l][i];
    }
  }
  d.n = static_cast<double>(n);
  for (std::size_t b = 0; b < nbins; ++b) {
    if (nx[b] == 0.0) continue;
    d.x.push_back(sx[b] / nx[b]);
    d.cnt.push_back(cnt[b]);
    d.sy.push_back(sy[b]);
    for (std::size_t j = 0; j < m; ++j) d.se.push_back(se[b * m + j]);
  }
  if (d.x.size() < 5) return out;

  const double wall = o.wall_n_per_deg;
  Shape best{x0, x1, 0.0, 0.0};
  if (o.fixed_shape) {
    const PiecewiseCubic& f = *o.fixed_shape;
    best = Shape{f.min_deg, f.max_deg, f.zone_deg, f.rest_deg};
  }
  Trial bt = solve(d, best, wall);
  if (!bt.ok) return out;
  const double span = x1 - x0;
  // Try each candidate for one parameter, keep the best; then refine around it.
  auto search = [&](double Shape::*param, double from, double to, double step) {
    auto tryAt = [&](double v) {
      Shape s = best;
      s.*param = v;
      if (s.hi <= s.lo || s.zone < 0.0) return;
      if (s.zone > 0.0 && (s.rest - s.zone < s.lo || s.rest + s.zone > s.hi)) return;
      const Trial t = solve(d, s, wall);
      if (t.ok && t.rss < bt.rss) {
        bt = t;
        best = s;
      }
    };
    for (double v = from; v <= to + 1e-9; v += step) tryAt(v);
    const double c = best.*param;
    for (double v = c - step; v <= c + step + 1e-9; v += step / 10.0) tryAt(v);
  };
  auto descend = [&]() {
    for (int round = 0; round < 3 && !o.fixed_shape; ++round) {
      const Shape before = best;
      if (o.find_walls) {
        search(&Shape::hi, x1 - 0.4 * span, x1, 0.25);
        search(&Shape::lo, x0, x0 + 0.4 * span, 0.25);
      }
      if (o.find_zone) {
        if (best.zone <= 0.0) {
          const double r = rootIn(polyOf(d, best, bt), best.lo, best.hi);
          if (std::isnan(r)) break;
          best.rest = r;
        }
        search(&Shape::zone, 0.0, std::min(0.3 * span, 30.0), 0.25);
        if (best.zone > 0.0) search(&Shape::rest, best.rest - 3.0, best.rest + 3.0, 0.1);
      }
      if (best.lo == before.lo && best.hi == before.hi && best.zone == before.zone &&
          best.rest == before.rest)
        break;
    }
  };
  // Coordinate descent, then both walls at once on a coarse grid near the ends (with the
  // zone found): where the cubic's end slopes are steep, one wall alone may not pay while
  // the pair does, and a search of one at a time does not find them; if the pair does
  // better, descend again from there.
  auto searchShape = [&]() {
    descend();
    if (!o.find_walls || o.fixed_shape) return;
    const double reach = std::min(0.4 * span, 10.0);
    const Shape start = best;
    const double rss_before = bt.rss;
    for (double lo = x0; lo <= x0 + reach + 1e-9; lo += 1.0) {
      for (double hi = x1 - reach; hi <= x1 + 1e-9; hi += 1.0) {
        Shape sh = start;
        sh.lo = lo;
        sh.hi = hi;
        if (sh.hi <= sh.lo) continue;
        if (sh.zone > 0.0 && (sh.rest - sh.zone < sh.lo || sh.rest + sh.zone > sh.hi)) continue;
        const Trial t = solve(d, sh, wall);
        if (t.ok && t.rss < bt.rss) {
          bt = t;
          best = sh;
        }
      }
    }
    if (bt.rss < rss_before) descend();
  };
  searchShape();
  if (o.find_walls && o.find_zone && !o.fixed_shape && o.zone_first_start) {
    // A second start, the zone searched first (no walls yet): searched walls first, a zone
    // the walls' search has not seen yet can leave a wall far inside the range, bending the
    // cubic to make up for the zone, and the zone then no longer pays (random patient 24's
    // axial axis at 1 Hz, seed 3: a wall found at 5.6 deg for 10.7, the lower one and the
    // 3.9 deg zone missed, 1.04 N off). The better of the two is kept.
    const Shape first = best;
    const Trial first_t = bt;
    best = Shape{x0, x1, 0.0, 0.0};
    bt = solve(d, best, wall);
    const double r = bt.ok ? rootIn(polyOf(d, best, bt), x0, x1) : std::nan("");
    if (!std::isnan(r)) {
      best.rest = r;
      search(&Shape::zone, 0.0, std::min(0.3 * span, 30.0), 0.25);
      if (best.zone > 0.0) search(&Shape::rest, best.rest - 3.0, best.rest + 3.0, 0.1);
      searchShape();
    }
    if (!(bt.ok && bt.rss < first_t.rss)) {
      best = first;
      bt = first_t;
    }
  }
  // Keep each part only when it pays for itself.
  const double pen = o.fixed_shape ? 0.0 : o.penalty * (bt.rss / d.n) * std::log(d.n);
  auto without = [&](Shape s) {
    const Trial t = solve(d, s, wall);
    if (t.ok && t.rss - bt.rss < pen) {
      best = s;
      bt = t;
    }
  };
  if (o.fixed_shape) {
    // as given
  } else if (best.zone > 0.0) {
    without(Shape{best.lo, best.hi, 0.0, best.rest});
  }
  // A wall must also explain a share of the force it adds over the samples beyond it
  // (options.min_wall_share): a wall the capture went deep past adds a force there the data
  // would show plainly, and a wall that explains little of it only bends the curve into a
  // misfit elsewhere (random patient 197's axial axis at 6 Hz, seed 10: a wall at 2.9 deg
  // with 8 deg of samples beyond it explained 0.16 % of its force; the walls the truth has,
  // 1-60 %, the least where a steep curve's end slope takes up most of it).
  auto withoutWall = [&](Shape s) {
    double added = 0.0;  // Σ (the wall's force)² over the samples beyond it
    for (std::size_t b = 0; b < d.x.size(); ++b) {
      const double e = std::clamp(d.x[b], s.lo, s.hi) - std::clamp(d.x[b], best.lo, best.hi);
      added += d.cnt[b] * wall * wall * e * e;
    }
    const Trial t = solve(d, s, wall);
    if (t.ok && (t.rss - bt.rss < pen || t.rss - bt.rss < o.min_wall_share * added)) {
      best = s;
      bt = t;
    }
  };
  if (!o.fixed_shape && best.hi < x1) withoutWall(Shape{best.lo, x1, best.zone, best.rest});
  if (!o.fixed_shape && best.lo > x0) withoutWall(Shape{x0, best.hi, best.zone, best.rest});

  out.curve.coeffs = polyOf(d, best, bt);
  out.curve.min_deg = best.lo;
  out.curve.max_deg = best.hi;
  out.curve.zone_deg = best.zone;
  out.curve.rest_deg = best.zone > 0.0 ? best.rest : 0.0;
  out.curve.wall_n_per_deg = wall;
  out.wall_lo = best.lo > x0 && best.lo < x1;
  out.wall_hi = best.hi < x1 && best.hi > x0;
  const double sigma2 = bt.rss / std::max(d.n - bt.p - d.m - 4.0, 1.0);
  for (std::size_t j = 0; j < m; ++j) {
    out.extra.push_back(bt.theta[static_cast<std::size_t>(bt.p) + j]);
    out.extra_se.push_back(std::sqrt(sigma2 * bt.var[static_cast<std::size_t>(bt.p) + j]));
  }
  out.rms = std::sqrt(bt.rss / d.n);
  out.ok = true;
  return out;
}

}  // namespace telehand
