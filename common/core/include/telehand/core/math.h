#pragma once
/// Eigen aliases: fixed-size types only, safe on the real-time path.
#include <Eigen/Dense>
#include <Eigen/Geometry>
#include <array>
#include <cmath>
#include <numbers>

namespace telehand {

using Vec3 = Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;
using Quat = Eigen::Quaterniond;

constexpr double kPi = std::numbers::pi;
constexpr double degToRad(double deg) { return deg * kPi / 180.0; }
constexpr double radToDeg(double rad) { return rad * 180.0 / kPi; }

/// 0 at x <= 0 rising to 1 at x >= width with no step in value or slope at either end
/// (smoothstep); 1 when width is not positive.
constexpr double smoothRamp(double x, double width) {
  if (!(width > 0.0)) return 1.0;
  const double u = x <= 0.0 ? 0.0 : x >= width ? 1.0 : x / width;
  return u * u * (3.0 - 2.0 * u);
}

inline bool allFinite(const Vec3& v) noexcept {
  return std::isfinite(v.x()) && std::isfinite(v.y()) && std::isfinite(v.z());
}

/// Per-finger quantity: index 0 is the thumb, 1 the index finger.
template <typename T>
using PerFinger = std::array<T, 2>;
constexpr int kThumb = 0;
constexpr int kIndex = 1;

}  // namespace telehand
