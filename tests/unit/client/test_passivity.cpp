// The passivity observer counts the energy exchanged at the device port exactly for a force
// held over each tick; the controller removes what an active environment injects, with no more
// damping than the device's lightest moving mass and its delay can render.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

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

/// v(k+1) = v(k) − a·v(k−d) from v = 1 for `steps` ticks: the largest |v| over the last 100.
double delayedDamper(double a, int d, int steps) {
  std::vector<double> v(static_cast<std::size_t>(d) + 1, 1.0);  // v(k−d) .. v(k)
  double late = 0.0;
  for (int k = 0; k < steps; ++k) {
    const double next = v.back() - a * v.front();
    v.erase(v.begin());
    v.push_back(next);
    if (k >= steps - 100) late = std::max(late, std::abs(next));
  }
  return late;
}

TEST(PassivityController, StableDampingIsWhereADelayedDamperStartsToRing) {
  // The bound against the difference equation itself, at delays and masses it was not
  // written for: 3 % under it a kick dies out, 3 % over it grows.
  constexpr double kT = 1e-3;
  for (int d = 0; d <= 5; ++d) {
    for (double m : {0.004, 0.0085, 0.05}) {
      const double b = stableDampingNsPerM(m, d, kT);
      ASSERT_GT(b, 0.0);
      const double a = b * kT / m;
      EXPECT_LT(delayedDamper(0.97 * a, d, 4000), 0.05) << "d " << d << " m " << m;
      EXPECT_GT(delayedDamper(1.03 * a, d, 4000), 1.0) << "d " << d << " m " << m;
    }
  }
  EXPECT_NEAR(stableDampingNsPerM(0.05, 0, kT), 100.0, 1e-9);  // 2·m/T
  EXPECT_NEAR(stableDampingNsPerM(0.05, 1, kT), 50.0, 1e-9);   // m/T
  EXPECT_EQ(stableDampingNsPerM(0.0, 1, kT), 0.0);
  EXPECT_EQ(stableDampingNsPerM(0.05, -1, kT), 0.0);
}

struct LightThimbleRun {
  double bound = 0.0;        ///< the controller's bound at 1 kHz
  double max_damping = 0.0;  ///< the largest damping it added
  double max_speed = 0.0;    ///< the fastest the thimble went
  double energy_j = 0.0;     ///< the observer's energy at the end
};

/// A thimble of 8.5 g along x (the emulated USB MF-2's lightest direction) whose force acts a
/// tick after the loop writes it, moving at 5 cm/s (10.6 µJ of motion) with a deficit of
/// `deficit_j` to remove and nothing else rendered; `device` tells the controller about it.
LightThimbleRun lightThimble(bool device, double deficit_j) {
  constexpr double kMassKg = 0.0085, kT = 1e-3;
  PassivityGuard g;
  if (device) g.setDeviceLimit(stableDampingNsPerM(kMassKg, 2, kT));  // a tick late, a tick old
  LightThimbleRun r;
  r.bound = g.dampingBoundNsPerM();
  const Vec3 index(0.0, 0.01, 0.0);
  double x = 0.0, v = 0.05;
  int64_t now = kNsPerS;
  // The deficit: over one tick the device pushed the thimble along its motion.
  g.observe({Vec3(x, 0, 0), index}, {Vec3::Zero(), Vec3::Zero()}, now);
  x += v * kT;
  now += kNsPerMs;
  g.observe({Vec3(x, 0, 0), index}, {Vec3(deficit_j / (v * kT), 0, 0), Vec3::Zero()}, now);
  double written = 0.0, acting = 0.0;
  for (int i = 0; i < 3000; ++i) {
    const PassivityOutput out = g.control({Vec3::Zero(), Vec3::Zero()});
    r.max_damping = std::max(r.max_damping, out.damping_ns_per_m);
    acting = written;  // the force written last tick acts over this one
    written = out.force_n[0].x();
    v += acting / kMassKg * kT;  // semi-implicit Euler
    x += v * kT;
    r.max_speed = std::max(r.max_speed, std::abs(v));
    if (!std::isfinite(x) || std::abs(v) > 100.0) break;
    now += kNsPerMs;
    g.observe({Vec3(x, 0, 0), index}, {Vec3(written, 0, 0), Vec3::Zero()}, now);
  }
  r.energy_j = g.energyJ();
  return r;
}

TEST(PassivityController, DampingStaysWithinWhatALightDelayedDeviceRenders) {
  // A deficit the motion can pay (5 µJ of 10.6): paid, by slowing the thimble.
  const LightThimbleRun paid = lightThimble(true, 5e-6);
  // The margin of 2·sin(π/10)·m/T: the delay of one tick, and the velocity a tick old.
  EXPECT_NEAR(paid.bound, PassivityConfig{}.stability_margin * stableDampingNsPerM(0.0085, 2, 1e-3),
              1e-9);
  EXPECT_LT(paid.bound, PassivityConfig{}.max_damping_ns_per_m);
  EXPECT_GT(paid.max_damping, 0.0) << "the controller acted";
  EXPECT_LE(paid.max_damping, paid.bound + 1e-12);
  EXPECT_LE(paid.max_speed, 0.05 + 1e-9) << "the damping only slowed the thimble";
  EXPECT_GT(paid.energy_j, -2e-7) << "the deficit was removed";
  // One it cannot (0.5 mJ, as when the observer misreads a delayed device's exchange): the
  // controller stays on, at its bound, and still only slows the thimble.
  const LightThimbleRun held = lightThimble(true, 5e-4);
  EXPECT_NEAR(held.max_damping, held.bound, 1e-9);
  EXPECT_LE(held.max_speed, 0.05 + 1e-9);
  // Told nothing, the controller damps up to its 20 N·s/m, which on 8.5 g a tick late rings
  // and grows: the limit cycle this bound exists for (docs/usb.md).
  const LightThimbleRun unbounded = lightThimble(false, 5e-4);
  EXPECT_EQ(unbounded.bound, PassivityConfig{}.max_damping_ns_per_m);
  EXPECT_GT(unbounded.max_speed, 0.5) << "the unbounded damper on this device does not ring";
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
