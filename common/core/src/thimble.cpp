#include "telehand/core/thimble.h"

namespace telehand {

ThimbleForces thimbleForces(const FsrReadings& fsr) noexcept {
  ThimbleForces f;
  f.tangential_n = static_cast<double>(fsr[1]) - static_cast<double>(fsr[2]);         // eq. 1
  f.normal_n = std::hypot(static_cast<double>(fsr[3]), static_cast<double>(fsr[0]));  // eq. 2
  return f;
}

Vec3 thimbleForceVector(const ThimbleForces& f, const Quat& q) noexcept {
  return q * Vec3(0.0, f.tangential_n, f.normal_n);
}

}  // namespace telehand
