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
