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

inline bool allFinite(const Vec3& v) noexcept {
  return std::isfinite(v.x()) && std::isfinite(v.y()) && std::isfinite(v.z());
}

/// Per-finger quantity: index 0 is the thumb, 1 the index finger.
template <typename T>
using PerFinger = std::array<T, 2>;
constexpr int kThumb = 0;
constexpr int kIndex = 1;

}  // namespace telehand
