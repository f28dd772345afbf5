// Capture and fitting figures (README "Performance"):
//  1. the k-nearest-neighbour (FLANN) model's cost per 1 kHz tick: the query alone, back to
//     back and paced at 1 kHz (caches go cold between ticks, as in the loop), and the whole
//     JointProxy::render with it;
//  2. live refit latency in the server: from the arrival of a capture's newest sample to
//     the JointModel fitted from it being published, with the capture streamed in real
//     time as the client's 100-sample record chunks; and the refit's compute time.
//  3. (--fit-table) fitted holding force against the truth: the shipped cases at the default
//     capture length (10 s per axis), 0.5, 3 and 6 Hz, the paper's 1.43 N thimble noise,
//     three seeds each; the largest error over the reachable range off the zone edges and
//     walls, and including them (the walls to 2 deg beyond each end reached); over the
//     range the capture covered, with how far it stopped short of the truth's range under
//     18 N where it did (more than 1 deg).
//     Also the fitted speed gain (spasm) against the truth's.
//  4. (--probe CASE_FILE|random-SEED HZ SEED) one capture fitted, per axis: the range
//     planned, reached and fitted, walls, zone, residual, hysteresis, errors, speed gain
//     with its standard error; PROBE_CURVE=1 prints the curves against the truth,
//     PROBE_TRUTH=1 the truth's own residual at lags of 0-2 samples (PROBE_LAGS=L1,L2,...:
//     at those, fractions interpolated) against the fit's (a fit worse than the truth: a
//     search problem; better: the model misses something), PROBE_BINS=L with it the mean
//     residual per 5 deg bin, stretching and returning, at lag L; PROBE_NOSPASM=1 fits
//     without the spasm term, PROBE_RHW=H fits (and rates the truth) with rates over ±H
//     samples (FitOptions::rate_half_window), PROBE_THW=H reads the turns' accelerations
//     over ±H samples (FitOptions::turn_half_window), PROBE_TRHW=H their rates
//     (FitOptions::turn_rate_half_window), PROBE_AHW=H the accelerations over ±H samples
//     (FitOptions::acc_half_window), PROBE_JCOL=C FitOptions::max_inertia_collinearity,
//     PROBE_SAT_MARGIN=M FitOptions::saturation_margin, PROBE_SAT_HW=H
//     FitOptions::saturation_half_window, PROBE_CPN=C the thimbles' FSRs at C counts per
//     newton (the default 180 saturates at 22 N), PROBE_J=1 prints each axis' inertia,
//     PROBE_NOISE=N captures with N newtons of thimble noise (default the paper's 1.43),
//     PROBE_SECONDS=S with S seconds per axis, PROBE_SUBSTEPS=N with the rig's finger integrated N
//     times a sample, PROBE_DUMP=FILE the points (after a header of the truth's lever, damping,
//     gain and damping cap; per sample the angles, forces, rates, accelerations and the truth's
//     holding force per axis).
//  5. (--fit-table --technique massage) the web's tissue model fitted from synthetic massage
//     captures (server/estimate/synthetic_massage.h: 60 s, 10 ± 2 N, the paper's 1.43 N
//     thimble noise), the shipped webs' [tissue] (healthy, oedema, scar, hypertonic) or
//     --random randomTissue seeds: per web the largest error per parameter over the seeds
//     (%), the largest error of the rendered static normal force over the forces pressed
//     (N), and the fit's time.
// Usage: telehand_bench_capture [--quick | --fit-table [CASES_DIR, default deploy/cases]
//          [--cases a,b] [--hz 0.5,3] [--seeds FIRST,COUNT] [--random S1,S2 (randomPatientCase)]
//          [--turn-window H (FitOptions::turn_half_window)]
//          [--turn-rate-window H (FitOptions::turn_rate_half_window)]
//          [--rate-window H (FitOptions::rate_half_window)]
//          [--acc-window H (FitOptions::acc_half_window)]
//          [--inertia-collinearity C (FitOptions::max_inertia_collinearity)]
//          [--saturation-margin M (FitOptions::saturation_margin)]
//          [--sweep-seconds S (per axis, as telehand-client's)]
//          [--rig-substeps N (CaptureRigOptions::substeps)]
//          [--technique massage [--seconds S] [--noise N]] | --probe CASE HZ SEED]
#include <spdlog/spdlog.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "telehand/config/config.h"
#include "telehand/core/clock.h"
#include "telehand/core/knn_model.h"
#include "telehand/protocol/wire.h"
#include "telehand/server/estimate/synthetic_capture.h"
#include "telehand/server/estimate/synthetic_massage.h"
#include "telehand/server/estimate/tissue_fit.h"
#include "telehand/server/session/session_manager.h"
#include "telehand/server/store/sqlite_store.h"

using namespace telehand;

namespace {

int64_t now() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec * kNsPerS + ts.tv_nsec;
}

void sleepUntil(int64_t t) {
  timespec ts{t / kNsPerS, t % kNsPerS};
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
  }
}

