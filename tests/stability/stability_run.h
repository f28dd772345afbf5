#pragma once
// One offline stability run: a patient case rendered by the real client pieces (HapticLoop:
// JointProxy, passivity controller, safety gate, fault detector) on the simulated MF-2, held
// by the simulated clinician mobilizing (the paper's 12-16 N band at a set frequency) or
// exploring the six directions, on a simulated clock (no DDS, faster than real time).
// Shared by the ctest suite (tests/unit/client/test_stability.cpp) and the sweep program
// (tests/bench/bench_stability.cpp).
#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "telehand/client/loop/haptic_loop.h"
#include "telehand/config/config.h"
#include "telehand/core/clock.h"
#include "telehand/devices/exploration_operator.h"
#include "telehand/devices/simulated_mf2.h"

namespace telehand::stability {

enum class Motion { kMobilization, kExploration };

struct RunResult {
  double range_excess_deg = 0.0;  ///< furthest the phalanx went past a range end
  double force_max_n = 0.0;       ///< largest per-finger force commanded (after the gate)
  double request_max_n = 0.0;     ///< largest per-finger force asked of the gate
  double min_energy_j = 0.0;      ///< lowest passivity observer energy
  uint64_t clamps = 0, rate_limited = 0, nonfinite = 0, pc_ticks = 0;
  client::loop::LoopFault fault = client::loop::LoopFault::kNone;
  bool finite = true;
  /// Per-finger force while the clinician pushes in the band (mobilization after the ramp):
  /// the larger and the smaller finger's force, device N.
  double pusher_max_n = 0.0, holder_max_n = 0.0;
  double flexion_min_deg = 1e9, flexion_max_deg = -1e9;
};

/// A guide along one period of a sine in flexion around `centre_deg`, `amplitude_deg` peak to
/// peak, the other axes at 0.
inline GuideParams sineGuide(double authority, double hz, double centre_deg, double amplitude_deg) {
  GuideParams g;
  g.authority = authority;
  g.period_s = 1.0 / hz;
  for (int k = 0; k < GuideParams::kPoints; ++k) {
    const double ph = 2.0 * kPi * k / GuideParams::kPoints;
    g.path_rad[static_cast<std::size_t>(k)] =
        Vec3(degToRad(centre_deg + amplitude_deg / 2 * std::sin(ph)), 0, 0);
  }
  return g;
}

/// The guides the late-loop checks compare around a swing: none, the demonstration's own
/// (3 Hz, the student's rhythm; only `with_demonstration`) and a supervisor's take-over at
/// 2 Hz with authority 0.67 and 1.
struct NamedGuide {
  const char* name;
  GuideParams guide;
};
inline std::vector<NamedGuide> lessonGuides(double centre_deg, double amplitude_deg,
                                            bool with_demonstration) {
  std::vector<NamedGuide> g{{"none", GuideParams{}}};
  if (with_demonstration) {
    g.push_back({"demo 3 Hz x1.00", sineGuide(1.0, 3.0, centre_deg, amplitude_deg)});
  }
  g.push_back({"take-over 2 Hz x0.67", sineGuide(0.67, 2.0, centre_deg, amplitude_deg)});
  g.push_back({"take-over 2 Hz x1.00", sineGuide(1.0, 2.0, centre_deg, amplitude_deg)});
  return g;
}

/// What a run may add to the plain rendering of the joint.
struct Extras {
  /// A lesson's guide rendered from the start (docs/lessons.md "Feel"); inactive by default.
  GuideParams guide{};
  /// A loop that runs late: this share of its ticks comes 2..max_stall_ms after the one
  /// before (uniformly, seeded by the run's seed; never sooner than a normal tick), and the
  /// device holds the last force meanwhile, as a busy host's loop does.
  double late_fraction = 0.0;
  int max_stall_ms = 1;
  /// The loop's rate (LoopConfig::rate_hz; a configuration allows kMinRateHz-kMaxRateHz,
  /// runs here may go below to see where the rendering breaks). The simulated MF-2
  /// streams at its own 1 kHz whatever the loop's rate: a faster loop sees each sample on
  /// more than one tick, a slower one every second or more.
  double loop_rate_hz = 1000.0;
};

/// `patient` is rendered and is what the clinician plans against; `seconds` of loop ticks.
inline RunResult runStability(const JointModelParams& patient, Motion motion, double freq_hz,
                              double seconds, uint64_t seed,
                              const client::loop::TeleopOptions& teleop = {},
                              const Extras& extras = {}) {
  ManualClock clock(kNsPerS);
  OperatorConfig op;
  op.frequency_hz = freq_hz;
  op.seed = seed;
  devices::SimulatedMf2 dev(patient, op, clock);
  // The clinician places the finger at its rest pose (a stiff joint rests flexed).
  const JointModel model(patient);
  dev.setPose(Vec3(model.restAngleRad(kFlexion), model.restAngleRad(kAbduction),
                   model.restAngleRad(kAxial)));
  devices::ExplorationPlan plan = devices::planExploration(patient, op.band_max_n);
  plan.seed = seed;
  devices::ExplorationOperator explorer(plan);
  if (motion == Motion::kExploration) dev.setOperator(&explorer);
  if (!(extras.loop_rate_hz >= 1.0 && extras.loop_rate_hz <= 1e6)) {
    throw std::invalid_argument("runStability: loop rate outside 1 Hz-1 MHz");
  }
  LoopConfig loop_config;
  loop_config.rate_hz = extras.loop_rate_hz;
  client::loop::HapticLoop hl(dev, clock, patient, SafetyLimits{}, loop_config, teleop);
  const int64_t tick_ns = std::llround(1e9 / extras.loop_rate_hz);
  if (extras.guide.active()) {
    JointModelParams guided = patient;
    guided.version = patient.version + 1;
    guided.guide = extras.guide;
    (void)hl.models().tryPush(guided);
  }
  std::mt19937_64 late_rng(seed * 0x9e37'79b9'7f4a'7c15ULL + 1);
  std::uniform_real_distribution<double> unit(0.0, 1.0);

  RunResult r;
  Sample s;
  const int64_t end_ns = std::llround(seconds * 1e9);
  for (int64_t t_ns = 0; t_ns < end_ns;) {
    int64_t step_ns = tick_ns;
    if (extras.late_fraction > 0.0 && unit(late_rng) < extras.late_fraction) {
      int ms = 2 + static_cast<int>(unit(late_rng) * std::max(0, extras.max_stall_ms - 1));
      ms = std::min(ms, std::max(2, extras.max_stall_ms));
      step_ns = std::max(tick_ns, ms * kNsPerMs);
    }
    t_ns += step_ns;
    clock.advance(step_ns);
    hl.step();
    while (hl.samples().tryPop(s)) {
    }
    const Vec3& a = dev.angles();
    if (!allFinite(a)) {
      r.finite = false;
      break;
    }
    r.range_excess_deg = std::max(r.range_excess_deg, model.rangeExcessDeg(a));
    const double t = static_cast<double>(t_ns) * 1e-9;
    if (motion == Motion::kMobilization && t > op.ramp_s + 0.5) {
      const double f0 = dev.renderedForce()[0].norm(), f1 = dev.renderedForce()[1].norm();
      r.pusher_max_n = std::max(r.pusher_max_n, std::max(f0, f1));
      r.holder_max_n = std::max(r.holder_max_n, std::min(f0, f1));
      r.flexion_min_deg = std::min(r.flexion_min_deg, radToDeg(a[kFlexion]));
      r.flexion_max_deg = std::max(r.flexion_max_deg, radToDeg(a[kFlexion]));
    }
  }
  const auto& h = hl.health();
  r.force_max_n = h.force_max_n.load();
  r.request_max_n = h.request_max_n.load();
  r.min_energy_j = h.passivity_min_energy_j.load();
  r.clamps = h.clamped.load();
  r.rate_limited = h.rate_limited.load();
  r.nonfinite = h.nonfinite.load();
  r.pc_ticks = h.passivity_activations.load();
  r.fault = hl.fault();
  return r;
}

/// The checks every run must pass, and a line saying which failed ("" when none).
struct Criteria {
  double range_margin_deg = 20.0;  ///< past a range end (a weak joint pushed into its wall)
  double energy_epsilon_j = 1e-3;  ///< the observer's energy may dip this far below zero
  double force_limit_n = 4.0;      ///< per finger, what the device renders
};

inline std::string failures(const RunResult& r, const Criteria& c = {}) {
  std::string why;
  if (!r.finite) why += " non-finite angles;";
  if (r.range_excess_deg > c.range_margin_deg) why += " left the range;";
  if (r.request_max_n > c.force_limit_n) why += " force beyond the limit;";
  if (r.min_energy_j < -c.energy_epsilon_j) why += " not passive;";
  if (r.clamps != 0) why += " clamped;";
  if (r.nonfinite != 0) why += " non-finite force;";
  if (r.fault != client::loop::LoopFault::kNone) why += " fault;";
  return why;
}

}  // namespace telehand::stability
