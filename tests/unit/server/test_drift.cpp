// The server's drift correction on synthetic signals: persistent drift is folded into the
// grip offset within about a second, the mobilization's own ripple and a released finger
// are not drift, and corrections are rate-limited and bounded.
#include <gtest/gtest.h>

#include <cmath>

#include "telehand/core/clock.h"
#include "telehand/core/joint_model.h"
#include "telehand/server/session/drift.h"

namespace telehand::server::session {
namespace {

constexpr double kDt = 1e-3;

/// A student mobilizing in flexion at 3 Hz (±10 deg around 40); the hand sits `drift_deg`
/// away from the thimbles plus a lag ripple of `ripple_deg` at the same frequency.
struct Scene {
  Vec3 drift_deg = Vec3::Zero();
  double ripple_deg = 0.0;
  Vec3 thimbles(double t) const {
    return Vec3(degToRad(40.0 + 10.0 * std::sin(2 * kPi * 3.0 * t)), 0.0, 0.0);
  }
  Vec3 hand(double t) const {
    Vec3 h = thimbles(t) + drift_deg * (kPi / 180.0);
    h[kFlexion] += degToRad(ripple_deg) * std::cos(2 * kPi * 3.0 * t);
    return h;
  }
};

/// Runs the corrector for `seconds` of 1 ms samples from `t0`; the proxy renders the
/// thimbles plus the corrector's present offset. Returns the number of corrections.
int run(DriftCorrector& c, const Scene& s, double t0, double seconds, bool held = true) {
  int n = 0;
  const int ticks = static_cast<int>(seconds / kDt);
  for (int i = 0; i < ticks; ++i) {
    const double t = t0 + i * kDt;
    const int64_t now = static_cast<int64_t>(t * 1e9);
    n += c.observe(s.hand(t), s.thimbles(t) + c.offset(), held, kDt, now);
  }
  return n;
}

TEST(DriftCorrector, PersistentDriftIsFoldedIntoTheOffsetWithinASecond) {
  DriftCorrector c;
  Scene s;
  s.drift_deg = Vec3(0.0, 1.5, -4.0);  // the pads slipped in pronation and a little abduction
  s.ripple_deg = 1.5;                  // and the hand lags the moving thimbles
  EXPECT_GE(run(c, s, 0.0, 1.2), 1);
  run(c, s, 1.2, 4.8);
  const Vec3 off_deg = c.offset() * (180.0 / kPi);
  for (int i = 0; i < kAxes; ++i) {
    EXPECT_NEAR(off_deg[i], s.drift_deg[i], c.options().threshold_deg) << i;
  }
  // Flexion's ripple averages out: no offset there beyond the threshold.
  EXPECT_LT(std::abs(off_deg[kFlexion]), c.options().threshold_deg);
  // A handful of corrections, not one per sample.
  EXPECT_LE(c.corrections(), 6u);
  EXPECT_LT(radToDeg(c.drift().cwiseAbs().maxCoeff()), c.options().threshold_deg);
}

TEST(DriftCorrector, TheMobilizationsOwnLagIsNotDrift) {
  DriftCorrector c;
  Scene s;
  s.ripple_deg = 3.0;  // ±3 deg of lag at 3 Hz, zero on average
  EXPECT_EQ(run(c, s, 0.0, 10.0), 0);
  EXPECT_EQ(c.offset(), Vec3::Zero());
}

TEST(DriftCorrector, AReleasedFingerIsNotDrift) {
  DriftCorrector c;
  Scene s;
  s.drift_deg = Vec3(-30.0, 0.0, 0.0);  // the finger sprang back to rest, the thimbles did not
  EXPECT_EQ(run(c, s, 0.0, 5.0, /*held=*/false), 0);
  EXPECT_EQ(c.offset(), Vec3::Zero());
  EXPECT_EQ(c.drift(), Vec3::Zero());
}

TEST(DriftCorrector, CorrectionsAreSpacedAndBounded) {
  DriftOptions o;
  o.max_offset_deg = 10.0;
  DriftCorrector c(o);
  Scene s;
  s.drift_deg = Vec3(0.0, 0.0, 25.0);  // beyond what the proxy may be moved
  int64_t last = -1;
  double min_gap_s = 1e9;
  for (int i = 0; i < 5000; ++i) {
    const double t = i * kDt;
    const int64_t now = static_cast<int64_t>(t * 1e9);
    if (c.observe(s.hand(t), s.thimbles(t) + c.offset(), true, kDt, now)) {
      if (last >= 0) min_gap_s = std::min(min_gap_s, static_cast<double>(now - last) * 1e-9);
      last = now;
    }
  }
  EXPECT_GE(min_gap_s, o.min_interval_s - 1e-9);
  EXPECT_NEAR(radToDeg(c.offset()[kAxial]), 10.0, 1e-9);
  // At the bound nothing more is published, though the drift stays.
  const uint64_t at_limit = c.corrections();
  EXPECT_EQ(run(c, s, 5.0, 3.0), 0);
  EXPECT_EQ(c.corrections(), at_limit);
  EXPECT_GT(radToDeg(c.drift()[kAxial]), 10.0);
}

TEST(DriftCorrector, NonFiniteAnglesAreIgnored) {
  DriftCorrector c;
  const Vec3 nan(std::nan(""), 0.0, 0.0);
  EXPECT_FALSE(c.observe(nan, Vec3::Zero(), true, kDt, 0));
  EXPECT_FALSE(c.observe(Vec3::Zero(), nan, true, kDt, 1'000'000));
  EXPECT_TRUE(c.drift().allFinite());
  EXPECT_EQ(c.corrections(), 0u);
}

}  // namespace
}  // namespace telehand::server::session