void report(const char* what, std::vector<int64_t> ns, double unit = 1e3, const char* u = "us") {
  std::sort(ns.begin(), ns.end());
  auto q = [&](double p) {
    return static_cast<double>(ns[std::min(
               ns.size() - 1, static_cast<std::size_t>(p * static_cast<double>(ns.size())))]) /
           unit;
  };
  std::printf("%-52s n=%-7zu p50 %8.2f  p90 %8.2f  p99 %8.2f  p99.9 %8.2f  max %8.2f %s\n", what,
              ns.size(), q(0.5), q(0.9), q(0.99), q(0.999), static_cast<double>(ns.back()) / unit,
              u);
}

class Recorder final : public server::session::Outbox {
 public:
  void publish(const telehand_msg_SessionStatus&) override {}
  void publish(const telehand_msg_JointModel& m) override {
    if (m.session_id == 1) ++capture_models;
  }
  void publish(const telehand_msg_HandState&) override {}
  void publish(const telehand_msg_SessionEvent&) override {}
  int capture_models = 0;
};

}  // namespace

/// The fitted and true holding force, worst over the range the capture covered: the truth's
/// range under max_force_n (its static holding force), cut to where the capture reached
/// (inner: off the zone edges and 1 deg from the walls; edges: including them and 2 deg into
/// each wall the capture went 2 deg into). `short_deg`: how far the capture stopped short of
/// the truth's range under max_force_n (the larger of both ends; 0: all of it reached).
struct FitError {
  double inner = 0.0, edges = 0.0, short_deg = 0.0;
};

FitError fitErrors(const JointModelParams& truth_p, const JointModelParams& fit_p, int i,
                   double max_force_n, double reached_min, double reached_max) {
  const JointModel truth(truth_p), fitted(fit_p);
  const CubicCurve& c = truth_p.axes[static_cast<std::size_t>(i)];
  const double rest = radToDeg(truth.restAngleRad(i));
  auto f = [&](double d) { return truth.holdingForceN(i, degToRad(d)); };
  double lo = rest, hi = rest;
  while (lo - 0.05 >= c.min_deg && std::abs(f(lo - 0.05)) <= max_force_n) lo -= 0.05;
  while (hi + 0.05 <= c.max_deg && std::abs(f(hi + 0.05)) <= max_force_n) hi += 0.05;
  FitError e;
  e.short_deg = std::max({reached_min - lo, hi - reached_max, 0.0});
  lo = std::max(lo, reached_min);
  hi = std::min(hi, reached_max);
  const bool wlo = lo <= c.min_deg + 0.05 && reached_min <= c.min_deg - 2.0;
  const bool whi = hi >= c.max_deg - 0.05 && reached_max >= c.max_deg + 2.0;
  const double zone = truth_p.neutral_zone_deg[static_cast<std::size_t>(i)];
  for (double d = wlo ? c.min_deg - 2.0 : lo; d <= (whi ? c.max_deg + 2.0 : hi); d += 0.05) {
    const double err = std::abs(fitted.holdingForceN(i, degToRad(d)) - f(d));
    e.edges = std::max(e.edges, err);
    const bool near =
        (wlo && d < c.min_deg + 1.0) || (whi && d > c.max_deg - 1.0) ||
        (zone > 0.0 && (std::abs(d - rest + zone) < 1.5 || std::abs(d - rest - zone) < 1.5));
    if (d >= lo && d <= hi && !near) e.inner = std::max(e.inner, err);
  }
  return e;
}

struct TableOptions {
  std::string cases_dir = "deploy/cases";
  std::vector<std::string> cases = {"healthy", "stiff", "lax", "recovery", "spasm"};
  std::vector<double> hz = {0.5, 3.0, 6.0};
  uint64_t first_seed = 1, seeds = 3;
  std::vector<uint64_t> random;  ///< randomPatientCase seeds instead of the case files
  bool massage = false;          ///< the web's tissue model instead of the joint
  double seconds = 60.0;         ///< massage capture length
  /// Joint capture length per axis (telehand-client --sweep-seconds).
  double sweep_seconds = server::estimate::SyntheticCaptureOptions{}.seconds_per_axis;
  /// The capture rig's integration steps a sample (CaptureRigOptions::substeps).
  int rig_substeps = server::estimate::SyntheticCaptureOptions{}.rig_substeps;
  double noise_n = 1.43;
  bool cases_given = false;
  bool each = false;  ///< massage (--each 1): the web's values and a line per fit, signed %
  /// The joint fit's options: --turn-window, --turn-rate-window, --rate-window, --acc-window,
  /// --inertia-collinearity.
  server::estimate::FitOptions fit;
};

/// The web's largest static normal force error at the same thimble positions (fitted
/// against true) up to the most force the capture pressed with, both fingers, at the centre
/// and 8 mm off it on both diagonals, N.
double normalForceError(const TissueParams& truth, const TissueParams& fitted, double force_max) {
  const TissueModel t(truth), f(fitted);
  const double surface = 0.5 * truth.thickness_m + truth.pad_radius_m;
  double worst = 0.0;
  for (int k = 0; k < 2; ++k) {
    for (const auto& [x, y] : {std::pair{0.0, 0.0}, {0.008, -0.008}, {-0.008, 0.008}}) {
      for (double d = 0.0; d <= 0.03; d += 1e-5) {
        const Vec3 p = t.fromWeb(Vec3(x, y, k == kThumb ? surface - d : -surface + d));
        const double ft = t.normalForceN(t.depthOf(k, p), 0.0, x, y);
        if (ft > force_max) break;
        worst = std::max(worst, std::abs(ft - f.normalForceN(f.depthOf(k, p), 0.0, x, y)));
      }
    }
  }
  return worst;
}

