// Direct mode (the server computes the force): the loop renders the newest server force it
// took, no longer than TeleopOptions::direct_max_age_ns after it took it, and refuses forces
// for samples it has not produced yet. On a manual clock.
#include <gtest/gtest.h>

#include <algorithm>

#include "telehand/client/loop/haptic_loop.h"
#include "telehand/core/clock.h"
#include "telehand/devices/simulated_mf2.h"

namespace telehand::client {
namespace {

using loop::HapticLoop;

/// A direct-mode loop on the simulated MF-2 whose passivity controller only observes, so that
/// what the device renders is the server's force through the safety gate.
class DirectForceTest : public ::testing::Test {
 protected:
  static loop::TeleopOptions directOptions() {
    loop::TeleopOptions teleop;
    teleop.render = loop::RenderMode::kDirect;
    teleop.passivity.control = false;
    return teleop;
  }

  /// The server's answer to the newest sample the loop produced: `n` newtons per finger.
  void serverAnswers(double n) {
    ASSERT_GT(hl_.nextSeq(), 0u) << "no sample produced yet";
    pushForce(hl_.nextSeq() - 1, n);
  }
  void pushForce(uint64_t device_seq, double n) {
    loop::DirectForceSample f;
    f.device_seq = device_seq;
    f.force_n = {Vec3(0, 0, n), Vec3(0, 0, -n)};
    ASSERT_TRUE(hl_.directForces().tryPush(f));
  }
  /// One 1 ms tick; the samples go nowhere.
  void tick() {
    clock_.advance(kNsPerMs);
    hl_.step();
    Sample s;
    while (hl_.samples().tryPop(s)) {
    }
  }
  /// `ms` ticks, the server answering each sample with `n` N (negative: silent).
  void run(int ms, double n) {
    for (int i = 0; i < ms; ++i) {
      if (n >= 0.0) serverAnswers(n);
      tick();
    }
  }
  double renderedN() const {
    return std::max(dev_.renderedForce()[0].norm(), dev_.renderedForce()[1].norm());
  }

  ManualClock clock_{kNsPerS};
  devices::SimulatedMf2 dev_{healthyIndexMcp(), OperatorConfig{}, clock_};
  HapticLoop hl_{dev_, clock_, healthyIndexMcp(), SafetyLimits{}, LoopConfig{}, directOptions()};
};

TEST_F(DirectForceTest, AServerThatStopsSendingLeavesNoForceHeldPastTheAgeLimit) {
  ASSERT_EQ(loop::TeleopOptions{}.direct_max_age_ns, 100 * kNsPerMs) << "the DeviceState deadline";
  tick();
  run(100, 2.0);
  EXPECT_NEAR(renderedN(), 2.0, 1e-9) << "the server's force, through the gate's rate limit";
  EXPECT_EQ(hl_.health().direct_stale_ticks.load(), 0u);

  // The server falls silent: its last force is held for the age limit, and no longer.
  run(100, -1.0);
  EXPECT_NEAR(renderedN(), 2.0, 1e-9) << "100 ms old: still within the limit";
  EXPECT_EQ(hl_.health().direct_stale_ticks.load(), 0u);
  run(1, -1.0);
  EXPECT_LT(renderedN(), 2.0) << "past the limit the force ramps down";
  EXPECT_EQ(hl_.health().direct_stale_ticks.load(), 1u);
  EXPECT_EQ(hl_.health().direct_stale_gaps.load(), 1u);
  run(30, -1.0);
  EXPECT_EQ(renderedN(), 0.0) << "nothing rendered from the silent server";
  run(2000, -1.0);
  EXPECT_EQ(renderedN(), 0.0) << "and for as long as it stays silent";
  EXPECT_EQ(hl_.health().direct_stale_ticks.load(), 2031u);
  EXPECT_EQ(hl_.health().direct_stale_gaps.load(), 1u);

  // Fresh forces (a server that took the session over): rendered again at once.
  run(1, 1.5);
  EXPECT_GT(renderedN(), 0.0);
  run(30, 1.5);
  EXPECT_NEAR(renderedN(), 1.5, 1e-9);
  EXPECT_EQ(hl_.health().direct_stale_ticks.load(), 2031u) << "fresh again";
  EXPECT_EQ(hl_.health().direct_stale_gaps.load(), 1u);
  EXPECT_EQ(hl_.fault(), loop::LoopFault::kNone) << loop::faultName(hl_.fault());

  // A second silence is a second gap.
  run(150, -1.0);
  EXPECT_EQ(renderedN(), 0.0);
  EXPECT_EQ(hl_.health().direct_stale_gaps.load(), 2u);
}

TEST_F(DirectForceTest, BeforeTheFirstServerForceNothingIsStale) {
  // The first force comes a round trip after the start: not a server that went silent.
  run(500, -1.0);
  EXPECT_EQ(renderedN(), 0.0);
  EXPECT_EQ(hl_.health().direct_stale_ticks.load(), 0u);
  EXPECT_EQ(hl_.health().direct_stale_gaps.load(), 0u);
}

TEST_F(DirectForceTest, AForceForASampleNotProducedYetIsRefused) {
  tick();
  run(50, 1.0);
  ASSERT_NEAR(renderedN(), 1.0, 1e-9);
  // A forged answer to a sample far ahead, then the sample about to be produced: neither
  // is taken, and the server's real answers go on being rendered.
  pushForce(hl_.nextSeq() + 1'000'000, 3.0);
  pushForce(hl_.nextSeq(), 3.0);
  tick();
  EXPECT_NEAR(renderedN(), 1.0, 1e-9) << "the forged force was not rendered";
  EXPECT_EQ(hl_.health().direct_forces_ahead.load(), 2u);
  const uint64_t taken = hl_.health().direct_forces.load();
  run(500, 1.5);
  EXPECT_NEAR(renderedN(), 1.5, 1e-9) << "later answers are taken, not held off by the forgery";
  EXPECT_EQ(hl_.health().direct_forces.load(), taken + 500);
  EXPECT_EQ(hl_.health().direct_stale_ticks.load(), 0u);
  EXPECT_EQ(hl_.health().direct_forces_ahead.load(), 2u);
}

TEST_F(DirectForceTest, AReorderedOlderForceDoesNotReplaceTheNewest) {
  tick();
  run(50, 1.0);
  const uint64_t newest = hl_.nextSeq() - 1;
  pushForce(newest, 2.0);
  pushForce(newest - 10, 0.5);  // overtaken on the way
  run(50, -1.0);
  EXPECT_NEAR(renderedN(), 2.0, 1e-9);
  EXPECT_EQ(hl_.health().direct_forces_ahead.load(), 0u);
}

}  // namespace
}  // namespace telehand::client
