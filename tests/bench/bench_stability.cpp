// The stability sweep (docs/manual.md "Tests"): every shipped patient case and N random ones
// (randomPatientCase, seeds 1..N), 30 s of mobilization at 1, 3 and 6 Hz and 30 s of
// exploration each, through the client's loop on the simulated MF-2, offline. Prints one
// line per run and a summary; exits 1 if any run fails the suite's criteria.
//
//   telehand_bench_stability [--random N] [--first K] [--seconds S] [--seed N] [--hz LIST]
//                            [--loop-rate HZ]
//   telehand_bench_stability --damping-sweep
//   telehand_bench_stability --late-sweep [--seconds S]
//
// --first: the random cases are K..K+N-1 (default 1), so that a sweep can try patients no
// earlier one did. --seed: the simulated clinician's seed (default 1) for every run. --hz: the
// mobilization frequencies (default 1,3,6; operator.frequency_hz allows 0.1-10).
//
// --loop-rate: the client's loop at HZ instead of 1 kHz, 100-4000 Hz (a configuration allows
// LoopConfig::kMinRateHz-kMaxRateHz; below it shows where the rendering breaks); the simulated
// MF-2 still streams at 1 kHz.
//
// --late-sweep: instead, mobilizes the healthy joint on a loop that runs late (a share of its
// ticks 2..N ms after the one before, the device holding the last force meanwhile) without a
// guide, under the demonstration's guide (3 Hz, the student's own rhythm) and under a
// supervisor's take-over (2 Hz), and counts the runs (5 seeds each) that leave the joint's
// range: where late ticks, not the guide, break the rendering (docs/lessons.md "Take-over").
//
// --damping-sweep: instead, renders a plain virtual damper B (N·s/m per finger, one tick late,
// velocity low-passed at 5 ms like the proxy's) on the simulated MF-2 during a mobilization
// and reports where it stops being stable: the measurement behind the damping cap
// (docs/facts.md "Damping cap").
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "../stability/stability_run.h"
#include "telehand/core/parse.h"

using namespace telehand;

namespace {

/// Adds −B·v to every command (v from the device's positions, 5 ms low-pass).
class DampedDevice final : public devices::Device {
 public:
  DampedDevice(devices::Device& inner, double b) : inner_(inner), b_(b) {}
  bool read(devices::DeviceSample& out) noexcept override {
    if (!inner_.read(out)) return false;
    for (int k = 0; k < 2; ++k) {
      if (have_ && out.time_ns > last_ns_) {
        const double dt = static_cast<double>(out.time_ns - last_ns_) * 1e-9;
        const Vec3 raw = (out.fingers[k].position_m - last_p_[k]) / dt;
        v_[k] += (dt / (0.005 + dt)) * (raw - v_[k]);
      }
      last_p_[k] = out.fingers[k].position_m;
    }
    have_ = true;
    last_ns_ = out.time_ns;
    return true;
  }
  bool write(const devices::ForceCommand& cmd) noexcept override {
    devices::ForceCommand c = cmd;
    for (int k = 0; k < 2; ++k) c.force_n[k] -= b_ * v_[k];
    return inner_.write(c);
  }
  devices::DeviceStatus status() const noexcept override { return inner_.status(); }
  std::string_view name() const noexcept override { return "damped"; }