int massageTable(const TableOptions& t) {
  std::printf(
      "web          |  k     n     lambda  kt    mu_s  mu_k  b      patch k/mu | normal force | "
      "fit s   worst |error| of %llu seeds, %%, %.0f s captures, %.2f N noise\n",
      static_cast<unsigned long long>(t.seeds), t.seconds, t.noise_n);
  std::vector<std::pair<std::string, TissueParams>> webs;
  for (const auto& name : t.cases) {
    const std::string file = t.cases_dir + "/" + name + ".toml";
    webs.emplace_back(name, std::filesystem::exists(file) ? loadPatientCase(file).tissue
                                                          : tissueCase(name.c_str()));
  }
  for (const uint64_t r : t.random)
    webs.emplace_back("random-" + std::to_string(r), server::estimate::randomTissue(r));
  for (const auto& [name, web] : webs) {
    std::array<double, 9> worst{};
    double force = 0.0, seconds = 0.0;
    bool all_ok = true;
    if (t.each)
      std::printf("%s: k %.4g n %.3f lambda %.3f kt %.0f mu %.3f/%.3f b %.3f patch %.2f/%.2f\n",
                  name.c_str(), web.stiffness_n_per_m_pow, web.exponent, web.damping_s_per_m,
                  web.lateral_stiffness_n_per_m, web.mu_static, web.mu_kinetic,
                  web.viscous_n_s_per_m, web.patch_stiffness_factor, web.patch_friction_factor);
    for (uint64_t seed = t.first_seed; seed < t.first_seed + t.seeds; ++seed) {
      server::estimate::SyntheticMassageOptions o;
      o.truth = web;
      o.seconds = t.seconds;
      o.noise_n = t.noise_n;
      o.seed = seed;
      const auto cap = server::estimate::synthesizeMassage(o);
      TissueParams nominal;
      nominal.origin_m = web.origin_m;
      nominal.orientation = web.orientation;
      nominal.thickness_m = web.thickness_m;
      nominal.pad_radius_m = web.pad_radius_m;
      nominal.half_extent_m = web.half_extent_m;
      nominal.patch_x_m = web.patch_x_m;
      nominal.patch_y_m = web.patch_y_m;
      nominal.patch_radius_m = web.patch_radius_m;
      nominal.patch_rim_m = web.patch_rim_m;
      server::estimate::TissueFitOptions fo;
      fo.noise_n = t.noise_n;
      server::estimate::TissueFitter fitter(nominal, fo);
      for (const auto& smp : cap.samples) fitter.add(smp, true);
      const int64_t t0 = now();
      const auto fit = fitter.fit();
      seconds += static_cast<double>(now() - t0) * 1e-9;
      all_ok = all_ok && fit.ok;
      if (!fit.ok) continue;
      const TissueParams& p = fit.params;
      const std::array<std::pair<double, double>, 9> pairs = {
          std::pair{p.stiffness_n_per_m_pow, web.stiffness_n_per_m_pow},
          {p.exponent, web.exponent},
          {p.damping_s_per_m, web.damping_s_per_m},
          {p.lateral_stiffness_n_per_m, web.lateral_stiffness_n_per_m},
          {p.mu_static, web.mu_static},
          {p.mu_kinetic, web.mu_kinetic},
          {p.viscous_n_s_per_m, web.viscous_n_s_per_m},
          {p.patch_stiffness_factor, web.patch_stiffness_factor},
          {p.patch_friction_factor, web.patch_friction_factor}};
      for (std::size_t i = 0; i < pairs.size(); ++i)
        worst[i] = std::max(worst[i], 100.0 * std::abs(pairs[i].first / pairs[i].second - 1.0));
      force = std::max(force, normalForceError(web, p, fit.force_max_n));
      if (t.each) {
        std::printf("  seed %-4llu |", static_cast<unsigned long long>(seed));
        for (std::size_t i = 0; i < (web.patch_radius_m > 0.0 ? 9u : 7u); ++i)
          std::printf(" %+6.1f", 100.0 * (pairs[i].first / pairs[i].second - 1.0));
        std::printf(" | se k %.1f lambda %.1f b %.1f %% | %.3f N\n",
                    100.0 * fit.stiffness.se / fit.stiffness.value,
                    100.0 * fit.damping.se / web.damping_s_per_m,
                    100.0 * fit.viscous.se / web.viscous_n_s_per_m,
                    normalForceError(web, p, fit.force_max_n));
      }
    }
    char patch[32] = "  -";
    if (web.patch_radius_m > 0.0)
      std::snprintf(patch, sizeof patch, "%4.1f/%-4.1f", worst[7], worst[8]);
    std::printf(
        "%-12s | %5.1f %5.1f %6.1f %5.1f %5.1f %5.1f %6.1f  %-10s | %5.3f        | %5.2f %s\n",
        name.c_str(), worst[0], worst[1], worst[2], worst[3], worst[4], worst[5], worst[6], patch,
        force, seconds / static_cast<double>(t.seeds), all_ok ? "" : "(a fit failed)");
    std::fflush(stdout);
  }
  return 0;
}

