// telehand-teleop-bench: the teleoperation matrix in simulated time. Every cell runs the
// client's HapticLoop (simulated MF-2, virtual clinician mobilizing at 3 Hz in 12-16 N) and
// the server's SessionManager (Bullet hand, recovering joint publishing model updates)
// across an emulated link, and prints per cell: stable or not, passive or not, RMS force
// error against the zero-delay model-mediated run, the largest force step from a model
// update, packets per second each way, and loop overruns. With --massage, the same for the
// circular massage of the web (simulated clinician circling with 10 ± 2 N, the web's tissue
// model in the JointModel the server sends): stable, passive, normal force in band and the
// server's web against the client's proxy, per link profile.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <iostream>
#include <optional>
#include <sstream>

#include "telehand/app/cli.h"
#include "telehand/core/error.h"
#include "telehand/netem/teleop_harness.h"

namespace {

using namespace telehand;
using namespace telehand::teleop;
using client::loop::RenderMode;

LinkProfile matrixLink(double rtt_ms, double loss_pct) {
  LinkProfile p;
  std::ostringstream n;
  n << rtt_ms << "ms-" << loss_pct << "%";
  p.name = n.str();
  p.rtt_ms = rtt_ms;
  p.jitter_ms = rtt_ms / 4.0;  // ±250 ms at 1 s RTT
  p.jitter_corr_ms = 100.0;
  p.loss_pct = loss_pct;
  p.loss_burst = 4.0;
  p.reorder_pct = rtt_ms > 0.0 ? 0.5 : 0.0;
  return p;
}

const char* modeName(RenderMode m) { return m == RenderMode::kModel ? "model-mediated" : "direct"; }

void printRow(const CellSpec& spec, const CellResult& r, double err, bool markdown) {
  // In direct mode the client's proxy renders nothing: its fades are not felt.
  char step[64] = "n/a";
  if (spec.render == RenderMode::kModel) {
    std::snprintf(step, sizeof step, "%.3f N (%.2f), %.1f µJ", r.update_step_max_n,
                  r.update_step_ratio, r.fade_unpaid_j * 1e6);
  }
  char line[512];
  std::snprintf(
      line, sizeof line,
      markdown ? "| %s | %s | %.0f ±%.0f | %.0f | %s (%.1f %%) | %s (%.1f mJ, %llu) | %.1f %% | "
                 "%s | %.2f° / %.2f° (%llu) | %.0f | %.0f | %.0f | %llu (%.0f µs) |"
               : "%-15s %-18s %5.0f ±%-4.0f %4.0f  %-8s %5.1f%%  %-3s %7.1f mJ %6llu  %6.1f%%  "
                 "%-15s  %5.2f/%5.2f deg (%llu)  %6.0f %6.0f %6.0f  %llu (%.0f us)",
      modeName(spec.render), spec.link.name.c_str(), spec.link.rtt_ms, spec.link.jitter_ms,
      spec.link.loss_pct, stable(r) ? "stable" : "UNSTABLE", r.oscillation * 100.0,
      passive(r) ? "yes" : "NO", r.po_min_j * 1e3, static_cast<unsigned long long>(r.pc_ticks),
      err * 100.0, step, r.drift_mean_deg, r.drift_rms_deg,
      static_cast<unsigned long long>(r.drift_corrections), r.device_state_pps, r.up_pps,
      r.down_pps, static_cast<unsigned long long>(r.overruns), r.step_max_us);
  std::cout << line << std::endl;
}

void printMassageRow(const LinkProfile& link, const CellResult& r, bool markdown) {
  char line[512];
  std::snprintf(
      line, sizeof line,
      markdown ? "| %s | %.0f ±%.0f | %.3g | %s (%s, %llu clamps) | %s (%.2f mJ, %llu) | %.1f %% | "
                 "%.2f N | %.3g %% / %.3g %% (%llu) | %llu | %llu (%.0f µs) |"
               : "%-18s %5.0f ±%-4.0f %5.3g%%  %-8s (%s, %llu clamps)  %-3s %7.2f mJ %6llu  "
                 "in band %5.1f%%  max %.2f N  web error max %.3g%% RMS %.3g%% (%llu)  models "
                 "%llu  overruns %llu (%.0f us)",
      link.name.c_str(), link.rtt_ms, link.jitter_ms, link.loss_pct,
      massageStable(r) ? "stable" : "UNSTABLE",
      client::loop::faultName(static_cast<client::loop::LoopFault>(r.fault)),
      static_cast<unsigned long long>(r.clamped), passive(r) ? "yes" : "NO", r.po_min_j * 1e3,
      static_cast<unsigned long long>(r.pc_ticks), 100.0 * r.massage_in_band, r.web_force_max_n,
      100.0 * r.web_error_max, 100.0 * r.web_error_rms,
      static_cast<unsigned long long>(r.web_compared),
      static_cast<unsigned long long>(r.models_applied),
      static_cast<unsigned long long>(r.overruns), r.step_max_us);
  std::cout << line << std::endl;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "telehand-teleop-bench: model-mediated against direct rendering over emulated "
      "links (RTT x loss), in simulated time, with the real loop and server code"};
  std::vector<double> rtts = {0, 50, 150, 300, 600, 1000};
  std::vector<double> losses = {0, 2, 10};
  std::vector<std::string> modes = {"model", "direct"};
  std::vector<std::string> profiles;
  std::vector<double> deadbands;
  double seconds = 20.0, steady = 4.0, treatment = 20.0;
  uint64_t seed = 1;
  bool markdown = false, no_hand = false, no_pc = false, drift = false, massage = false,
       no_joint = false;
  std::string massage_case = "healthy";
  std::string case_name = "regain";
  std::string clinician = "force";
  app.add_option("--rtt", rtts, "round trips, ms")
      ->check(CLI::Range(0.0, 10000.0))
      ->capture_default_str();
  app.add_option("--loss", losses, "mean losses, % (bursty, 4 packets per burst)")
      ->check(CLI::Range(0.0, 90.0))
      ->capture_default_str();
  app.add_option("--modes", modes, "model, direct")
      ->check(CLI::IsMember({"model", "direct"}))
      ->capture_default_str();
  app.add_option("--profile", profiles, "also run these link profiles (deploy/links/*.toml)")
      ->check(CLI::ExistingFile);
  app.add_option("--deadband", deadbands,
                 "also run model-mediated cells with these Weber fractions")
      ->check(CLI::Range(0.0, 0.5));
  app.add_option("--seconds", seconds, "simulated session length")
      ->capture_default_str()
      ->check(CLI::Range(2.0, 3600.0));
  app.add_option("--steady-from", steady, "metrics from this time on (after the ramp), s")
      ->capture_default_str();
  app.add_option("--clinician", clinician,
                 "force: pushes the paper's 12-16 N band; servo: moves the joint along a set path "
                 "through that band, so the force shows what is rendered")
      ->check(CLI::IsMember({"force", "servo"}))
      ->capture_default_str();
  app.add_option("--case", case_name, "patient case (tests/teleop/cases, deploy/cases)")
      ->capture_default_str();
  app.add_option("--recovery-s", treatment,
                 "treatment time over which a recovering case regains its range")
      ->capture_default_str();
  app.add_option("--seed", seed, "operator and link seed")->capture_default_str();
  app.add_flag("--markdown", markdown, "print Markdown tables");
  app.add_flag("--no-hand", no_hand,
               "no Bullet hand on the server (no treatment, no recovery updates)");
  app.add_flag("--no-passivity-control", no_pc, "observe passivity but never add damping");
  app.add_flag("--drift", drift,
               "also compare drift (hand against proxy) with the server's correction off and on");
  app.add_flag("--massage", massage,
               "also run the massage of the web (model-mediated) over no delay and each --profile");
  app.add_option("--massage-case", massage_case,
                 "patient case of the massage (its web: tissueCase of the name unless the file "
                 "gives one)")
      ->capture_default_str();
  app.add_flag("--no-joint", no_joint, "skip the mobilization matrix (with --massage)");
  TELEHAND_CLI_PARSE(app, argc, argv)

