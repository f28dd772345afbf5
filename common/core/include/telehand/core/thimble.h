#pragma once
/// Thimble force estimation from the four FlexiForce A201 sensors of an MF-2 thimble.
/// Sensors 1 (end) and 4 (pad) are normal to the fingertip, 2 and 3 are the sides
/// (paper section IV, docs/facts.md "The paper").
#include <array>

#include "telehand/core/math.h"

namespace telehand {

/// FSR readings in newtons, index 0..3 = sensors 1..4.
using FsrReadings = std::array<float, 4>;

struct ThimbleForces {
  double tangential_n = 0.0;  ///< eq. 1: F2 - F3 (signed, along the thimble's side axis)
  double normal_n = 0.0;      ///< eq. 2: sqrt(F4^2 + F1^2)
};

/// Paper eqs. 1-2.
ThimbleForces thimbleForces(const FsrReadings& fsr) noexcept;

/// Thimble frame convention: +z is the pad normal pointing out of the fingertip into what it
/// presses, +y the side axis along which eq. 1's tangential force is positive.
Vec3 thimbleForceVector(const ThimbleForces& f, const Quat& thimble_orientation) noexcept;

}  // namespace telehand
