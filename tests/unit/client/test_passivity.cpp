// The passivity observer counts the energy exchanged at the device port exactly for a force
// held over each tick; the controller removes what an active environment injects.
#include <gtest/gtest.h>

#include <cmath>

#include "telehand/client/loop/passivity.h"
#include "telehand/core/clock.h"

namespace telehand::client::loop {
namespace {

/// The operator moves both thimbles along x: 10 mm amplitude at `hz`.
PerFinger<Vec3> motion(int i, double hz) {
  const double x = 0.01 * std::sin(2 * kPi * hz * i * 1e-3);
  return {Vec3(x, 0.0, 0.0), Vec3(x, 0.01, 0.0)};
}

TEST(PassivityObserver, CountsTheWorkOfAHeldForceExactly) {
  PassivityGuard g(PassivityConfig{false});
  g.observe({Vec3::Zero(), Vec3::Zero()}, {Vec3::Zero(), Vec3::Zero()}, 0);
  // The device pushes +x with 1 N on the thumb while the thumb moves 2 mm along +x: the
  // environment gave 2 mJ to the operator.
  g.observe({Vec3(0.002, 0, 0), Vec3::Zero()}, {Vec3(1, 0, 0), Vec3::Zero()}, kNsPerMs);
  EXPECT_NEAR(g.energyJ(), -0.002, 1e-15);
  // Pushing against the motion takes energy in.
  g.observe({Vec3(0.003, 0, 0), Vec3::Zero()}, {Vec3(-3, 0, 0), Vec3::Zero()}, 2 * kNsPerMs);
  EXPECT_NEAR(g.energyJ(), -0.002 + 0.003, 1e-15);
}

TEST(PassivityObserver, ASpringWithDampingStaysPassive) {
  PassivityGuard g(PassivityConfig{false});
  PerFinger<Vec3> last{Vec3::Zero(), Vec3::Zero()};
  PerFinger<Vec3> prev = motion(0, 3.0);
  double lowest = 0.0;
  for (int i = 0; i < 3000; ++i) {
    const PerFinger<Vec3> p = motion(i, 3.0);
    g.observe(p, last, i * kNsPerMs);
    lowest = std::min(lowest, g.energyJ());
    for (int k = 0; k < 2; ++k) {
      const Vec3 v = (p[k] - prev[k]) / 1e-3;
      last[k] = -200.0 * (p[k] - Vec3(0, 0.01 * k, 0)) - 1.0 * v;  // 200 N/m, 1 N·s/m
    }
    prev = p;
  }
  EXPECT_GT(g.energyJ(), 0.0);
  EXPECT_GT(lowest, -1e-4);  // the zero-order hold leaks at most K·Δx²/2 per tick
}

TEST(PassivityController, DampsAnActiveEnvironmentBackToPassive) {
  for (bool control : {false, true}) {
    PassivityGuard g(PassivityConfig{control, 50.0});
    PerFinger<Vec3> last{Vec3::Zero(), Vec3::Zero()};
    PerFinger<Vec3> prev = motion(0, 2.0);
    double lowest = 0.0;
    uint64_t active = 0;
    for (int i = 0; i < 2000; ++i) {
      const PerFinger<Vec3> p = motion(i, 2.0);
      g.observe(p, last, i * kNsPerMs);
      lowest = std::min(lowest, g.energyJ());
      PerFinger<Vec3> request;
      for (int k = 0; k < 2; ++k) request[k] = 2.0 * (p[k] - prev[k]) / 1e-3;  // negative damping
      const PassivityOutput out = g.control(request);
      active += out.damping_ns_per_m > 0.0;
      if (!control) {
        EXPECT_EQ(out.damping_ns_per_m, 0.0);
      }
      last = out.force_n;
      prev = p;
    }
    if (control) {
      EXPECT_GT(active, 100u);
      // At most one tick's injection is ever outstanding.
      EXPECT_GT(lowest, -2e-4) << lowest;
    } else {
      EXPECT_LT(g.energyJ(), -0.05) << "the environment really is active";
    }
  }
}

TEST(PassivityObserver, IgnoresNonFinitePositions) {
  PassivityGuard g;
  g.observe({Vec3::Zero(), Vec3::Zero()}, {Vec3::Zero(), Vec3::Zero()}, 0);
  const double nan = std::nan("");
  g.observe({Vec3(nan, 0, 0), Vec3::Zero()}, {Vec3(1, 0, 0), Vec3::Zero()}, kNsPerMs);
  EXPECT_TRUE(std::isfinite(g.energyJ()));
  const PassivityOutput out = g.control({Vec3(1, 0, 0), Vec3::Zero()});
  EXPECT_TRUE(allFinite(out.force_n[0]));
}

}  // namespace
}  // namespace telehand::client::loop
