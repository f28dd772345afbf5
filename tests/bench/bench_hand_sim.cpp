// Cost of the authoritative hand (Bullet, 24 DoF) per 1 ms step, on one core.
// "Time" is CPU time per step (one iteration = one step of every simulated hand).
// Counters:
//   rtf               real-time factor: simulated time / CPU time (1 ms per step)
//   sessions_per_core 1 kHz sessions one core can carry (each needs 1000 steps/s: = rtf
//                     for one hand; N·rtf of one round when N hands are stepped in turn)
//   track_err_deg     (pinch) worst |MCP flexion - commanded| over one more cycle after
//                     the timed steps: the figure is not bought with fidelity
// Rates are per CPU second: "rtf=64/s" reads 64 simulated seconds per second of one core.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <memory>
#include <vector>

#include "telehand/core/joint_model.h"
#include "telehand/server/sim/hand_sim.h"

namespace telehand::server::sim {
namespace {

const HandModel& hand() {
  static const HandModel m =
      HandModel::load(std::string(TELEHAND_DEPLOY_DIR) + "/hand/hand24.urdf");
  return m;
}

constexpr double kStepS = 1e-3;
constexpr int kCycleSteps = 1000;  // one second: three periods of the 3 Hz mobilization

void reportRate(benchmark::State& state, double sessions) {
  const auto steps = static_cast<double>(state.iterations());
  state.counters["rtf"] = benchmark::Counter(steps * kStepS, benchmark::Counter::kIsRate);
  state.counters["sessions_per_core"] =
      benchmark::Counter(steps * kStepS * sessions, benchmark::Counter::kIsRate);
}

/// A therapist's pinch mobilizing the index MCP at 3 Hz: flexion 50 ± 15 deg, with a little
/// abduction and axial rotation, thimbles 8 mm either side of the phalanx (the client's grip).
class Pinch {
 public:
  explicit Pinch(const JointModel& m, int phase_steps = 0) {
    for (int i = 0; i < kCycleSteps; ++i) {
      const double t = (i + phase_steps) * kStepS;
      const Vec3 a(degToRad(50.0 + 15.0 * std::sin(2 * kPi * 3.0 * t)), degToRad(2.0),
                   degToRad(1.0));
      angles_.push_back(a);
      grips_.push_back(m.gripFromAngles(a, 0.008));
    }
  }
  /// Puts the phalanx where the pinch starts and runs 3 s: contacts settle and the untouched
  /// fingers fall asleep (2 s at rest), the steady state of a session.
  void engage(HandSim& sim) {
    sim.resetMcp(angles_[0]);
    for (int i = 0; i < 3 * kCycleSteps; ++i) step(sim);
  }
  void step(HandSim& sim) {
    sim.setFingerTargets(grips_[i_], true);
    sim.step();
    i_ = i_ + 1 == kCycleSteps ? 0 : i_ + 1;
  }
  const Vec3& commanded() const { return angles_[i_ == 0 ? kCycleSteps - 1 : i_ - 1]; }

 private:
  std::vector<Vec3> angles_;
  std::vector<PerFinger<Vec3>> grips_;
  int i_ = 0;
};

/// Nobody touches the hand: spheres parked, every finger at rest (after 5 s of settling,
/// as in a session waiting for the student: the index swings to its rest angle in ~1.5 s,
/// fingers sleep after 2 s at rest).
void BM_HandSimStepIdle(benchmark::State& state) {
  static HandSim& sim = []() -> HandSim& {
    static HandSim h(hand(), healthyIndexMcp());
    for (int i = 0; i < 5000; ++i) {
      h.setFingerTargets({Vec3::Zero(), Vec3::Zero()}, false);
      h.step();
    }
    return h;
  }();
  const PerFinger<Vec3> none{Vec3::Zero(), Vec3::Zero()};
  for (auto _ : state) {
    sim.setFingerTargets(none, false);
    sim.step();
  }
  reportRate(state, 1.0);
}
BENCHMARK(BM_HandSimStepIdle)->Unit(benchmark::kMicrosecond);

/// Every finger awake: the first 2 s of a session (and of any finger that was woken) before
/// untouched fingers sleep. The worst case a server has to budget for. A new hand every
/// 1.5 s (rebuilt untimed) keeps it there.
void BM_HandSimStepAllAwake(benchmark::State& state) {
  const JointModelParams params = healthyIndexMcp();
  auto sim = std::make_unique<HandSim>(hand(), params);
  const PerFinger<Vec3> none{Vec3::Zero(), Vec3::Zero()};
  int steps = 0;
  for (auto _ : state) {
    sim->setFingerTargets(none, false);
    sim->step();
    if (++steps == 1500) {
      state.PauseTiming();
      sim = std::make_unique<HandSim>(hand(), params);
      steps = 0;
      state.ResumeTiming();
    }
  }
  reportRate(state, 1.0);
}
BENCHMARK(BM_HandSimStepAllAwake)->Unit(benchmark::kMicrosecond);

/// One pinched hand per session: warmed up once and kept across Google Benchmark's repeated
/// runs (3 s of warm-up per hand would otherwise dominate a smoke run).
struct Session {
  std::unique_ptr<HandSim> sim;
  Pinch pinch;
};
std::vector<Session>& pinchedHands(int n) {
  static std::map<int, std::vector<Session>> cache;
  auto& sessions = cache[n];
  if (sessions.empty()) {
    const JointModelParams params = healthyIndexMcp();
    const JointModel proxy(params);
    for (int k = 0; k < n; ++k) {
      sessions.push_back(
          {std::make_unique<HandSim>(hand(), params), Pinch(proxy, k * kCycleSteps / (3 * n))});
      sessions.back().pinch.engage(*sessions.back().sim);
    }
  }
  return sessions;
}

/// The pinch: both spheres on the index proximal phalanx, skin friction holding it.
void BM_HandSimStepPinch(benchmark::State& state) {
  Session& s = pinchedHands(1)[0];
  for (auto _ : state) s.pinch.step(*s.sim);
  reportRate(state, 1.0);
  double worst = 0.0;  // one more cycle, untimed
  for (int i = 0; i < kCycleSteps; ++i) {
    s.pinch.step(*s.sim);
    worst = std::max(worst, std::abs(s.sim->mcpAngles()[kFlexion] - s.pinch.commanded()[kFlexion]));
  }
  state.counters["track_err_deg"] = radToDeg(worst);
}
BENCHMARK(BM_HandSimStepPinch)->Unit(benchmark::kMicrosecond);

/// N sessions on one core: N hands, each pinched (phases spread), stepped in turn, as a
/// server thread would serve them. One iteration = one 1 ms round of all N.
void BM_HandSimRoundRobin(benchmark::State& state) {
  auto& sessions = pinchedHands(static_cast<int>(state.range(0)));
  for (auto _ : state) {
    for (Session& s : sessions) s.pinch.step(*s.sim);
  }
  reportRate(state, static_cast<double>(sessions.size()));
}
BENCHMARK(BM_HandSimRoundRobin)->Arg(1)->Arg(4)->Arg(16)->Unit(benchmark::kMicrosecond);

/// What a session's start (or a pool's take-over) pays for its hand: one HandSim built and
/// freed (the bodies, hull shapes and constraints of the 24-DoF model in a world of its own).
void BM_HandSimBuild(benchmark::State& state) {
  const JointModelParams params = healthyIndexMcp();
  for (auto _ : state) {
    auto h = std::make_unique<HandSim>(hand(), params);
    benchmark::DoNotOptimize(h.get());
  }
}
BENCHMARK(BM_HandSimBuild)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace telehand::server::sim

BENCHMARK_MAIN();
