// Time per 1 kHz tick: the whole HapticLoop::step() and its two heaviest parts alone.
// "Time" is ns per tick (one iteration = one tick).
#include <benchmark/benchmark.h>

#include <cmath>
#include <vector>

#include "telehand/client/loop/haptic_loop.h"
#include "telehand/core/clock.h"
#include "telehand/core/joint_model.h"
#include "telehand/core/safety.h"
#include "telehand/devices/simulated_mf2.h"

namespace telehand {
namespace {

/// step() with a simulated MF-2 mid-mobilization; the clock advances 1 ms per tick, so the
/// device integrates one 1 ms step per tick as it would live.
void BM_HapticLoopStep(benchmark::State& state) {
  const JointModelParams model = healthyIndexMcp();
  ManualClock clock(kNsPerS);
  devices::SimulatedMf2 dev(model, OperatorConfig{}, clock);
  client::loop::HapticLoop loop(dev, clock, model, SafetyLimits{});
  Sample s;
  // Past the operator's ramp, into the 12-16 N oscillation.
  for (int i = 0; i < 2000; ++i) {
    clock.advance(kNsPerMs);
    loop.step();
    while (loop.samples().tryPop(s)) {
    }
  }
  int64_t ticks = 0;
  for (auto _ : state) {
    clock.advance(kNsPerMs);
    benchmark::DoNotOptimize(loop.step());
    if (++ticks % 8192 == 0) {  // the link thread's job: keep the sample ring from filling
      state.PauseTiming();
      while (loop.samples().tryPop(s)) {
      }
      state.ResumeTiming();
    }
  }
  state.counters["dropped"] = static_cast<double>(loop.health().samples_dropped.load());
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_HapticLoopStep);

/// JointProxy::render alone: grip -> angles -> passive torque -> fingertip forces.
void BM_JointProxyRender(benchmark::State& state) {
  const JointModelParams model = healthyIndexMcp();
  const JointModel m(model);
  std::vector<PerFinger<Vec3>> grips;
  for (int i = 0; i < 1000; ++i) {  // 1 s of a 3 Hz flexion oscillation
    const double t = i * 1e-3;
    grips.push_back(m.gripFromAngles(
        Vec3(degToRad(65.0 + 5.0 * std::sin(2 * kPi * 3.0 * t)), degToRad(2.0), degToRad(1.0)),
        0.008));
  }
  JointProxy proxy(model);
  int64_t now = 0;
  std::size_t i = 0;
  for (auto _ : state) {
    now += kNsPerMs;
    ProxyOutput out = proxy.render(grips[i], now);
    benchmark::DoNotOptimize(out);
    i = i + 1 == grips.size() ? 0 : i + 1;
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_JointProxyRender);

/// The same during a model cross-fade (renders both models).
void BM_JointProxyRenderBlending(benchmark::State& state) {
  const JointModelParams model = healthyIndexMcp();
  JointModelParams other = model;
  other.version = 2;
  other.axes[kFlexion].coeffs = {3e-5, 0.002, 0.08, 1.0};
  const JointModel m(model);
  const PerFinger<Vec3> grip = m.gripFromAngles(Vec3(degToRad(60.0), 0.0, 0.0), 0.008);
  JointProxy proxy(model, INT64_MAX / 4);  // a blend that never ends
  proxy.setModel(other);
  int64_t now = 0;
  for (auto _ : state) {
    now += kNsPerMs;
    ProxyOutput out = proxy.render(grip, now);
    benchmark::DoNotOptimize(out);
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_JointProxyRenderBlending);

/// SafetyGate::apply alone, with requests that alternate so that the clamp and the rate
/// limit both work.
void BM_SafetyGateApply(benchmark::State& state) {
  SafetyGate gate;
  const PerFinger<Vec3> requests[2] = {{Vec3(1.0, 2.0, 3.0), Vec3(-0.5, 0.2, 0.1)},
                                       {Vec3(0.9, 2.1, 2.9), Vec3(-0.4, 0.3, 0.1)}};
  int64_t now = 0;
  int k = 0;
  for (auto _ : state) {
    now += kNsPerMs;
    SafetyOutput out = gate.apply(requests[k], now, now);
    benchmark::DoNotOptimize(out);
    k ^= 1;
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_SafetyGateApply);

}  // namespace
}  // namespace telehand

BENCHMARK_MAIN();