std::vector<std::string> splitList(const std::string& s) {
  std::vector<std::string> out;
  std::size_t a = 0;
  while (a <= s.size()) {
    const std::size_t b = std::min(s.find(',', a), s.size());
    if (b > a) out.push_back(s.substr(a, b - a));
    a = b + 1;
  }
  return out;
}

int fitTable(const TableOptions& t) {
  std::printf(
      "case        Hz   | flexion inner/edges | abduction inner/edges | axial inner/edges | "
      "speed gain fit (truth) | worst of %llu seeds, N\n",
      static_cast<unsigned long long>(t.seeds));
  std::vector<PatientCase> cases;
  for (const auto& name : t.cases)
    cases.push_back(loadPatientCase(t.cases_dir + "/" + name + ".toml"));
  for (const uint64_t r : t.random) cases.push_back(randomPatientCase(r));
  for (const PatientCase& pc : cases) {
    const JointModelParams& truth = pc.model;
    for (const double hz : t.hz) {
      std::array<FitError, kAxes> worst{};
      bool all_ok = true;
      double gain_lo = 1e300, gain_hi = -1e300;
      for (uint64_t seed = t.first_seed; seed < t.first_seed + t.seeds; ++seed) {
        server::estimate::SyntheticCaptureOptions o;
        o.truth = truth;
        o.frequency_hz = hz;
        o.seed = seed;
        o.seconds_per_axis = t.sweep_seconds;
        o.rig_substeps = t.rig_substeps;
        const auto cap = server::estimate::synthesizeCapture(o);
        server::estimate::CaptureFitter fitter(cap.geometry, t.fit);
        for (const auto& smp : cap.samples) fitter.add(smp, true);
        const auto fit = fitter.fit();
        all_ok = all_ok && fit.ok();
        const JointModelParams fitted = fit.model(truth);
        gain_lo = std::min(gain_lo, fitted.speed_gain_s_per_rad);
        gain_hi = std::max(gain_hi, fitted.speed_gain_s_per_rad);
        JointModelParams static_truth = truth;
        static_truth.speed_gain_s_per_rad = 0.0;
        for (int i = 0; i < kAxes; ++i) {
          const auto& a = fit.axes[static_cast<std::size_t>(i)];
          const auto e = fitErrors(static_truth, fitted, i, o.max_force_n, a.reached_min_deg,
                                   a.reached_max_deg);
          auto& w = worst[static_cast<std::size_t>(i)];
          w = {std::max(w.inner, e.inner), std::max(w.edges, e.edges),
               std::max(w.short_deg, e.short_deg)};
        }
      }
      std::string short_of;
      for (std::size_t i = 0; i < kAxes; ++i) {
        if (worst[i].short_deg > 1.0) {
          char b[64];
          std::snprintf(b, sizeof b, " %s %.1f deg short", kAxisNames[i].data(),
                        worst[i].short_deg);
          short_of += b;
        }
      }
      std::printf(
          "%-11s %-4.1f | %6.2f / %-6.2f     | %6.2f / %-6.2f       | %6.2f / %-6.2f   | "
          "%4.2f..%4.2f (%4.2f) %s%s\n",
          pc.name.c_str(), hz, worst[0].inner, worst[0].edges, worst[1].inner, worst[1].edges,
          worst[2].inner, worst[2].edges, gain_lo, gain_hi, truth.speed_gain_s_per_rad,
          all_ok ? "" : "(an axis not fitted)", short_of.c_str());
      std::fflush(stdout);
    }
  }
  return 0;
}

