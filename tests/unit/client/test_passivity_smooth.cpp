// The passivity controller's added force is smooth on encoder positions: it does not turn
// quantization into force steps, does not feed on them, and switches on and off without
// stepping the force; with the simulated MF-2 (encoder positions through the device model),
// the safety gate's rate limit is left for real transients.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "telehand/client/loop/haptic_loop.h"
#include "telehand/client/loop/passivity.h"
#include "telehand/core/clock.h"
#include "telehand/devices/simulated_mf2.h"

namespace telehand::client {
namespace {

using loop::PassivityGuard;
using loop::PassivityOutput;

constexpr double kQuantumM = 4e-6;           // about one MF-2 actuator count at a thimble
constexpr double kGateStepN = 200.0 * 1e-3;  // the safety gate's default 200 N/s at 1 kHz

PerFinger<Vec3> zero() { return {Vec3::Zero(), Vec3::Zero()}; }

/// Leaves `g` with an energy deficit of `deficit_j`: over one 1 ms tick the thumb moved
/// 0.1 mm along +x while the device pushed it that way.
void preloadDeficit(PassivityGuard& g, double deficit_j, int64_t& now) {
  g.observe({Vec3::Zero(), Vec3(0, 0.01, 0)}, zero(), now);
  now += kNsPerMs;
  g.observe({Vec3(1e-4, 0, 0), Vec3(0, 0.01, 0)}, {Vec3(deficit_j / 1e-4, 0, 0), Vec3::Zero()},
            now);
}

TEST(PassivityController, EncoderDitherAtRestNeitherShakesNorFeedsTheController) {
  // A finger held still on the edge of an encoder count: its position flickers by one count.
  // The one-tick difference says ±4 mm/s; a 20 N·s/m damper on it would step the force by
  // 0.16 N from tick to tick and, held over the next tick against the next flicker, do
  // negative work in the observer's account, deepening the deficit it is meant to remove.
  PassivityGuard g;
  std::mt19937 rng(3);
  auto dither = [&rng] { return Vec3(1e-4 + ((rng() & 1u) ? kQuantumM : 0.0), 0, 0); };
  const Vec3 index(0, 0.01, 0);
  int64_t now = kNsPerS;
  Vec3 p = dither();
  for (int i = 0; i < 50; ++i, now += kNsPerMs) {
    p = dither();
    g.observe({p, index}, zero(), now);
    ASSERT_EQ(g.control(zero()).damping_ns_per_m, 0.0) << "no deficit, no damping";
  }
  // A deficit of 0.1 mJ: on one flicker up, the device pushed 25 N along it.
  const Vec3 up = Vec3(1e-4 + kQuantumM, 0, 0);
  const Vec3 down = Vec3(1e-4, 0, 0);
  g.observe({down, index}, zero(), now);
  now += kNsPerMs;
  g.observe({up, index}, {Vec3(1e-4 / kQuantumM, 0, 0), Vec3::Zero()}, now);
  const double start_j = g.energyJ();
  ASSERT_NEAR(start_j, -1e-4, 1e-12);

  PerFinger<Vec3> last = zero();
  double largest_added = 0.0, largest_step = 0.0;
  for (int i = 0; i < 2000; ++i) {
    now += kNsPerMs;
    g.observe({dither(), index}, last, now);
    const PassivityOutput out = g.control(zero());  // the added force alone
    for (int k = 0; k < 2; ++k) {
      largest_added = std::max(largest_added, out.force_n[k].norm());
      largest_step = std::max(largest_step, (out.force_n[k] - last[k]).norm());
    }
    last = out.force_n;
  }
  // At most one count over the 20-tick window: 0.2 mm/s, 4 mN at the largest damping.
  EXPECT_LE(largest_added, 0.0041) << "N: damping quantization noise";
  EXPECT_LE(largest_step, 0.0081) << "N per tick";
  EXPECT_GE(g.energyJ(), start_j - 1e-8) << "the controller must not deepen the deficit";
}

TEST(PassivityController, AddedForceSwitchesOnAndOffWithoutSteps) {
  // The thimbles oscillate at 3 Hz, 1 mm amplitude (19 mm/s at the peak). A deficit appears
  // at rest (t = 0, zero speed) and must be dissipated as the motion picks up; the damping
  // that does it would be 20 N·s/m × 19 mm/s = 0.38 N if it switched on or off at once.
  const loop::PassivityConfig config;
  PassivityGuard g(config);
  int64_t now = kNsPerS;
  preloadDeficit(g, 2e-5, now);
  PerFinger<Vec3> last = zero();
  PerFinger<Vec3> last_v = g.velocity();
  double largest_step = 0.0;
  int active = 0;
  for (int i = 1; i <= 1000; ++i) {
    now += kNsPerMs;
    const double x = 1e-4 + 1e-3 * std::sin(2 * kPi * 3.0 * i * 1e-3);
    g.observe({Vec3(x, 0, 0), Vec3(x, 0.01, 0)}, last, now);
    const PassivityOutput out = g.control(zero());  // the added force alone
    active += out.damping_ns_per_m > 0.0;
    for (int k = 0; k < 2; ++k) {
      const double step = (out.force_n[k] - last[k]).norm();
      largest_step = std::max(largest_step, step);
      // The damping moves by at most max_force_rate·dt worth of force; the rest of a step
      // is the damped velocity's own change.
      const double bound = config.max_force_rate_n_per_s * 1e-3 +
                           config.max_damping_ns_per_m * (g.velocity()[k] - last_v[k]).norm();
      ASSERT_LE(step, bound + 1e-12) << "tick " << i << ", finger " << k;
    }
    last = out.force_n;
    last_v = g.velocity();
  }
  EXPECT_GT(active, 5) << "the controller did act";
  EXPECT_GE(g.energyJ(), -1e-9) << "and dissipated the whole deficit";
  EXPECT_LT(largest_step, 0.08) << "N per tick, well under the safety gate's 0.2 N";
}

/// Runs the haptic loop with the simulated MF-2 mobilizing the healthy joint (3 Hz, 12-16 N),
/// the device started `head_start_ns` before the loop (its clinician already pushing).
struct MobilizationRun {
  uint64_t rate_limited = 0;
  double last_rate_limited_s = -1.0;
  uint64_t passivity_ticks = 0;
  double lowest_energy_j = 0.0;
};

MobilizationRun mobilize(int64_t head_start_ns, double seconds) {
  const JointModelParams model = healthyIndexMcp();
  ManualClock clock(kNsPerS);
  devices::SimulatedMf2 dev(model, OperatorConfig{}, clock);
  clock.advance(head_start_ns);
  loop::HapticLoop hl(dev, clock, model, SafetyLimits{});
  MobilizationRun r;
  Sample s;
  const int ticks = static_cast<int>(seconds * 1000.0);
  for (int i = 0; i < ticks; ++i) {
    clock.advance(kNsPerMs);
    hl.step();
    while (hl.samples().tryPop(s)) {
      if (s.flags & sample_flags::kSafetyRateLimited) {
        ++r.rate_limited;
        r.last_rate_limited_s = static_cast<double>(s.seq) * 1e-3;
      }
    }
  }
  r.passivity_ticks = hl.health().passivity_activations.load();
  r.lowest_energy_j = hl.health().passivity_min_energy_j.load();
  EXPECT_EQ(hl.health().rate_limited.load(), r.rate_limited);
  return r;
}

TEST(PassivityInTheLoop, MobilizationWithTheSimulatedMf2IsNotRateLimited) {
  // The joint renders 0.15 N at 0° while the clinician's push is still ramping up, so the
  // finger first yields into extension and the rendered joint gives back energy it never
  // took in (E < 0): the controller damps that, smoothly. Only the very first tick is rate
  // limited (the gate ramps from zero).
  const MobilizationRun r = mobilize(0, 4.0);
  EXPECT_GT(r.passivity_ticks, 0u) << "the controller removes the start-up deficit";
  EXPECT_LE(r.rate_limited, 1u) << "the last at " << r.last_rate_limited_s << " s";
  EXPECT_LE(r.last_rate_limited_s, 0.0);
  // Observing only, the joint's release reaches -57 µJ; the controller must not deepen it.
  EXPECT_GT(r.lowest_energy_j, -4e-5);
}

TEST(PassivityInTheLoop, LateStartRateLimitsOnlyTheJointSwitchingOn) {
  // The device runs 0.3 s before the loop: the clinician's push has moved the finger freely
  // to 38° of flexion, where the joint holds 1.2 N, all on the thumb (the pushing finger,
  // docs/facts.md "Force split"). Switching the joint on there is a real step the gate ramps
  // (0.2 N per tick); nothing after it is rate limited.
  const MobilizationRun r = mobilize(300 * kNsPerMs, 4.0);
  EXPECT_GE(r.rate_limited, 3u);
  EXPECT_LE(r.rate_limited, 10u);
  EXPECT_LT(r.last_rate_limited_s, 0.010) << "s";
  EXPECT_LT(r.lowest_energy_j, 0.0) << "the joint gave back what it never took in";
  EXPECT_GT(r.lowest_energy_j, -1e-3) << "J, the teleoperation benchmark's passivity bound";
}

TEST(PassivityInTheLoop, ALateTickLowersTheDampingBoundsForASecond) {
  // The simulated MF-2 (50 g, its command acting on the next step): at 1 kHz the joint renders
  // at most 25 N·s/m and the controller adds at most 20. A tick 8 ms late holds the force 8
  // times longer: for the next second both follow that tick (the joint the whole limit at
  // 8 ms, 2·cos(π/3)·m/T = 6.25 N·s/m, the controller 0.4 of it), then return.
  ManualClock clock(kNsPerS);
  const JointModelParams model = healthyIndexMcp();
  devices::SimulatedMf2 dev(model, OperatorConfig{}, clock);
  loop::HapticLoop hl(dev, clock, model, SafetyLimits{});
  Sample s;
  auto tick = [&](int64_t ns) {
    clock.advance(ns);
    hl.step();
    while (hl.samples().tryPop(s)) {
    }
  };
  const auto& h = hl.health();
  for (int i = 0; i < 100; ++i) tick(kNsPerMs);
  EXPECT_DOUBLE_EQ(h.joint_damping_cap_ns_per_m.load(), kMaxDeviceDampingNsPerM);
  EXPECT_DOUBLE_EQ(h.passivity_bound_ns_per_m.load(), 20.0);
  EXPECT_DOUBLE_EQ(h.passivity_bound_lowest_ns_per_m.load(), 20.0) << "none late yet";
  EXPECT_DOUBLE_EQ(h.joint_damping_cap_lowest_ns_per_m.load(), kMaxDeviceDampingNsPerM);
  tick(8 * kNsPerMs);
  const double late = stableDampingNsPerM(0.05, 1, 0.008);
  EXPECT_NEAR(late, 6.25, 1e-9);
  EXPECT_NEAR(h.joint_damping_cap_ns_per_m.load(), late, 1e-9);
  EXPECT_NEAR(h.passivity_bound_ns_per_m.load(), 0.4 * late, 1e-9);
  EXPECT_NEAR(hl.proxy().model().deviceDampingCapNsPerM(), late, 1e-9) << "the rendered cap";
  for (int i = 0; i < 900; ++i) tick(kNsPerMs);
  EXPECT_NEAR(h.passivity_bound_ns_per_m.load(), 0.4 * late, 1e-9) << "held within the second";
  for (int i = 0; i < 200; ++i) tick(kNsPerMs);
  EXPECT_DOUBLE_EQ(h.joint_damping_cap_ns_per_m.load(), kMaxDeviceDampingNsPerM);
  EXPECT_DOUBLE_EQ(h.passivity_bound_ns_per_m.load(), 20.0);
  // What the client's summary prints: the bounds at the nominal tick all along, and the
  // lowest they were lowered to.
  EXPECT_DOUBLE_EQ(h.joint_damping_cap_nominal_ns_per_m.load(), kMaxDeviceDampingNsPerM);
  EXPECT_DOUBLE_EQ(h.passivity_bound_nominal_ns_per_m.load(), 20.0);
  EXPECT_NEAR(h.joint_damping_cap_lowest_ns_per_m.load(), late, 1e-9);
  EXPECT_NEAR(h.passivity_bound_lowest_ns_per_m.load(), 0.4 * late, 1e-9);
  // A 2 ms tick: the joint's 25 N·s/m is the whole limit there and stays; the controller
  // gets 10.
  tick(2 * kNsPerMs);
  EXPECT_DOUBLE_EQ(h.joint_damping_cap_ns_per_m.load(), kMaxDeviceDampingNsPerM);
  EXPECT_NEAR(h.passivity_bound_ns_per_m.load(), 10.0, 1e-9);
  EXPECT_DOUBLE_EQ(h.passivity_bound_nominal_ns_per_m.load(), 20.0);
  EXPECT_NEAR(h.passivity_bound_lowest_ns_per_m.load(), 0.4 * late, 1e-9) << "still the lowest";
}

}  // namespace
}  // namespace telehand::client