  try {
    if (steady >= seconds) throw telehand::ConfigError("--steady-from must be below --seconds");
    std::optional<server::sim::HandModel> hand;
    if (!no_hand)
      hand = server::sim::HandModel::load(std::string(TELEHAND_DEPLOY_DIR) + "/hand/hand24.urdf");
    auto spec = [&](const LinkProfile& link, RenderMode mode) {
      CellSpec s;
      s.link = link;
      s.render = mode;
      s.seconds = seconds;
      s.steady_from_s = steady;
      s.case_name = case_name;
      s.recovery_treatment_s = treatment;
      s.seed = seed;
      s.passivity_control = !no_pc;
      s.clinician = clinician == "servo" ? Clinician::kServo : Clinician::kForceBand;
      return s;
    };
    int failures = 0;
    if (massage) {
      std::cout << "massage (model-mediated, case " << massage_case
                << "): the simulated clinician circling on the web with 10 ± 2 N; stable: no "
                   "loop fault; passive: lowest observer energy; in band: ticks both pads "
                   "measured 10 ± 2 N; web error: the server's web force (HandState) against "
                   "the client's proxy for the same sample, per finger, over max(|F|, 1 N)\n";
      if (markdown) {
        std::cout << "| link | RTT ms | loss % | stable (fault, clamps) | passive (lowest PO "
                     "energy, PC ticks) | both pads in 10 ± 2 N | largest web force | "
                     "proxy/server force error max / RMS (HandStates) | models applied | "
                     "overruns (worst step CPU) |\n"
                     "|---|---|---|---|---|---|---|---|---|---|\n";
      }
      std::vector<LinkProfile> links = {matrixLink(0, 0)};
      for (const auto& path : profiles) links.push_back(loadLinkProfile(path));
      for (const auto& link : links) {
        CellSpec s = spec(link, RenderMode::kModel);
        s.technique = Technique::kMassage;
        s.case_name = massage_case;
        const CellResult r = runCell(s, hand ? &*hand : nullptr);
        printMassageRow(link, r, markdown);
        if (r.samples_recorded != r.ticks) {
          std::cout << "  record incomplete: " << r.samples_recorded << " of " << r.ticks << "\n";
          ++failures;
        }
      }
      if (no_joint) return failures ? 1 : 0;
      std::cout << "\n";
    }
    const CellSpec ref_spec = spec(matrixLink(0, 0), RenderMode::kModel);
    const CellResult ref = runCell(ref_spec, hand ? &*hand : nullptr);
    std::cout << "reference: model-mediated, no delay, no loss: " << ref.models_applied
              << " model versions applied, " << ref.samples_recorded << " of " << ref.ticks
              << " samples recorded\n\n";
    if (markdown) {
      std::cout
          << "| mode | link | RTT ms | loss % | stable (force above 15 Hz) | passive (lowest PO "
             "energy, PC ticks) | "
             "RMS force error | largest update step (/ bound), unpaid fade energy | drift mean / "
             "RMS (corrections) | DeviceState /s | up /s | down /s | overruns (worst step CPU) |\n"
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
    } else {
      std::cout << "mode            link               RTT ms      loss  stable   osc     passive  "
                   "PO min  PC ticks  "
                   "error   update step      drift mean/RMS (corr)  DS/s   up/s down/s  overruns\n";
    }
    auto run = [&](const CellSpec& s) {
      const CellResult r = runCell(s, hand ? &*hand : nullptr);
      const double err = forceError(r, ref, s);
      printRow(s, r, err, markdown);
      if (r.samples_recorded != r.ticks) {
        std::cout << "  record incomplete: " << r.samples_recorded << " of " << r.ticks << "\n";
        ++failures;
      }
      return std::make_pair(r, err);
    };
    for (const auto& m : modes) {
      const RenderMode mode = m == "model" ? RenderMode::kModel : RenderMode::kDirect;
      for (double rtt : rtts) {
        for (double loss : losses) run(spec(matrixLink(rtt, loss), mode));
      }
      for (const auto& path : profiles) run(spec(loadLinkProfile(path), mode));
    }
    if (!deadbands.empty()) {
      std::cout
          << "\ndeadband (model-mediated): DeviceState packets against every sample, rendered "
             "force error against the same link without deadband, server-side reconstruction "
             "error\n";
      if (markdown) {
        std::cout << "| link | Weber | DeviceState /s | fewer packets | rendered force error | "
                     "reconstruction error | HandState /s |\n"
                     "|---|---|---|---|---|---|---|\n";
      }
      for (const auto& link : {matrixLink(0, 0), matrixLink(300, 2)}) {
        const CellSpec base = spec(link, RenderMode::kModel);
        const CellResult full = runCell(base, hand ? &*hand : nullptr);
        for (double w : deadbands) {
          CellSpec s = base;
          s.deadband.weber = w;
          const CellResult r = runCell(s, hand ? &*hand : nullptr);
          char line[400];
          std::snprintf(
              line, sizeof line,
              markdown
                  ? "| %s | %.2f | %.0f (of %.0f) | %.1f %% | %.2f %% | %.2f %% | %.0f (of %.0f) |"
                  : "%-14s weber %.2f  DeviceState %5.0f/s (of %.0f)  %.1f %% fewer  rendered "
                    "error %.2f %%  "
                    "reconstruction error %.2f %%  HandState %.0f/s (of %.0f)",
              link.name.c_str(), w, r.device_state_pps, full.device_state_pps,
              100.0 * (1.0 - r.device_state_pps / full.device_state_pps),
              100.0 * forceError(r, full, s), 100.0 * r.reconstruction_error, r.hand_state_pps,
              full.hand_state_pps);
          std::cout << line << std::endl;
        }
      }
    }
    if (drift) {
      std::cout << "\ndrift (model-mediated): the server's hand against the client's proxy, same "
                   "device sample, largest axis; force error against the zero-delay run with the "
                   "correction on\n";
      if (markdown) {
        std::cout << "| link | correction | drift mean | drift RMS | corrections | largest update "
                     "step (/ bound) | RMS force error |\n"
                     "|---|---|---|---|---|---|---|\n";
      }
      std::vector<LinkProfile> links = {matrixLink(0, 0), matrixLink(300, 2), matrixLink(1000, 10)};
      for (const auto& path : profiles) links.push_back(loadLinkProfile(path));
      for (const auto& link : links) {
        for (bool on : {false, true}) {
          CellSpec s = spec(link, RenderMode::kModel);
          s.drift_correction = on;
          const CellResult r = runCell(s, hand ? &*hand : nullptr);
          char line[400];
          std::snprintf(
              line, sizeof line,
              markdown
                  ? "| %s | %s | %.2f° | %.2f° | %llu | %.3f N (%.2f) | %.1f %% |"
                  : "%-18s correction %-3s  drift mean %.2f deg  RMS %.2f deg  %llu corrections  "
                    "update step %.3f N (%.2f)  force error %.1f %%",
              link.name.c_str(), on ? "on" : "off", r.drift_mean_deg, r.drift_rms_deg,
              static_cast<unsigned long long>(r.drift_corrections), r.update_step_max_n,
              r.update_step_ratio, 100.0 * forceError(r, ref, s));
          std::cout << line << std::endl;
        }
      }
    }
    return failures ? 1 : 0;
  } catch (const telehand::Error& e) {
    std::cerr << "telehand-teleop-bench: " << e.what() << "\n";
    return 2;
  }
}
