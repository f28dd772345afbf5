// The haptic loop's fault detector: a diverging rendering, a force held at the clamp and a
// runaway past the range each latch their fault, zero the force, and a normal session does
// not trip it.
#include <gtest/gtest.h>

#include "../../stability/stability_run.h"
#include "telehand/client/loop/haptic_loop.h"
#include "telehand/core/clock.h"
#include "telehand/devices/simulated_mf2.h"

namespace telehand::client {
namespace {

using loop::HapticLoop;
using loop::LoopFault;

struct FaultRun {
  LoopFault fault = LoopFault::kNone;
  double fault_s = 0.0;
  uint64_t clamps = 0;
  double peak_n = 0.0;
  double force_after_n = 0.0;  ///< commanded per-finger force 100 ms after the fault
};

/// Mobilizes `model` (3 Hz, 12-16 N) for up to `seconds`; `direct_n` > 0 renders that
/// constant force per finger instead of the model (direct mode, no server).
FaultRun mobilize(const JointModelParams& model, double seconds, loop::TeleopOptions teleop,
                  double direct_n = -1.0) {
  ManualClock clock(kNsPerS);
  devices::SimulatedMf2 dev(model, OperatorConfig{}, clock);
  if (direct_n >= 0.0) teleop.render = loop::RenderMode::kDirect;
  HapticLoop hl(dev, clock, model, SafetyLimits{}, LoopConfig{}, teleop);
  if (direct_n > 0.0) {
    loop::DirectForceSample f;
    f.force_n = {Vec3(0, 0, direct_n), Vec3(0, 0, -direct_n)};
    hl.directForces().tryPush(f);
  }
  FaultRun r;
  Sample s;
  int after = -1;
  for (int i = 0; i < static_cast<int>(seconds * 1000); ++i) {
    clock.advance(kNsPerMs);
    hl.step();
    while (hl.samples().tryPop(s)) {
    }
    if (after < 0 && hl.fault() != LoopFault::kNone) after = i + 100;
    if (i == after) {
      r.force_after_n = std::max(dev.renderedForce()[0].norm(), dev.renderedForce()[1].norm());
      break;
    }
  }
  const auto& h = hl.health();
  r.fault = hl.fault();
  r.fault_s = static_cast<double>(h.fault_time_ns.load()) * 1e-9;
  r.clamps = h.fault_clamps.load();
  r.peak_n = h.fault_peak_force_n.load();
  return r;
}

TEST(FaultDetector, ADivergingRenderingIsDetected) {
  // A joint 300 times stiffer than the paper's (tens of N/mm at the device, far past what
  // 1 kHz renders: docs/facts.md "Stable wall"), without the passivity controller.
  JointModelParams stiff = healthyIndexMcp();
  for (auto& axis : stiff.axes) {
    for (double& c : axis.coeffs) c *= 300.0;
  }
  loop::TeleopOptions teleop;
  teleop.passivity.control = false;
  const FaultRun r = mobilize(stiff, 10.0, teleop);
  // Whichever shows first: the force storming the clamp or the phalanx thrown off its range.
  EXPECT_NE(r.fault, LoopFault::kNone);
  EXPECT_GT(r.clamps, 0u);
  EXPECT_GT(r.peak_n, 4.0);
  EXPECT_LT(r.fault_s, 5.0);
  EXPECT_LT(r.force_after_n, 1e-9) << "after the fault the loop renders nothing";
}

TEST(FaultDetector, AForceHeldAtTheClampIsASustainedClamp) {
  // 10 N per finger asked for and held: clamped once, and for good.
  const FaultRun r = mobilize(healthyIndexMcp(), 2.0, {}, 10.0);
  EXPECT_EQ(r.fault, LoopFault::kSustainedClamp) << loop::faultName(r.fault);
  EXPECT_NEAR(r.fault_s, 0.25, 0.01);
  EXPECT_GE(r.clamps, 250u);
  EXPECT_NEAR(r.peak_n, 10.0, 0.1) << "asked 10 N (plus the passivity controller's damping)";
  EXPECT_LT(r.force_after_n, 1e-9);
}

TEST(FaultDetector, AJointPushedFarPastItsRangeIsARunaway) {
  // Nothing rendered (direct mode, no server force): the push takes the phalanx through the
  // model's short flexion range and on.
  JointModelParams shortRange = healthyIndexMcp();
  shortRange.axes[kFlexion].max_deg = 20.0;
  const FaultRun r = mobilize(shortRange, 5.0, {}, 0.0);
  EXPECT_EQ(r.fault, LoopFault::kRangeRunaway) << loop::faultName(r.fault);
  EXPECT_EQ(r.clamps, 0u);
}

TEST(FaultDetector, ANormalSessionDoesNotTripIt) {
  for (const double hz : {1.0, 6.0}) {
    const stability::RunResult r =
        stability::runStability(healthyIndexMcp(), stability::Motion::kMobilization, hz, 10.0, 3);
    EXPECT_EQ(r.fault, LoopFault::kNone) << hz;
    EXPECT_EQ(r.clamps, 0u) << hz;
  }
}

TEST(FaultDetector, DisabledItNeverTrips) {
  loop::TeleopOptions teleop;
  teleop.fault.enabled = false;
  const FaultRun r = mobilize(healthyIndexMcp(), 1.0, teleop, 10.0);
  EXPECT_EQ(r.fault, LoopFault::kNone);
}

}  // namespace
}  // namespace telehand::client
