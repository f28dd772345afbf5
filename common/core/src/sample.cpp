#include "telehand/core/sample.h"

#include <cmath>
#include <cstdio>
#include <limits>
#include <type_traits>

namespace telehand {

std::optional<std::string> firstNonFinite(const Sample& s) {
  for (int k = 0; k < 2; ++k) {
    const auto& f = s.fingers[k];
    const std::string finger = k == 0 ? "fingers[0] (thumb)" : "fingers[1] (index)";
    for (int i = 0; i < 3; ++i) {
      if (!std::isfinite(f.position_m[i])) return finger + ".position_m[" + std::to_string(i) + "]";
      if (!std::isfinite(f.command_n[i])) return finger + ".command_n[" + std::to_string(i) + "]";
    }
    for (int i = 0; i < 4; ++i) {
      if (!std::isfinite(f.orientation_q[i])) {
        return finger + ".orientation_q[" + std::to_string(i) + "]";
      }
      if (!std::isfinite(f.fsr_n[i])) return finger + ".fsr_n[" + std::to_string(i) + "]";
    }
    if (!std::isfinite(f.tangential_n)) return finger + ".tangential_n";
    if (!std::isfinite(f.normal_n)) return finger + ".normal_n";
    if (!std::isfinite(f.contact_depth_m)) return finger + ".contact_depth_m";
    for (int i = 0; i < 3; ++i) {
      if (!std::isfinite(f.tissue_force_n[i]))
        return finger + ".tissue_force_n[" + std::to_string(i) + "]";
    }
  }
  for (int i = 0; i < 3; ++i) {
    if (!std::isfinite(s.mcp_angles_rad[i])) return "mcp_angles_rad[" + std::to_string(i) + "]";
    if (!std::isfinite(s.mcp_torque_nm[i])) return "mcp_torque_nm[" + std::to_string(i) + "]";
  }
  return std::nullopt;
}

std::optional<std::string> firstInvalid(const Sample& s) {
  if (auto bad = firstNonFinite(s)) return "non-finite " + *bad;
  namespace b = sample_bounds;
  const auto out = [](const std::string& field, double v) {
    char buf[48];
    std::snprintf(buf, sizeof buf, " = %.6g", v);
    return "implausible " + field + buf;
  };
  if (s.seq >= b::kMaxSeq) return out("seq", static_cast<double>(s.seq));
  for (int k = 0; k < 2; ++k) {
    const auto& f = s.fingers[k];
    const std::string finger = k == 0 ? "fingers[0] (thumb)" : "fingers[1] (index)";
    double q2 = 0.0;
    for (int i = 0; i < 3; ++i) {
      if (std::abs(f.position_m[i]) > b::kPositionM) {
        return out(finger + ".position_m[" + std::to_string(i) + "]", f.position_m[i]);
      }
      if (std::abs(f.command_n[i]) > b::kCommandN) {
        return out(finger + ".command_n[" + std::to_string(i) + "]", f.command_n[i]);
      }
    }
    for (int i = 0; i < 4; ++i) {
      q2 += f.orientation_q[i] * f.orientation_q[i];
      if (std::abs(f.fsr_n[i]) > b::kFsrN) {
        return out(finger + ".fsr_n[" + std::to_string(i) + "]", f.fsr_n[i]);
      }
    }
    if (std::abs(std::sqrt(q2) - 1.0) > b::kQuatNormTolerance) {
      return out(finger + ".orientation_q norm", std::sqrt(q2));
    }
    if (std::abs(f.tangential_n) > b::kThimbleForceN)
      return out(finger + ".tangential_n", f.tangential_n);
    if (std::abs(f.normal_n) > b::kThimbleForceN) return out(finger + ".normal_n", f.normal_n);
    if (f.contact_depth_m < 0.0 || f.contact_depth_m > b::kDepthM)
      return out(finger + ".contact_depth_m", f.contact_depth_m);
    for (int i = 0; i < 3; ++i) {
      if (std::abs(f.tissue_force_n[i]) > b::kThimbleForceN) {
        return out(finger + ".tissue_force_n[" + std::to_string(i) + "]", f.tissue_force_n[i]);
      }
    }
  }
  for (int i = 0; i < 3; ++i) {
    if (std::abs(s.mcp_angles_rad[i]) > b::kAngleRad) {
      return out("mcp_angles_rad[" + std::to_string(i) + "]", s.mcp_angles_rad[i]);
    }
    if (std::abs(s.mcp_torque_nm[i]) > b::kTorqueNm) {
      return out("mcp_torque_nm[" + std::to_string(i) + "]", s.mcp_torque_nm[i]);
    }
  }
  return std::nullopt;
}

PerFinger<Vec3> thimblePositions(const Sample& s) noexcept {
  PerFinger<Vec3> p;
  for (int k = 0; k < 2; ++k) {
    p[k] = Vec3(s.fingers[k].position_m[0], s.fingers[k].position_m[1], s.fingers[k].position_m[2]);
  }
  return p;
}

}  // namespace telehand

namespace telehand {

void SampleDigest::add(const Sample& s) noexcept {
  uint64_t h = 0xcbf29ce484222325ULL;  // FNV-1a, 64 bit
  const auto mix = [&h](const void* p, std::size_t n) {
    const auto* b = static_cast<const unsigned char*>(p);
    for (std::size_t i = 0; i < n; ++i) h = (h ^ b[i]) * 0x100000001b3ULL;
  };
  visitSampleFields(s, [&](const auto& v) {
    using T = std::remove_cvref_t<decltype(v)>;
    if constexpr (std::is_floating_point_v<T>) {
      // One NaN for all: the record keeps a NaN as NULL and reads back the canonical one.
      const T x = std::isnan(v) ? std::numeric_limits<T>::quiet_NaN() : v;
      mix(&x, sizeof x);
    } else {
      mix(&v, sizeof v);
    }
  });
  ++count;
  sum += h;
}

std::string SampleDigest::text() const {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%llu samples, digest %016llx",
                static_cast<unsigned long long>(count), static_cast<unsigned long long>(sum));
  return buf;
}

}  // namespace telehand