int probe(const std::string& file, double hz, uint64_t seed) {
  const PatientCase pc = file.rfind("random-", 0) == 0
                             ? randomPatientCase(std::stoull(file.substr(7)))
                             : loadPatientCase(file);
  server::estimate::SyntheticCaptureOptions o;
  o.truth = pc.model;
  o.frequency_hz = hz;
  o.seed = seed;
  if (const char* h = std::getenv("PROBE_NOISE")) o.noise_n = std::atof(h);
  if (const char* h = std::getenv("PROBE_SECONDS")) o.seconds_per_axis = std::atof(h);
  if (const char* h = std::getenv("PROBE_SUBSTEPS")) o.rig_substeps = std::atoi(h);
  if (const char* h = std::getenv("PROBE_CPN"))
    for (auto& t : o.device.thimbles)
      for (auto& f : t.fsr) f.counts_per_n = std::atof(h);
  const auto cap = server::estimate::synthesizeCapture(o);
  server::estimate::FitOptions fo;
  fo.fit_spasm = std::getenv("PROBE_NOSPASM") == nullptr;
  if (const char* h = std::getenv("PROBE_RHW")) fo.rate_half_window = std::atoi(h);
  if (const char* h = std::getenv("PROBE_THW")) fo.turn_half_window = std::atoi(h);
  if (const char* h = std::getenv("PROBE_AHW")) fo.acc_half_window = std::atoi(h);
  if (const char* h = std::getenv("PROBE_JCOL")) fo.max_inertia_collinearity = std::atof(h);
  if (const char* h = std::getenv("PROBE_TRHW")) fo.turn_rate_half_window = std::atoi(h);
  if (const char* h = std::getenv("PROBE_TW")) fo.weigh_turns = std::atoi(h) != 0;
  if (const char* h = std::getenv("PROBE_WALL_SHARE")) fo.min_wall_share = std::atof(h);
  if (const char* h = std::getenv("PROBE_SAT_MARGIN")) fo.saturation_margin = std::atof(h);
  if (const char* h = std::getenv("PROBE_SAT_HW")) fo.saturation_half_window = std::atoi(h);
  server::estimate::CaptureFitter fitter(cap.geometry, fo);
  for (const auto& smp : cap.samples) fitter.add(smp, true);
  const int64_t t0 = now();
  const auto fit = fitter.fit();
  std::printf("fit %.0f ms\n", static_cast<double>(now() - t0) / 1e6);
  std::printf("samples %zu used %llu fsr_fault %llu near_saturation %llu delay %.2f\n",
              cap.samples.size(), (unsigned long long)fit.counts.used,
              (unsigned long long)fit.counts.fsr_fault,
              (unsigned long long)fit.counts.near_saturation, fit.delay_samples);
  const JointModelParams fitted = fit.model(pc.model);
  std::printf("fitted b %.5f gain %.3f (truth b %.5f gain %.3f)\n", fitted.damping_nms_per_rad,
              fitted.speed_gain_s_per_rad, pc.model.damping_nms_per_rad,
              pc.model.speed_gain_s_per_rad);
  JointModelParams st = pc.model;
  st.speed_gain_s_per_rad = 0.0;
  const JointModel tm(st), fm(fitted);
  for (int i = 0; i < kAxes; ++i) {
    const auto ax = static_cast<std::size_t>(i);
    const auto& a = fit.axes[ax];
    const auto fe = fitErrors(st, fitted, i, o.max_force_n, a.reached_min_deg, a.reached_max_deg);
    const std::pair<double, double> e{fe.inner, fe.edges};
    std::printf(
        "%-9s plan %.1f..%.1f reached %.1f..%.1f truth %.1f..%.1f fit %.1f..%.1f walls %d%d "
        "zone %.1f (%.1f) rms %.4f hyst %.2f err %.3f/%.3f gain %.3f±%.3f %d b %.5f\n",
        kAxisNames[ax].data(), cap.plan.lo_deg[ax], cap.plan.hi_deg[ax], a.reached_min_deg,
        a.reached_max_deg, st.axes[ax].min_deg, st.axes[ax].max_deg, a.curve.min_deg,
        a.curve.max_deg, a.wall_min, a.wall_max, a.zone_deg, st.neutral_zone_deg[ax], a.rms_n,
        a.hysteresis_n, e.first, e.second, a.speed_gain_fitted_s_per_rad, a.speed_gain_se_s_per_rad,
        a.spasm, a.damping_nms_per_rad);
    if (std::getenv("PROBE_J"))
      std::printf("   inertia %.2e est %d col %.2f\n", a.inertia_kgm2, a.inertia_estimated,
                  a.inertia_collinearity);
    if (std::getenv("PROBE_CURVE")) {
      for (double d = a.reached_min_deg; d <= a.reached_max_deg;
           d += std::max(0.1, std::atof(std::getenv("PROBE_CURVE"))))
        std::printf("   %6.1f truth %7.2f fit %7.2f\n", d, tm.holdingForceN(i, degToRad(d)),
                    fm.holdingForceN(i, degToRad(d)));
    }
  }
  if (std::getenv("PROBE_TRUTH")) {
    const auto rate = fitter.rates();
    const auto acc = fitter.accelerations();
    const auto& pts = fitter.points();
    const JointModel full(pc.model);
    const double L = pc.model.lever_arm_m, dcap = full.maxDampingNmsPerRad();
    std::vector<double> delays{0.0, 1.0, 2.0};
    if (const char* lags = std::getenv("PROBE_LAGS")) {
      delays.clear();
      for (const auto& l : splitList(lags)) delays.push_back(std::stod(l));
    }
    for (const double delay : delays) {
      const auto kd = static_cast<std::size_t>(std::floor(delay));
      const double fd = delay - static_cast<double>(kd);
      for (int i = 0; i < kAxes; ++i) {
        double ss = 0, ssf = 0;
        std::size_t cnt = 0;
        // mean residual per 5-deg bin, stretching vs returning
        double bs[40] = {}, bn[40] = {}, cs[40] = {}, cn[40] = {};
        for (std::size_t k = 3 + kd; k + 2 < pts.size(); ++k) {
          const std::size_t q = k - kd, qb = q - 1;
          if (pts[k].seq - pts[qb].seq != kd + 1) continue;
          auto mix = [&](double later, double earlier) {
            return (1.0 - fd) * later + fd * earlier;
          };
          const double ang = mix(pts[q].angles_rad[i], pts[qb].angles_rad[i]),
                       v = mix(rate[q][i], rate[qb][i]), w = mix(acc[q][i], acc[qb][i]);
          const double fel = tm.holdingForceN(i, ang);
          const double el = -fel * L;
          const bool str = el * v < 0.0;
          const double c = std::min(pc.model.damping_nms_per_rad +
                                        (str ? pc.model.speed_gain_s_per_rad * std::abs(el) : 0.0),
                                    dcap);
          const double model =
              fel + c * v / L + server::estimate::FitOptions{}.inertia_kgm2 * w / L;
          const double r = pts[k].axis_force_n[i] - model;
          ss += r * r;
          const double rf =
              pts[k].axis_force_n[i] - fm.holdingForceN(i, ang) -
              fit.axes[static_cast<std::size_t>(i)].dynamicForceN(radToDeg(ang), v, w, L);
          ssf += rf * rf;
          ++cnt;
          const int b = std::clamp(static_cast<int>((radToDeg(ang) + 60.0) / 5.0), 0, 39);
          if (std::abs(v) > 0.5) {
            if (str) {
              bs[b] += r;
              cs[b] += 1;
            } else {
              bn[b] += r;
              cn[b] += 1;
            }
          }
        }
        std::printf("delay %.2f %-9s truth rms %.3f fit rms %.3f\n", delay,
                    kAxisNames[static_cast<std::size_t>(i)].data(),
                    std::sqrt(ss / static_cast<double>(cnt)),
                    std::sqrt(ssf / static_cast<double>(cnt)));
        if (std::getenv("PROBE_BINS") &&
            std::abs(delay - std::atof(std::getenv("PROBE_BINS"))) < 1e-9)
          for (int b = 0; b < 40; ++b)
            if (cs[b] > 50 || cn[b] > 50)
              std::printf("   %5.0f stretch %6.2f (%4.0f) return %6.2f (%4.0f)\n", b * 5.0 - 60.0,
                          cs[b] > 0 ? bs[b] / cs[b] : 0.0, cs[b], cn[b] > 0 ? bn[b] / cn[b] : 0.0,
                          cn[b]);
      }
    }
  }
  if (const char* dump = std::getenv("PROBE_DUMP")) {
    FILE* f = std::fopen(dump, "w");
    const auto rate = fitter.rates();
    const auto acc = fitter.accelerations();
    const auto& pts = fitter.points();
    const JointModel tmd(pc.model);
    std::fprintf(f, "# lever %.6f b %.6f gain %.6f cap %.6f\n", pc.model.lever_arm_m,
                 pc.model.damping_nms_per_rad, pc.model.speed_gain_s_per_rad,
                 tmd.maxDampingNmsPerRad());
    for (std::size_t k = 0; k < pts.size(); ++k)
      std::fprintf(
          f,
          "%lld %.5f %.5f %.5f %.4f %.4f %.4f %.4f %.4f %.4f %.2f %.2f %.2f %.5f %.5f "
          "%.5f\n",
          (long long)pts[k].seq, radToDeg(pts[k].angles_rad[0]), radToDeg(pts[k].angles_rad[1]),
          radToDeg(pts[k].angles_rad[2]), pts[k].axis_force_n[0], pts[k].axis_force_n[1],
          pts[k].axis_force_n[2], rate[k][0], rate[k][1], rate[k][2], acc[k][0], acc[k][1],
          acc[k][2], tmd.holdingForceN(0, pts[k].angles_rad[0]),
          tmd.holdingForceN(1, pts[k].angles_rad[1]), tmd.holdingForceN(2, pts[k].angles_rad[2]));
    std::fclose(f);
  }
  return 0;
}

