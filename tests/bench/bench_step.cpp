// Time per 1 kHz tick: the whole HapticLoop::step() and its two heaviest parts alone.
// "Time" is ns per tick (one iteration = one tick). The loop's cases also time every tick on
// its own (steady clock around step()) and report its median and 99th percentile (p50_ns,
// p99_ns): the mobilization (joint rendered) and the massage (web rendered; the joint proxy
// and the tissue proxy both compute every tick).
#include <benchmark/benchmark.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <vector>

#include "telehand/client/loop/haptic_loop.h"
#include "telehand/core/clock.h"
#include "telehand/core/joint_model.h"
#include "telehand/core/safety.h"
#include "telehand/core/tissue_model.h"
#include "telehand/devices/simulated_massage_mf2.h"
#include "telehand/devices/simulated_mf2.h"

namespace telehand {
namespace {

/// Steps `loop` (clock 1 ms per tick) past the operator's ramp, then once per iteration,
/// timing each step on its own; reports the median and 99th percentile of those times.
void runLoop(benchmark::State& state, client::loop::HapticLoop& loop, ManualClock& clock) {
  Sample s;
  for (int i = 0; i < 2000; ++i) {
    clock.advance(kNsPerMs);
    loop.step();
    while (loop.samples().tryPop(s)) {
    }
  }
  std::vector<int64_t> times(1 << 20);
  std::size_t n = 0;
  int64_t ticks = 0;
  for (auto _ : state) {
    clock.advance(kNsPerMs);
    const auto t0 = std::chrono::steady_clock::now();
    benchmark::DoNotOptimize(loop.step());
    const auto t1 = std::chrono::steady_clock::now();
    times[n] = std::chrono::duration_cast<std::chrono::nanoseconds>(t1 - t0).count();
    n = n + 1 == times.size() ? 0 : n + 1;
    if (++ticks % 8192 == 0) {  // the link thread's job: keep the sample ring from filling
      state.PauseTiming();
      while (loop.samples().tryPop(s)) {
      }
      state.ResumeTiming();
    }
  }
  const std::size_t have = std::min<std::size_t>(static_cast<std::size_t>(ticks), times.size());
  if (have > 0) {
    times.resize(have);
    auto at = [&](double q) {
      const auto k = static_cast<std::size_t>(q * static_cast<double>(have - 1));
      std::nth_element(times.begin(), times.begin() + static_cast<std::ptrdiff_t>(k), times.end());
      return static_cast<double>(times[k]);
    };
    state.counters["p50_ns"] = at(0.50);
    state.counters["p99_ns"] = at(0.99);
  }
  state.counters["dropped"] = static_cast<double>(loop.health().samples_dropped.load());
  state.SetItemsProcessed(state.iterations());
}

/// step() with a simulated MF-2 mid-mobilization; the clock advances 1 ms per tick, so the
/// device integrates one 1 ms step per tick as it would live.
void BM_HapticLoopStep(benchmark::State& state) {
  const JointModelParams model = healthyIndexMcp();
  ManualClock clock(kNsPerS);
  devices::SimulatedMf2 dev(model, OperatorConfig{}, clock);
  client::loop::HapticLoop loop(dev, clock, model, SafetyLimits{});
  // Past the operator's ramp, into the 12-16 N oscillation.
  runLoop(state, loop, clock);
}
BENCHMARK(BM_HapticLoopStep);

/// step() rendering the massage: the simulated MF-2's clinician circling on the healthy web
/// with 10 ± 2 N, the joint proxy and the tissue proxy both stepped every tick.
void BM_HapticLoopStepMassage(benchmark::State& state) {
  JointModelParams model = healthyIndexMcp();
  model.technique = Technique::kMassage;
  model.tissue = tissueCase("healthy");
  ManualClock clock(kNsPerS);
  devices::SimulatedMassageMf2 dev(model.tissue, OperatorConfig{}, clock, model.force_scale);
  client::loop::HapticLoop loop(dev, clock, model, SafetyLimits{});
  runLoop(state, loop, clock);
  state.counters["massage_ticks"] = static_cast<double>(loop.health().massage_ticks.load());
}
BENCHMARK(BM_HapticLoopStepMassage);

/// TissueProxy::render alone: both pads pressing the web ~10 N and circling 6 mm at 1.5 Hz.
void BM_TissueProxyRender(benchmark::State& state) {
  const TissueParams web = tissueCase("healthy");
  const TissueModel m(web);
  const double d = m.depthForForce(10.0);
  std::vector<PerFinger<Vec3>> pads;
  for (int i = 0; i < 1000; ++i) {  // 1.5 laps
    const double a = 2 * kPi * 1.5 * i * 1e-3;
    const double x = 0.006 * std::cos(a), y = 0.006 * std::sin(a);
    const double z = 0.5 * web.thickness_m + web.pad_radius_m - d;
    pads.push_back({m.fromWeb(Vec3(x, y, z)), m.fromWeb(Vec3(x, y, -z))});
  }
  TissueProxy proxy(web);
  int64_t now = 0;
  std::size_t i = 0;
  for (auto _ : state) {
    now += kNsPerMs;
    TissueOutput out = proxy.render(pads[i], now);
    benchmark::DoNotOptimize(out);
    i = i + 1 == pads.size() ? 0 : i + 1;
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_TissueProxyRender);

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