 private:
  devices::Device& inner_;
  double b_;
  bool have_ = false;
  int64_t last_ns_ = 0;
  PerFinger<Vec3> last_p_{Vec3::Zero(), Vec3::Zero()}, v_{Vec3::Zero(), Vec3::Zero()};
};

int dampingSweep() {
  std::printf("%8s %10s %12s %12s\n", "B N.s/m", "flex range", "peak cmd N", "verdict");
  for (double b : {10.0, 20.0, 25.0, 30.0, 40.0, 50.0, 60.0, 80.0, 100.0, 150.0, 200.0, 400.0}) {
    ManualClock clock(kNsPerS);
    const JointModelParams m = healthyIndexMcp();
    devices::SimulatedMf2 sim(m, OperatorConfig{}, clock);
    DampedDevice dev(sim, b);
    client::loop::TeleopOptions teleop;
    teleop.passivity.control = false;
    teleop.fault.enabled = false;
    SafetyLimits lim;
    lim.max_force_n = 1e6;  // see the damper itself, not the gate
    lim.max_rate_n_per_s = 1e9;
    client::loop::HapticLoop hl(dev, clock, m, lim, LoopConfig{}, teleop);
    Sample s;
    double lo = 1e9, hi = -1e9, peak = 0.0;
    bool finite = true;
    for (int i = 0; i < 6000; ++i) {
      clock.advance(kNsPerMs);
      hl.step();
      while (hl.samples().tryPop(s)) {
      }
      if (!allFinite(sim.angles())) {
        finite = false;
        break;
      }
      if (i > 2000) {
        lo = std::min(lo, radToDeg(sim.angles()[kFlexion]));
        hi = std::max(hi, radToDeg(sim.angles()[kFlexion]));
        peak =
            std::max(peak, std::max(sim.renderedForce()[0].norm(), sim.renderedForce()[1].norm()));
      }
    }
    const bool stable = finite && peak < 10.0 && hi - lo < 30.0;
    std::printf("%8.0f %10.1f %12.2f %12s\n", b, finite ? hi - lo : -1.0, peak,
                stable ? "stable" : "UNSTABLE");
  }
  return 0;
}

int lateSweep(double seconds) {
  const JointModelParams m = healthyIndexMcp();
  // Where the student's own swing lies on a loop that is never late: the guides go there.
  const auto calm = stability::runStability(m, stability::Motion::kMobilization, 3.0, seconds, 1);
  const double centre = 0.5 * (calm.flexion_min_deg + calm.flexion_max_deg);
  const double amplitude = calm.flexion_max_deg - calm.flexion_min_deg;
  const auto guides = stability::lessonGuides(centre, amplitude, true);
  std::printf("swing without late ticks: %.1f..%.1f deg; %.0f s per run, 5 seeds\n",
              calm.flexion_min_deg, calm.flexion_max_deg, seconds);
  std::printf("%-22s %6s", "guide", "late");
  const int stalls[] = {4, 8, 12, 20};
  for (int st : stalls) std::printf("  <=%2d ms", st);
  std::printf("   (runs that left the range)\n");
  client::loop::TeleopOptions teleop;
  teleop.fault.enabled = false;  // see the rendering itself, not the detector stopping it
  for (const auto& g : guides) {
    for (double late : {0.05, 0.10, 0.17}) {
      std::printf("%-22s %5.0f%%", g.name, 100.0 * late);
      for (int st : stalls) {
        int left = 0;
        for (uint64_t seed = 1; seed <= 5; ++seed) {
          stability::Extras x;
          x.guide = g.guide;
          x.late_fraction = late;
          x.max_stall_ms = st;
          const auto r = stability::runStability(m, stability::Motion::kMobilization, 3.0, seconds,
                                                 seed, teleop, x);
          if (!r.finite || r.range_excess_deg > stability::Criteria{}.range_margin_deg) ++left;
        }
        std::printf("  %4d/5 ", left);
      }
      std::printf("\n");
    }
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  double randoms = 20;
  double first = 1;
  double seconds = 30.0;
  bool seconds_given = false;
  double seed = 1;
  std::vector<double> mobilization_hz{1.0, 3.0, 6.0};
  stability::Extras extras;
  enum class Mode { kSweep, kDamping, kLate } mode = Mode::kSweep;
  const auto usage = [&](FILE* to) {
    std::fprintf(to,
                 "usage: %s [--random N] [--first K] [--seconds S] [--seed N] [--hz 1,3,6] "
                 "[--loop-rate HZ (100-4000)]\n"
                 "       %s --damping-sweep\n"
                 "       %s --late-sweep [--seconds S (default 10)]\n",
                 argv[0], argv[0], argv[0]);
  };
  // A whole number in [lo, hi] (counts, case numbers, seeds).
  const auto wholeNumber = [](const char* text, double lo, double hi, double& out) {
    return parseFiniteNumber(text, out) && out >= lo && out <= hi && out == std::floor(out);
  };
  const auto bad = [&](const char* option, const char* value, const char* want) {
    std::fprintf(stderr, "%s: %s '%s' is not %s\n", argv[0], option, value, want);
    return 2;
  };
  for (int i = 1; i < argc; ++i) {
    const char* opt = argv[i];
    const char* value = i + 1 < argc ? argv[i + 1] : nullptr;
    const bool takes_value = !std::strcmp(opt, "--random") || !std::strcmp(opt, "--first") ||
                             !std::strcmp(opt, "--seconds") || !std::strcmp(opt, "--seed") ||
                             !std::strcmp(opt, "--hz") || !std::strcmp(opt, "--loop-rate");
    if (takes_value && !value) {
      std::fprintf(stderr, "%s: %s needs a value\n", argv[0], opt);
      return 2;
    }
    if (takes_value) ++i;
    if (!std::strcmp(opt, "--help") || !std::strcmp(opt, "-h")) {
      usage(stdout);
      return 0;
    } else if (!std::strcmp(opt, "--random")) {
      if (!wholeNumber(value, 0, 100000, randoms)) {
        return bad(opt, value, "a count of random cases (0-100000)");
      }
    } else if (!std::strcmp(opt, "--first")) {
      if (!wholeNumber(value, 1, 1e15, first)) {
        return bad(opt, value, "the first random case (a whole number, 1-1e15)");
      }
    } else if (!std::strcmp(opt, "--seconds")) {
      if (!parseFiniteNumber(value, seconds) || !(seconds > 0.0) || seconds > 3600.0) {
        return bad(opt, value, "a duration in seconds (above 0, at most 3600)");
      }
      seconds_given = true;
    } else if (!std::strcmp(opt, "--seed")) {
      if (!wholeNumber(value, 0, 1e15, seed)) {
        return bad(opt, value, "a seed (a whole number, 0-1e15)");
      }
    } else if (!std::strcmp(opt, "--hz")) {
      mobilization_hz.clear();
      std::string list = value;
      for (std::size_t at = 0; at <= list.size();) {
        const std::size_t comma = std::min(list.find(',', at), list.size());
        const std::string tok = list.substr(at, comma - at);
        double hz = 0.0;
        if (!parseFiniteNumber(tok, hz) || !(hz >= 0.1 && hz <= 10.0)) {
          return bad(opt, value, "a list of mobilization frequencies in 0.1-10 Hz (e.g. 1,3,6)");
        }
        mobilization_hz.push_back(hz);
        at = comma + 1;
      }
    } else if (!std::strcmp(opt, "--loop-rate")) {
      if (!parseFiniteNumber(value, extras.loop_rate_hz) ||
          !(extras.loop_rate_hz >= 100.0 && extras.loop_rate_hz <= 4000.0)) {
        return bad(opt, value, "a loop rate in 100-4000 Hz");
      }
    } else if (!std::strcmp(opt, "--damping-sweep")) {
      mode = Mode::kDamping;
    } else if (!std::strcmp(opt, "--late-sweep")) {
      mode = Mode::kLate;
    } else {
      std::fprintf(stderr, "%s: unknown option '%s'\n", argv[0], opt);
      usage(stderr);
      return 2;
    }
  }
  const bool sweep_options_given = randoms != 20 || first != 1 || seed != 1 ||
                                   extras.loop_rate_hz != 1000.0 ||
                                   mobilization_hz != std::vector<double>{1.0, 3.0, 6.0};
  if (mode != Mode::kSweep && (sweep_options_given || (mode == Mode::kDamping && seconds_given))) {
    std::fprintf(stderr,
                 "%s: --damping-sweep and --late-sweep take no other options but "
                 "--late-sweep's --seconds\n",
                 argv[0]);
    return 2;
  }
  if (mode == Mode::kDamping) return dampingSweep();
  if (mode == Mode::kLate) return lateSweep(seconds_given ? seconds : 10.0);
  std::vector<JointModelParams> cases;
  for (const auto& name : listPatientCases(TELEHAND_DEPLOY_DIR "/cases")) {
    cases.push_back(loadPatientCaseByName(TELEHAND_DEPLOY_DIR "/cases", name).model);
  }
  for (uint64_t k = 0; k < static_cast<uint64_t>(randoms); ++k) {
    cases.push_back(randomPatientCase(static_cast<uint64_t>(first) + k).model);
  }
  std::printf("loop at %g Hz, operator seed %.0f\n", extras.loop_rate_hz, seed);
  std::printf("%-12s %-6s %4s %8s %8s %8s %10s %6s %6s %6s %6s  %s\n", "case", "motion", "Hz",
              "excess", "req N", "push N", "min E J", "hold N", "clamps", "PC", "fault", "result");
  int runs = 0, failed = 0;
  for (const auto& m : cases) {
    for (std::size_t j = 0; j <= mobilization_hz.size(); ++j) {
      const bool explore = j == mobilization_hz.size();
      const double hz = explore ? 0.0 : mobilization_hz[j];
      const auto r = stability::runStability(
          m, explore ? stability::Motion::kExploration : stability::Motion::kMobilization,
          explore ? 3.0 : hz, seconds, static_cast<uint64_t>(seed), {}, extras);
      const std::string why = stability::failures(r);
      ++runs;
      failed += why.empty() ? 0 : 1;
      std::printf("%-12s %-6s %4g %8.2f %8.3f %8.3f %10.2e %6.3f %6llu %6llu %6s  %s\n",
                  m.case_name.data(), explore ? "explor" : "mobil", hz, r.range_excess_deg,
                  r.request_max_n, r.pusher_max_n, r.min_energy_j, r.holder_max_n,
                  static_cast<unsigned long long>(r.clamps),
                  static_cast<unsigned long long>(r.pc_ticks),
                  r.fault == client::loop::LoopFault::kNone ? "-" : "FAULT",
                  why.empty() ? "ok" : why.c_str());
    }
  }
  std::printf("%d runs, %d failed\n", runs, failed);
  return failed ? 1 : 0;
}