int run(int argc, char** argv) {
  if (argc > 1 && (std::strcmp(argv[1], "--help") == 0 || std::strcmp(argv[1], "-h") == 0)) {
    std::printf(
        "usage: telehand_bench_capture [--quick]\n"
        "         kNN query cost per tick and live refit latency\n"
        "       telehand_bench_capture --fit-table [CASES_DIR (deploy/cases)] [--cases a,b]\n"
        "         [--hz 0.5,3,6] [--seeds FIRST,COUNT] [--random S1,S2,...]\n"
        "         [--turn-window H (the turns' accelerations over +-H samples)]\n"
        "         [--turn-rate-window H (the turns' rates over +-H samples, 0: as elsewhere)]\n"
        "         [--rate-window H (the rates elsewhere over +-H samples)]\n"
        "         [--acc-window H (the accelerations over +-H samples)]\n"
        "         [--inertia-collinearity C (0: always the known inertia)]\n"
        "         [--saturation-margin M (FitOptions::saturation_margin; 0: only the\n"
        "          saturated samples left out)]\n"
        "         [--sweep-seconds S (capture length per axis, as telehand-client's)]\n"
        "         [--rig-substeps N (the simulated finger integrated N times a sample)]\n"
        "         fitted holding force against the truth (docs/capture.md)\n"
        "       telehand_bench_capture --fit-table --technique massage [--seconds S] "
        "[--noise N]\n"
        "       telehand_bench_capture --probe CASE_FILE|random-SEED HZ SEED\n"
        "         one capture fitted; PROBE_CURVE, PROBE_TRUTH, PROBE_LAGS, PROBE_BINS,\n"
        "         PROBE_NOSPASM, PROBE_RHW, PROBE_THW, PROBE_TRHW, PROBE_AHW, PROBE_JCOL,\n"
        "         PROBE_J, PROBE_NOISE, PROBE_SECONDS, PROBE_SUBSTEPS, PROBE_DUMP\n"
        "         (see the source's header)\n");
    return 0;
  }
  if (argc > 4 && std::strcmp(argv[1], "--probe") == 0)
    return probe(argv[2], std::stod(argv[3]), std::stoull(argv[4]));
  if (argc > 1 && std::strcmp(argv[1], "--fit-table") == 0) {
    TableOptions t;
    int a = 2;
    if (argc > a && argv[a][0] != '-') t.cases_dir = argv[a++];
    for (; a + 1 < argc; a += 2) {
      const std::string key = argv[a], val = argv[a + 1];
      if (key == "--cases") {
        t.cases = splitList(val);
        t.cases_given = true;
      } else if (key == "--hz") {
        t.hz.clear();
        for (const auto& h : splitList(val)) t.hz.push_back(std::stod(h));
      } else if (key == "--seeds") {  // FIRST,COUNT
        const auto v = splitList(val);
        t.first_seed = std::stoull(v.at(0));
        t.seeds = v.size() > 1 ? std::stoull(v[1]) : 1;
      } else if (key == "--random") {  // randomPatientCase (randomTissue) seeds
        if (!t.cases_given) t.cases.clear();
        for (const auto& r : splitList(val)) t.random.push_back(std::stoull(r));
      } else if (key == "--technique") {
        t.massage = val == "massage";
        if (t.massage && !t.cases_given && t.random.empty())
          t.cases = {"healthy", "oedema", "scar", "hypertonic"};
      } else if (key == "--seconds") {
        t.seconds = std::stod(val);
      } else if (key == "--sweep-seconds") {
        t.sweep_seconds = std::stod(val);
      } else if (key == "--rig-substeps") {
        t.rig_substeps = std::stoi(val);
      } else if (key == "--noise") {
        t.noise_n = std::stod(val);
      } else if (key == "--each") {
        t.each = val != "0";
      } else if (key == "--turn-window") {  // FitOptions::turn_half_window, samples
        t.fit.turn_half_window = std::stoi(val);
      } else if (key == "--turn-rate-window") {  // FitOptions::turn_rate_half_window
        t.fit.turn_rate_half_window = std::stoi(val);
      } else if (key == "--rate-window") {  // FitOptions::rate_half_window
        t.fit.rate_half_window = std::stoi(val);
      } else if (key == "--acc-window") {  // FitOptions::acc_half_window
        t.fit.acc_half_window = std::stoi(val);
      } else if (key == "--inertia-collinearity") {  // FitOptions::max_inertia_collinearity
        t.fit.max_inertia_collinearity = std::stod(val);
      } else if (key == "--saturation-margin") {  // FitOptions::saturation_margin
        t.fit.saturation_margin = std::stod(val);
      } else {
        std::fprintf(stderr, "unknown option %s\n", key.c_str());
        return 2;
      }
    }
    return t.massage ? massageTable(t) : fitTable(t);
  }
  const bool quick = argc > 1 && std::strcmp(argv[1], "--quick") == 0;
  spdlog::set_level(spdlog::level::warn);
  // 1. k-nearest neighbours per tick.
  // Flexion and abduction swept together (the coupled-joint capture): samples fill the plane.
  server::estimate::SyntheticCaptureOptions o;
  o.seconds_per_axis = quick ? 4.0 : 20.0;
  o.combined_sweep = true;
  o.frequency_hz = 0.1;
  o.max_force_n = 8.0;
  const auto train = server::estimate::synthesizeCapture(o);
  o.seed = 2;
  const auto held = server::estimate::synthesizeCapture(o);
  server::estimate::CaptureFitter ft(train.geometry), fh(held.geometry);
  for (const auto& s : train.samples) ft.add(s, true);
  for (const auto& s : held.samples) fh.add(s, true);
  std::vector<KnnPoint> raw;
  for (const auto& p : ft.points())
    raw.push_back({p.angles_rad, -p.axis_force_n * train.geometry.lever_arm_m});
  const KnnTorqueModel cells(voxelAverage(raw, KnnOptions{}.cell_deg));
  const KnnTorqueModel all(raw);
  std::printf("kNN model: %zu cell-averaged samples (the live model), %zu raw samples; k = %d\n",
              cells.size(), all.size(), KnnOptions{}.k);
  const auto& q = fh.points();
  volatile double sink = 0.0;
  for (const KnnTorqueModel* m : {&cells, &all}) {
    std::vector<int64_t> t;
    t.reserve(q.size());
    for (const auto& p : q) {
      const int64_t t0 = now();
      sink = sink + m->torqueNm(p.angles_rad)[0];
      t.push_back(now() - t0);
    }
    report(
        m == &cells ? "query back to back, cell-averaged model" : "query back to back, raw samples",
        t);
  }
  {
    // Paced at 1 kHz: one query per millisecond along the held-out trajectory.
    const std::size_t ticks = quick ? 1000 : 10000;
    std::vector<int64_t> t;
    t.reserve(ticks);
    int64_t next = now() + kNsPerMs;
    for (std::size_t i = 0; i < ticks; ++i) {
      sleepUntil(next);
      next += kNsPerMs;
      const int64_t t0 = now();
      sink = sink + cells.torqueNm(q[i % q.size()].angles_rad)[0];
      t.push_back(now() - t0);
    }
    report("query paced at 1 kHz, cell-averaged model", t);
  }
  {
    JointModelParams p = healthyIndexMcp();
    p.knn = &cells;
    JointProxy knn_proxy(p), cubic_proxy(healthyIndexMcp());
    const JointModel geo(p);
    for (JointProxy* proxy : {&cubic_proxy, &knn_proxy}) {
      std::vector<int64_t> t;
      int64_t clock = kNsPerS;
      for (const auto& pt : q) {
        const auto grip = geo.gripFromAngles(pt.angles_rad, 0.008);
        clock += kNsPerMs;
        const int64_t t0 = now();
        sink = sink + proxy->render(grip, clock).torque_ref_nm[0];
        t.push_back(now() - t0);
      }
      report(
          proxy == &knn_proxy ? "JointProxy::render, kNN model" : "JointProxy::render, cubic model",
          t);
    }
  }

  // 2. Live refit latency, real time.
  namespace fs = std::filesystem;
  const fs::path dir =
      fs::temp_directory_path() / ("telehand-bench-capture-" + std::to_string(getpid()));
  fs::create_directories(dir);
  {
    server::store::SqliteStore store((dir / "r.db").string());
    Recorder out;
    server::session::SessionManager mgr(store, out, ServerConfig{});
    telehand_msg_SessionCommand open{};
    open.client_id = 1;
    open.kind = telehand_msg_CMD_OPEN;
    open.mode = telehand_msg_MODE_CAPTURE;
    std::strcpy(open.case_name, "healthy");
    mgr.onCommand(open, now());
    server::estimate::SyntheticCaptureOptions lo;
    lo.seconds_per_axis = quick ? 2.0 : 6.0;
    const auto cap = server::estimate::synthesizeCapture(lo);
    std::vector<int64_t> latency, compute, chunk_cost;
    std::vector<telehand_msg_DeviceState> chunk;
    int64_t next_chunk = now();
    int64_t last_latency_seen = 0;
    int published_before = 0;
    for (std::size_t i = 0; i < cap.samples.size(); i += 100) {
      // The server ticks every few ms between chunks (its waitset wakes on data or timeout).
      while (now() < next_chunk) {
        const int64_t t0 = now();
        mgr.tick(t0);
        const int64_t dt = now() - t0;
        if (out.capture_models != published_before) {
          published_before = out.capture_models;
          compute.push_back(dt);
          if (mgr.stats().last_refit_latency_ns != last_latency_seen) {
            last_latency_seen = mgr.stats().last_refit_latency_ns;
            latency.push_back(last_latency_seen + dt);
          }
        }
        sleepUntil(std::min(next_chunk, now() + 2 * kNsPerMs));
      }
      next_chunk += 100 * kNsPerMs;
      chunk.clear();
      for (std::size_t j = i; j < std::min(i + 100, cap.samples.size()); ++j)
        chunk.push_back(toWire(cap.samples[j]));
      for (auto& s : chunk) s.session_id = 1;
      telehand_msg_RecordChunk c{};
      c.session_id = 1;
      c.chunk_seq = i / 100;
      c.samples._buffer = chunk.data();
      c.samples._length = static_cast<uint32_t>(chunk.size());
      c.samples._maximum = c.samples._length;
      const int64_t t0 = now();
      mgr.onChunk(c, t0);
      chunk_cost.push_back(now() - t0);
    }
    std::printf(
        "live refit: %d models published from a %.0f s capture (%zu samples), refit at most every "
        "%.1f s;\n"
        "  a sample that arrives just after a refit waits for the next one (up to that interval)\n",
        out.capture_models, static_cast<double>(cap.samples.size()) / 1000.0, cap.samples.size(),
        static_cast<double>(server::estimate::LiveRefitOptions{}.min_interval_ns) / 1e9);
    if (!latency.empty()) {
      report("newest sample's arrival -> model published", latency, 1e6, "ms");
      report("refit compute (tick that published)", compute, 1e6, "ms");
    }
    report("storing + feeding one 100-sample chunk", chunk_cost, 1e6, "ms");
    std::printf(
        "  end to end add the client's chunking (a sample waits up to 100 ms for its chunk) "
        "and DDS (~0.1 ms on loopback)\n");
    mgr.closeAll(now());
  }
  fs::remove_all(dir);
  return sink == 12345.678 ? 1 : 0;
}

int main(int argc, char** argv) {
  // A case file that cannot be read, a number that does not parse: said, not a crash.
  try {
    return run(argc, argv);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "telehand_bench_capture: %s (--help: usage)\n", e.what());
    return 2;
  }
}
