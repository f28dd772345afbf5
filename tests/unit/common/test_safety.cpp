// The one gate every force passes (docs/design.md "House style"): finite check, per-finger clamp
// to 4 N, rate limit, watchdog; a fault commands zero at once.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include "telehand/core/safety.h"

namespace telehand {
namespace {

constexpr int64_t kTickNs = 1'000'000;
constexpr double kMaxStepPerTick = 200.0 * 1e-3;  // default 200 N/s at 1 kHz

/// Drives a gate at 1 kHz with fresh samples, as the loop does.
class GateDriver {
 public:
  explicit GateDriver(const SafetyLimits& limits = {}) : gate(limits) {}
  SafetyOutput tick(const PerFinger<Vec3>& request) {
    now += kTickNs;
    return gate.apply(request, now, now);
  }
  SafetyOutput tickStale(const PerFinger<Vec3>& request, int64_t sample_age_ns) {
    now += kTickNs;
    return gate.apply(request, now, now - sample_age_ns);
  }
  /// Ticks until the output stops changing (rate limit done).
  SafetyOutput settle(const PerFinger<Vec3>& request) {
    SafetyOutput out;
    for (int i = 0; i < 200; ++i) out = tick(request);
    return out;
  }
  SafetyGate gate;
  int64_t now = 1'000'000'000;
};

bool isZero(const SafetyOutput& o) { return o.force_n[0].isZero() && o.force_n[1].isZero(); }

TEST(SafetyGate, PassesAReasonableForceAfterTheRamp) {
  GateDriver d;
  const PerFinger<Vec3> req{Vec3(1.0, -0.5, 2.0), Vec3(-0.3, 0.2, 0.1)};
  const SafetyOutput out = d.settle(req);
  EXPECT_EQ(out.flags, 0u);
  EXPECT_EQ(out.force_n[0], req[0]);
  EXPECT_EQ(out.force_n[1], req[1]);
}

TEST(SafetyGate, NanCommandsZeroAtOnceOnBothFingers) {
  GateDriver d;
  d.settle({Vec3(2.0, 0.0, 0.0), Vec3(0.0, 2.0, 0.0)});
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const SafetyOutput out = d.tick({Vec3(nan, 0.0, 0.0), Vec3(0.0, 2.0, 0.0)});
  EXPECT_TRUE(isZero(out)) << "one bad finger zeroes both";
  EXPECT_TRUE(out.flags & kSafetyNonFinite);
  EXPECT_FALSE(out.flags & kSafetyWatchdog);
}

TEST(SafetyGate, InfinityCommandsZero) {
  for (double inf :
       {std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity()}) {
    GateDriver d;
    d.settle({Vec3(1.0, 1.0, 1.0), Vec3(1.0, 1.0, 1.0)});
    const SafetyOutput out = d.tick({Vec3(1.0, 1.0, 1.0), Vec3(0.0, 0.0, inf)});
    EXPECT_TRUE(isZero(out)) << inf;
    EXPECT_EQ(out.flags, static_cast<uint32_t>(kSafetyNonFinite)) << inf;
  }
}

TEST(SafetyGate, RecoveryFromANonFiniteFaultRampsFromZero) {
  GateDriver d;
  const PerFinger<Vec3> req{Vec3(0.0, 0.0, 3.0), Vec3(0.0, 3.0, 0.0)};
  d.settle(req);
  d.tick({Vec3::Constant(std::nan("")), req[1]});
  const SafetyOutput first = d.tick(req);
  EXPECT_NEAR(first.force_n[0].norm(), kMaxStepPerTick, 1e-12);
  EXPECT_TRUE(first.flags & kSafetyRateLimited);
}

TEST(SafetyGate, HugeForceIsClampedTo4NKeepingItsDirection) {
  GateDriver d;
  const Vec3 dir = Vec3(1.0, 2.0, -3.0).normalized();
  const PerFinger<Vec3> req{1e9 * dir, -1e9 * dir};
  const SafetyOutput out = d.settle(req);
  for (int k = 0; k < 2; ++k) {
    EXPECT_NEAR(out.force_n[k].norm(), 4.0, 1e-12) << k;
    const Vec3 want = k == 0 ? dir : Vec3(-dir);
    EXPECT_GT(out.force_n[k].normalized().dot(want), 1.0 - 1e-12) << k;
  }
  EXPECT_TRUE(out.flags & kSafetyClamped);
  EXPECT_FALSE(out.flags & kSafetyRateLimited);
}

TEST(SafetyGate, ClampIsPerFinger) {
  GateDriver d;
  const SafetyOutput out = d.settle({Vec3(5.0, 0.0, 0.0), Vec3(0.0, 3.0, 0.0)});
  EXPECT_NEAR(out.force_n[0].x(), 4.0, 1e-12);
  EXPECT_EQ(out.force_n[1], Vec3(0.0, 3.0, 0.0)) << "the other finger keeps its force";
}

TEST(SafetyGate, ConfiguredMaximumIsHonoured) {
  SafetyLimits limits;
  limits.max_force_n = 1.5;
  GateDriver d(limits);
  const SafetyOutput out = d.settle({Vec3(0.0, 0.0, -10.0), Vec3(0.0, 0.0, 1.0)});
  EXPECT_NEAR(out.force_n[0].z(), -1.5, 1e-12);
  EXPECT_NEAR(out.force_n[1].z(), 1.0, 1e-12);
}

TEST(SafetyGate, SuddenJumpIsRateLimited) {
  GateDriver d;
  d.settle({Vec3::Zero(), Vec3::Zero()});
  const PerFinger<Vec3> req{Vec3(0.0, 3.0, 0.0), Vec3(0.0, 0.0, -2.0)};
  Vec3 prev = Vec3::Zero();
  int ticks = 0;
  SafetyOutput out;
  do {
    out = d.tick(req);
    EXPECT_LE((out.force_n[0] - prev).norm(), kMaxStepPerTick + 1e-12) << ticks;
    // Moves straight toward the request.
    EXPECT_NEAR(out.force_n[0].x(), 0.0, 1e-15);
    prev = out.force_n[0];
    ++ticks;
  } while (out.force_n[0] != req[0] && ticks < 100);
  EXPECT_GE(ticks, 15) << "3 N at 0.2 N per tick";
  EXPECT_LE(ticks, 16) << "3 N at 0.2 N per tick (one more for rounding)";
  EXPECT_EQ(out.force_n[1], req[1]);
  EXPECT_EQ(d.tick(req).flags, 0u) << "no flag once the request is reached";
}

TEST(SafetyGate, RateLimitScalesWithTheTimeStep) {
  SafetyGate gate;
  gate.apply({Vec3::Zero(), Vec3::Zero()}, 0, 0);
  // 10 ms later: up to 2 N.
  const SafetyOutput out =
      gate.apply({Vec3(3.0, 0.0, 0.0), Vec3(1.0, 0.0, 0.0)}, 10'000'000, 10'000'000);
  EXPECT_NEAR(out.force_n[0].x(), 2.0, 1e-12);
  EXPECT_NEAR(out.force_n[1].x(), 1.0, 1e-12);
  EXPECT_TRUE(out.flags & kSafetyRateLimited);
}

TEST(SafetyGate, TimeGoingBackwardsHoldsTheLastForce) {
  SafetyGate gate;
  gate.apply({Vec3::Zero(), Vec3::Zero()}, 0, 0);
  const SafetyOutput a = gate.apply({Vec3(1.0, 0, 0), Vec3::Zero()}, 5'000'000, 5'000'000);
  const SafetyOutput b = gate.apply({Vec3(4.0, 0, 0), Vec3::Zero()}, 4'000'000, 4'000'000);
  EXPECT_EQ(b.force_n[0], a.force_n[0]);
}

TEST(SafetyGate, StaleSampleCommandsZeroAtOnce) {
  GateDriver d;
  const PerFinger<Vec3> req{Vec3(0.0, 0.0, 3.0), Vec3(3.0, 0.0, 0.0)};
  d.settle(req);
  // Exactly at the limit is still fresh; one nanosecond more trips the watchdog.
  const SafetyOutput fresh = d.tickStale(req, 5'000'000);
  EXPECT_FALSE(fresh.flags & kSafetyWatchdog);
  EXPECT_NEAR(fresh.force_n[0].z(), 3.0, 1e-12);
  const SafetyOutput stale = d.tickStale(req, 5'000'001);
  EXPECT_TRUE(isZero(stale)) << "no ramp down: zero at once";
  EXPECT_EQ(stale.flags, static_cast<uint32_t>(kSafetyWatchdog));
  // Stays zero while stale.
  for (int i = 0; i < 10; ++i) EXPECT_TRUE(isZero(d.tickStale(req, 20'000'000)));
}

TEST(SafetyGate, RecoveryFromTheWatchdogRampsThroughTheRateLimit) {
  GateDriver d;
  const PerFinger<Vec3> req{Vec3(0.0, 0.0, 3.0), Vec3(3.0, 0.0, 0.0)};
  d.settle(req);
  d.tickStale(req, 50'000'000);
  Vec3 prev = Vec3::Zero();
  for (int i = 0; i < 15; ++i) {
    const SafetyOutput out = d.tick(req);
    EXPECT_FALSE(out.flags & kSafetyWatchdog);
    EXPECT_NEAR(out.force_n[0].norm(), std::min(3.0, (i + 1) * kMaxStepPerTick), 1e-9) << i;
    EXPECT_LE((out.force_n[0] - prev).norm(), kMaxStepPerTick + 1e-12);
    prev = out.force_n[0];
  }
  EXPECT_NEAR(prev.z(), 3.0, 1e-12);
}

TEST(SafetyGate, ConfiguredWatchdogIsHonoured) {
  SafetyLimits limits;
  limits.watchdog_ns = 20'000'000;
  GateDriver d(limits);
  d.settle({Vec3(1.0, 0, 0), Vec3::Zero()});
  EXPECT_FALSE(d.tickStale({Vec3(1.0, 0, 0), Vec3::Zero()}, 15'000'000).flags & kSafetyWatchdog);
  EXPECT_TRUE(d.tickStale({Vec3(1.0, 0, 0), Vec3::Zero()}, 25'000'000).flags & kSafetyWatchdog);
}

TEST(SafetyGate, BothFaultsAreReported) {
  GateDriver d;
  const SafetyOutput out = d.tickStale({Vec3::Constant(std::nan("")), Vec3::Zero()}, 1'000'000'000);
  EXPECT_TRUE(isZero(out));
  EXPECT_EQ(out.flags, static_cast<uint32_t>(kSafetyWatchdog | kSafetyNonFinite));
}

TEST(SafetyGate, ResetRampsFromZeroAgain) {
  GateDriver d;
  const PerFinger<Vec3> req{Vec3(2.0, 0, 0), Vec3(0, 2.0, 0)};
  d.settle(req);
  d.gate.reset();
  const SafetyOutput first = d.tick(req);
  EXPECT_LE(first.force_n[0].norm(), kMaxStepPerTick + 1e-12);
  EXPECT_TRUE(first.flags & kSafetyRateLimited);
}

TEST(SafetyGate, RandomAbuseNeverExceedsTheLimits) {
  std::mt19937_64 rng(12345);
  std::uniform_real_distribution<double> mag(-12.0, 12.0);  // log10 of the force
  std::uniform_real_distribution<double> comp(-1.0, 1.0);
  std::uniform_int_distribution<int> kind(0, 19);
  GateDriver d;
  PerFinger<Vec3> prev{Vec3::Zero(), Vec3::Zero()};
  for (int i = 0; i < 20000; ++i) {
    PerFinger<Vec3> req;
    for (int k = 0; k < 2; ++k)
      req[k] = Vec3(comp(rng), comp(rng), comp(rng)) * std::pow(10.0, mag(rng));
    const int what = kind(rng);
    if (what == 0) req[1].y() = std::nan("");
    if (what == 1) req[0].x() = std::numeric_limits<double>::infinity();
    const SafetyOutput out = what == 2 ? d.tickStale(req, 10'000'000) : d.tick(req);
    const bool fault = out.flags & (kSafetyWatchdog | kSafetyNonFinite);
    for (int k = 0; k < 2; ++k) {
      ASSERT_TRUE(allFinite(out.force_n[k])) << i;
      ASSERT_LE(out.force_n[k].norm(), 4.0 + 1e-12) << i;
      if (fault) {
        ASSERT_TRUE(out.force_n[k].isZero()) << i;
      } else {
        ASSERT_LE((out.force_n[k] - prev[k]).norm(), kMaxStepPerTick + 1e-9) << i;
      }
    }
    EXPECT_EQ(fault, what <= 2) << i;
    prev = out.force_n;
  }
}

TEST(SafetyGateCapture, ZeroWhateverIsRequestedThenRampsOut) {
  SafetyGate gate;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  int64_t t = 1'000'000'000;
  gate.apply({Vec3(0, 0, 3.0), Vec3::Zero()}, t, t);
  gate.setCapture(true);
  for (const PerFinger<Vec3>& req : {PerFinger<Vec3>{Vec3(0, 0, 3.0), Vec3(1, 1, 1)},
                                     PerFinger<Vec3>{Vec3(1e6, 0, 0), Vec3::Zero()},
                                     PerFinger<Vec3>{Vec3(nan, 0, 0), Vec3::Zero()}}) {
    t += 1'000'000;
    const SafetyOutput out = gate.apply(req, t, t - 100'000'000);  // even with a stale sample
    EXPECT_EQ(out.force_n[0], Vec3::Zero());
    EXPECT_EQ(out.force_n[1], Vec3::Zero());
    EXPECT_EQ(out.flags, kSafetyCapture);
  }
  gate.setCapture(false);
  t += 1'000'000;
  const SafetyOutput out = gate.apply({Vec3(0, 0, 3.0), Vec3::Zero()}, t, t);
  EXPECT_NEAR(out.force_n[0].norm(), 200.0 * 1e-3, 1e-9) << "leaves capture through the rate limit";
}

}  // namespace
}  // namespace telehand
