// Velocity from quantized positions by adaptive windowing: quiet at low speed, no lag when
// the motion is fast or turns.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "telehand/core/velocity.h"

namespace telehand {
namespace {

constexpr int64_t kTickNs = 1'000'000;
constexpr double kQuantumM = 4e-6;  // about one MF-2 actuator count at a thimble

/// A position as an encoder reports it: rounded to the quantum on each axis.
Vec3 quantized(const Vec3& p) {
  return Vec3(std::round(p.x() / kQuantumM), std::round(p.y() / kQuantumM),
              std::round(p.z() / kQuantumM)) *
         kQuantumM;
}

TEST(AdaptiveVelocity, QuietOnASlowQuantizedMotion) {
  // 3 mm/s along a diagonal: under one quantum per tick, so the one-tick difference jumps
  // between 0 and 4 mm/s on each axis.
  const Vec3 v_true = Vec3(3e-3, -1.5e-3, 1e-3);
  AdaptiveVelocity est(2 * kQuantumM, 20);  // the line goes through two samples off by q/2
  Vec3 last = Vec3::Zero();
  double raw_err = 0.0, est_err = 0.0;
  for (int i = 0; i < 500; ++i) {
    const Vec3 p = quantized(Vec3(0.01, 0.02, -0.005) + v_true * (i * 1e-3));
    const Vec3 v = est.update(p, i * kTickNs);
    if (i >= 40) {
      raw_err = std::max(raw_err, ((p - last) / 1e-3 - v_true).norm());
      est_err = std::max(est_err, (v - v_true).norm());
      EXPECT_GE(est.window(), 10) << i;
    }
    last = p;
  }
  EXPECT_GT(raw_err, 3e-3) << "the one-tick difference is mostly quantization";
  EXPECT_LT(est_err, 0.6e-3) << "the windowed slope is within 20 % of the true speed";
}

TEST(AdaptiveVelocity, AtRestADitheringCountGivesAlmostNothing) {
  AdaptiveVelocity est(2 * kQuantumM, 20);
  double largest = 0.0;
  for (int i = 0; i < 400; ++i) {
    // A count flickering as a still finger sits on its edge: 0, q, 0, 0, q, ...
    const double x = ((i * 7) % 3 == 0) ? kQuantumM : 0.0;
    const Vec3 v = est.update(Vec3(x, 0.0, 0.0), i * kTickNs);
    if (i >= 20) largest = std::max(largest, v.norm());
  }
  // One count over a 20-tick window at most; the one-tick difference would give 4 mm/s.
  EXPECT_LE(largest, kQuantumM / 20e-3 + 1e-12);
}

TEST(AdaptiveVelocity, FollowsAFastReversalWithinATick) {
  AdaptiveVelocity est(2 * kQuantumM, 20);
  double x = 0.0;
  for (int i = 0; i < 100; ++i) {
    x += (i < 50 ? 0.1 : -0.1) * 1e-3;  // 100 mm/s, then back
    const Vec3 v = est.update(quantized(Vec3(x, 0.0, 0.0)), i * kTickNs);
    if (i >= 5 && i < 50) {
      EXPECT_NEAR(v.x(), 0.1, 0.005) << i;
    }
    if (i >= 51) {
      EXPECT_NEAR(v.x(), -0.1, 0.005) << i << ": the window must not reach back over the turn";
    }
  }
}

TEST(AdaptiveVelocity, UsesSampleTimesIgnoresRepeatsAndRestartsWhenTimeGoesBack) {
  AdaptiveVelocity est(2 * kQuantumM, 20);
  EXPECT_EQ(est.update(Vec3::Zero(), 0), Vec3::Zero()) << "one sample: no estimate";
  EXPECT_EQ(est.window(), 0);
  // 2 ms between these two samples: the slope uses the real interval.
  est.update(Vec3(0.0, 0.0, 0.002), 2 * kTickNs);
  EXPECT_NEAR(est.velocity().z(), 1.0, 1e-12);
  EXPECT_EQ(est.window(), 1);
  // A non-finite sample is not motion, and the same sample read again is nothing new: the
  // estimate stays.
  const double nan = std::numeric_limits<double>::quiet_NaN();
  EXPECT_NEAR(est.update(Vec3(nan, 0.0, 0.0), 3 * kTickNs).z(), 1.0, 1e-12);
  EXPECT_NEAR(est.update(Vec3(0.0, 0.0, 0.002), 2 * kTickNs).z(), 1.0, 1e-12);
  EXPECT_EQ(est.window(), 1);
  est.update(Vec3(0.0, 0.0, 0.003), 3 * kTickNs);
  EXPECT_NEAR(est.velocity().z(), 1.0, 1e-12);
  EXPECT_EQ(est.window(), 2) << "the repeated sample did not enter the window";
  // Time going back restarts the history.
  EXPECT_EQ(est.update(Vec3(1.0, 1.0, 1.0), kTickNs), Vec3::Zero());
  EXPECT_EQ(est.window(), 0);
}

}  // namespace
}  // namespace telehand
