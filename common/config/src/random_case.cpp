// Random patient cases within published ranges (docs/facts.md "Random patient cases").
#include <algorithm>
#include <cmath>
#include <cstring>
#include <random>
#include <string>

#include "telehand/config/config.h"
#include "telehand/core/error.h"

namespace telehand {

namespace {

/// F(a - shift) · scale, expanded back into cubic coefficients of a.
std::array<double, 4> scaledShifted(const std::array<double, 4>& c, double scale, double d) {
  const double c3 = c[0], c2 = c[1], c1 = c[2], c0 = c[3];
  return {scale * c3, scale * (c2 - 3.0 * c3 * d), scale * (c1 - 2.0 * c2 * d + 3.0 * c3 * d * d),
          scale * (c0 - c1 * d + c2 * d * d - c3 * d * d * d)};
}

}  // namespace

PatientCase randomPatientCase(uint64_t seed, const RandomCaseRanges& r) {
  std::mt19937_64 rng(seed);
  auto uniform = [&rng](const double(&range)[2]) {
    return std::uniform_real_distribution<double>(range[0], range[1])(rng);
  };
  auto logUniform = [&rng](const double(&range)[2]) {
    return std::exp(
        std::uniform_real_distribution<double>(std::log(range[0]), std::log(range[1]))(rng));
  };
  PatientCase pc;
  pc.name = "random-" + std::to_string(seed);
  pc.description = "random patient within published ranges";
  pc.source = "docs/facts.md 'Random patient cases'";
  JointModelParams& m = pc.model;
  const JointModelParams healthy = healthyIndexMcp();
  m = healthy;
  const double scale = logUniform(r.stiffness_scale);
  const std::array<double, kAxes> shift = {uniform(r.flexion_shift_deg), 0.0, 0.0};
  for (std::size_t i = 0; i < kAxes; ++i) {
    // Each axis within ±20 % of the joint's overall stiffness.
    const double axis_scale = scale * std::uniform_real_distribution<double>(0.8, 1.2)(rng);
    m.axes[i].coeffs = scaledShifted(healthy.axes[i].coeffs, axis_scale, shift[i]);
    m.neutral_zone_deg[i] =
        std::uniform_real_distribution<double>(0.0, r.neutral_zone_max_deg[i])(rng);
  }
  m.axes[kFlexion].min_deg = uniform(r.flexion_min_deg);
  m.axes[kFlexion].max_deg = uniform(r.flexion_max_deg);
  m.axes[kAbduction].min_deg = -uniform(r.abduction_deg);
  m.axes[kAbduction].max_deg = uniform(r.abduction_deg);
  m.axes[kAxial].min_deg = uniform(r.axial_min_deg);
  m.axes[kAxial].max_deg = uniform(r.axial_max_deg);
  m.damping_nms_per_rad = logUniform(r.damping_nms_per_rad);
  const bool spasm = std::uniform_real_distribution<double>(0.0, 1.0)(rng) < r.spasm_probability;
  const double gain = uniform(r.speed_gain_s_per_rad);  // drawn either way: same stream
  m.speed_gain_s_per_rad = spasm ? gain : 0.0;
  for (std::size_t i = 0; i < kAxes; ++i) {
    // Positive scales and shifts keep eqs. 3-5 rising (their slopes have no real roots), and
    // the ranges keep their force far under kMaxHoldingForceN; the case-file check holds by
    // construction, and is checked all the same.
    if (const auto why = passiveCurveProblem(m.axes[i])) {
      throw Error("random case " + std::to_string(seed) + ": " + std::string(kAxisNames[i]) +
                  " curve " + *why);
    }
  }
  m.version = 1;
  std::memset(m.case_name.data(), 0, m.case_name.size());
  std::memcpy(m.case_name.data(), pc.name.data(), std::min(pc.name.size(), m.case_name.size() - 1));
  return pc;
}

}  // namespace telehand
