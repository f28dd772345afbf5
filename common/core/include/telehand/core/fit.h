#pragma once
/// Least-squares fitting shared by the server's estimator and the tools: a cubic in one
/// variable plus optional linear extra regressors (e.g. the angular rate, whose coefficient
/// is a damping), solved on a centred and scaled variable with column-pivoting Householder
/// QR so that a cubic over ±90° (a^3 up to 7e5) stays well conditioned.
#include <array>
#include <cstddef>
#include <span>
#include <vector>

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

/// A joint axis' holding force as telehand's joint model renders it (joint_model.h,
/// JointModel::holdingForceN): a cubic P; a free band of half width `zone_deg` around
/// `rest_deg` (P's zero) where the force stays P(rest_deg); beyond `min_deg`/`max_deg` an
/// end-of-range wall whose stiffness adds to P's end slope.
struct PiecewiseCubic {
  std::array<double, 4> coeffs{};  ///< c3, c2, c1, c0 of P in the caller's units of x
  double min_deg = 0.0, max_deg = 0.0;
  double zone_deg = 0.0, rest_deg = 0.0;
  double wall_n_per_deg = 1.0;
  double poly(double x) const noexcept {
    return ((coeffs[0] * x + coeffs[1]) * x + coeffs[2]) * x + coeffs[3];
  }
  double polySlope(double x) const noexcept {
    return (3.0 * coeffs[0] * x + 2.0 * coeffs[1]) * x + coeffs[2];
  }
  /// The holding force at x (the same expression as JointModel::holdingForceN).
  double eval(double x) const noexcept;
};

struct PiecewiseFitOptions {
  double wall_n_per_deg = 1.0;  ///< the joint model's kWallNPerDeg
  double bin_deg = 0.05;        ///< samples are pooled in angle bins this wide
  bool find_zone = true;
  bool find_walls = true;
  /// A zone or wall is kept only when it lowers the residual sum of squares by more than
  /// this many times σ² ln n (a Bayesian-information-style penalty against fitting noise).
  double penalty = 2.0;
  /// ...and a wall only when it also lowers it by this share of the sum of squares of the
  /// force it adds beyond it (wall_n_per_deg times the depth, over the samples there).
  double min_wall_share = 0.005;
  /// With walls and zone searched, a second search from a start with the zone searched
  /// first, the better kept (twice the search's cost).
  bool zone_first_start = true;
  /// Fit only the linear part, with this shape's walls, zone and rest (no search).
  const PiecewiseCubic* fixed_shape = nullptr;
  /// Per sample (empty, or as long as x), a known factor on the piecewise curve:
  /// y ≈ curve_scale_i · piecewise(x_i) + Σ extras (a force that grows with the holding
  /// force, e.g. a stretch reflex, stays linear in the curve's coefficients).
  std::span<const double> curve_scale;
};

struct PiecewiseFitResult {
  bool ok = false;
  PiecewiseCubic curve;  ///< min/max_deg: the walls found, else the data's extent
  bool wall_lo = false, wall_hi = false;
  std::vector<double> extra;     ///< coefficients of the extra regressors
  std::vector<double> extra_se;  ///< their standard errors
  double rms = 0.0;
  std::size_t n = 0;
  double x_min = 0.0, x_max = 0.0;
};

/// y ≈ piecewise(x) + Σ extra_j · extras[j] (each as long as x; with options.curve_scale the
/// curve term is scaled per sample), least squares: the cubic and
/// the extras' coefficients are linear; the zone (half width, centre), and the wall angles
/// are searched (coordinate descent on grids, then refined), each kept only when it pays
/// for itself (options.penalty). Samples are pooled in narrow angle bins, so each trial
/// costs the number of bins, not of samples.
PiecewiseFitResult fitPiecewiseCubic(std::span<const double> x, std::span<const double> y,
                                     std::span<const std::span<const double>> extras,
                                     const PiecewiseFitOptions& options = {});

}  // namespace telehand
