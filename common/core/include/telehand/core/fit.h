#pragma once
/// Least-squares fitting shared by the server's estimator and the tools: a cubic in one
/// variable plus optional linear extra regressors (e.g. the angular rate, whose coefficient
/// is a damping), solved on a centred and scaled variable with column-pivoting Householder
/// QR so that a cubic over ±90° (a^3 up to 7e5) stays well conditioned.
#include <array>
#include <cstddef>
#include <span>

namespace telehand {

struct CubicFitResult {
  bool ok = false;                 ///< enough distinct points and a full-rank system
  std::array<double, 4> coeffs{};  ///< c3, c2, c1, c0 in the caller's units of x
  double extra = 0.0;              ///< coefficient of the extra regressor (0 without one)
  double rms = 0.0;                ///< root mean square residual
  std::size_t n = 0;
  double x_min = 0.0, x_max = 0.0;
  double eval(double x) const noexcept {
    return ((coeffs[0] * x + coeffs[1]) * x + coeffs[2]) * x + coeffs[3];
  }
};

/// y ≈ c3 x^3 + c2 x^2 + c1 x + c0 (+ extra_coeff * extra). `extra` empty or as long as x.
CubicFitResult fitCubic(std::span<const double> x, std::span<const double> y,
                        std::span<const double> extra = {});

/// Coefficients (highest power first) of p((x - centre) / scale) expanded in x.
std::array<double, 4> expandScaledCubic(const std::array<double, 4>& b_low_first, double centre,
                                        double scale) noexcept;

}  // namespace telehand
