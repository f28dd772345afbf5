#include "records_fit.h"

#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>

#include "file_output.h"
#include "records_tissue.h"
#include "telehand/config/config.h"
#include "telehand/core/error.h"
#include "telehand/server/estimate/capture_fit.h"
#include "telehand/server/estimate/synthetic_capture.h"
#include "telehand/server/store/open_store.h"

namespace telehand::records {

namespace fs = std::filesystem;
using server::estimate::CaptureFit;
using server::estimate::CaptureFitter;

bool runGnuplot(const fs::path& out, const std::string& format, std::string& error,
                const std::function<void(FILE*)>& script) {
  FILE* gp = popen("gnuplot 2>&1", "w");
  if (!gp) {
    error = "cannot run gnuplot (deploy/setup.sh installs gnuplot-nox)";
    return false;
  }
  const std::string terminal =
      format == "png" ? "pngcairo size 900,800 font ',10'" : "svg size 900,800 font 'sans,11'";
  std::fprintf(gp, "set terminal %s\nset output '%s'\n", terminal.c_str(), out.string().c_str());
  script(gp);
  const int status = pclose(gp);
  if (status != 0) {
    error = "gnuplot failed (exit status " + std::to_string(WEXITSTATUS(status)) + ") writing '" +
            out.string() + "'" +
            (WEXITSTATUS(status) == 127
                 ? ": gnuplot is not installed (deploy/setup.sh installs gnuplot-nox)"
                 : "");
    return false;
  }
  return true;
}

namespace {

/// The joint frame and lever arm a session's angles and forces refer to: its patient case
/// when the case file is there, else the default joint's.
JointModelParams sessionGeometry(const std::string& cases_dir, const std::string& case_name) {
  JointModelParams g = healthyIndexMcp();
  std::error_code ec;
  if (!cases_dir.empty() && fs::exists(fs::path(cases_dir) / (case_name + ".toml"), ec)) {
    g = loadPatientCaseByName(cases_dir, case_name).model;
  }
  return server::estimate::captureGeometry(g);
}

/// One plot per axis like the paper's Fig. 3b: the captured force against the angle with
/// the fitted cubic, and the residual below.
bool plotAxis(const CaptureFitter& fitter, const std::vector<Vec3>& rates,
              const std::vector<Vec3>& accs, const CaptureFit& fit, double lever_m, int axis,
              const fs::path& out, const std::string& format, const std::string& title,
              std::string& error) {
  const auto ax = static_cast<std::size_t>(axis);
  const auto& a = fit.axes[ax];
  const auto& pts = fitter.points();
  return runGnuplot(out, format, error, [&](FILE* gp) {
    // Decimate to at most ~8000 points: the plot shows the cloud, the fit used them all.
    const std::size_t stride = std::max<std::size_t>(1, pts.size() / 8000);
    std::fprintf(gp, "$data << EOD\n");
    for (std::size_t i = 0; i < pts.size(); i += stride) {
      const double deg = radToDeg(pts[i].angles_rad[axis]);
      const double f = pts[i].axis_force_n[axis];
      const double dynamic =
          (a.damping_nms_per_rad * rates[i][axis] + a.inertia_kgm2 * accs[i][axis]) / lever_m;
      std::fprintf(gp, "%.5f %.5f %.5f\n", deg, f, f - a.holdingForceN(deg) - dynamic);
    }
    std::fprintf(gp, "EOD\n");
    // The fitted holding force as the joint model renders it (neutral zone, walls).
    std::fprintf(gp, "$model << EOD\n");
    for (double d = a.reached_min_deg; d <= a.reached_max_deg; d += 0.25)
      std::fprintf(gp, "%.3f %.5f\n", d, a.holdingForceN(d));
    std::fprintf(gp, "EOD\n");
    const auto& c = a.curve.coeffs;
    std::fprintf(gp, "f(x) = ((%.12g*x + %.12g)*x + %.12g)*x + %.12g\n", c[0], c[1], c[2], c[3]);
    char curve_title[160], rms_title[64];
    std::snprintf(curve_title, sizeof curve_title, "cubic: %.4g a^3 %+.4g a^2 %+.4g a %+.4g", c[0],
                  c[1], c[2], c[3]);
    std::snprintf(rms_title, sizeof rms_title, "residual, RMS %.3f N", a.rms_n);
    std::fprintf(gp,
                 "set multiplot layout 2,1 title \"%s\"\n"
                 "set grid\nset xrange [%.3f:%.3f]\n"
                 "set size 1,0.65\nset origin 0,0.35\n"
                 "set ylabel 'force at the lever arm (N)'\nunset xlabel\n"
                 "plot $data using 1:2 with points pt 7 ps 0.2 lc rgb '#7799bb' title 'captured', "
                 "$model using 1:2 with lines lw 2.5 lc rgb '#cc2222' title '%s'\n"
                 "set size 1,0.35\nset origin 0,0\n"
                 "set xlabel '%s angle (deg)'\nset ylabel 'residual (N)'\n"
                 "plot $data using 1:3 with points pt 7 ps 0.2 lc rgb '#555555' title '%s', 0 with "
                 "lines lc rgb '#cc2222' notitle\n"
                 "unset multiplot\n",
                 title.c_str(), a.reached_min_deg, a.reached_max_deg, curve_title,
                 std::string(kAxisNames[ax]).c_str(), rms_title);
  });
}

}  // namespace

int runFit(const FitRequest& r) {
  const auto opened = server::store::openStore(r.db, server::store::SessionStore::Mode::kReadOnly);
  server::store::SessionStore& store = *opened;
  const auto info = store.session(r.session);
  if (!info) {
    std::cerr << "telehand-records: no session " << r.session << " in " << store.location() << "\n";
    return 2;
  }
  // A capture of a web says so in its record ("capture-massage"); --technique massage fits a
  // plain capture's samples as a web.
  if (r.technique == "massage" || info->mode == "capture-massage")
    return runFitMassage(r, store, *info);
  if (info->mode != "capture") {
    std::cerr << "telehand-records: session " << r.session << " is a " << info->mode
              << " session; only capture sessions (actuators off) measure a real joint\n";
    return 2;
  }
  const std::string name = r.name.empty() ? "capture-" + std::to_string(r.session) : r.name;
  const fs::path output = r.output.empty() ? fs::path(name + ".toml") : fs::path(r.output);
  const fs::path plots = r.plots_dir.empty() ? output.parent_path() : fs::path(r.plots_dir);
  if (r.plot_format != "svg" && r.plot_format != "png") {
    std::cerr << "telehand-records: --plot-format must be svg or png, not '" << r.plot_format
              << "'\n";
    return 2;
  }

  const JointModelParams geometry = sessionGeometry(r.cases_dir, info->case_name);
  CaptureFitter fitter(geometry);
  const uint64_t total = info->samples;
  uint64_t seen = 0, next_report = total / 10;
  store.forEachSample(r.session, [&](const Sample& s, bool valid) {
    fitter.add(s, valid);
    if (++seen >= next_report && total > 50'000 && !r.quiet) {
      std::cerr << "reading samples: " << seen << " / " << total << " (" << (100 * seen / total)
                << " %)\n";
      next_report += total / 10;
    }
  });
  const CaptureFit fit = fitter.fit([&](int axis, double f) {
    if (!r.quiet && f == 0.0 && total > 50'000)
      std::cerr << "fitting " << kAxisNames[static_cast<std::size_t>(axis)] << "\n";
  });
  const auto& k = fit.counts;
  std::cout << "session " << r.session << ": " << total << " samples, " << k.used << " used ("
            << k.invalid << " invalid, " << k.fsr_fault << " with a flagged FSR, "
            << k.near_saturation << " near an FSR's ceiling, " << k.not_capture
            << " with the actuators on)\n";
  if (!fit.ok()) {
    for (std::size_t i = 0; i < kAxes; ++i) {
      if (!fit.axes[i].ok) {
        std::cerr << "telehand-records: " << kAxisNames[i]
                  << " could not be fitted: " << fit.axes[i].samples
                  << " samples; the capture must move every axis through "
                  << "at least a few degrees\n";
      }
    }
    return 3;
  }
  const JointModelParams model = fit.model(healthyIndexMcp());
  const std::string toml = server::estimate::patientCaseToml(
      fit, model, name,
      "fitted from capture session " + std::to_string(r.session) + " (" + info->user + ")",
      "telehand-records fit of " + store.location() + " session " + std::to_string(r.session));
  // The file must load as a case: a fit whose force falls somewhere is refused here.
  try {
    parsePatientCase(toml, output.string());
  } catch (const ConfigError& e) {
    std::cerr << "telehand-records: the fitted model is not a valid patient case: " << e.what()
              << "\n";
    return 3;
  }
  for (std::size_t i = 0; i < kAxes; ++i) {
    const auto& a = fit.axes[i];
    std::printf(
        "  %-9s range %6.1f .. %5.1f deg   RMS residual %.3f N   neutral zone %.1f .. %.1f deg   "
        "F = %.5g a^3 %+.5g a^2 %+.5g a %+.5g\n",
        kAxisNames[i].data(), a.curve.min_deg, a.curve.max_deg, a.rms_n, a.neutral_min_deg,
        a.neutral_max_deg, a.curve.coeffs[0], a.curve.coeffs[1], a.curve.coeffs[2],
        a.curve.coeffs[3]);
  }
  std::printf("  damping %.4f N m s/rad; force channel lag %.2f samples\n",
              model.damping_nms_per_rad, fit.delay_samples);
  for (std::size_t i = 0; i < kAxes; ++i) {
    const auto& a = fit.axes[i];
    std::printf(
        "  %-9s walls %s/%s   neutral zone ±%.1f deg   inertia %.2e kg m^2 (%s; free estimate "
        "%.2e ± %.1e, acceleration/angle correlation %.2f)   dynamic share %.2f N   up/down "
        "hysteresis %.2f N\n",
        kAxisNames[i].data(), a.wall_min ? "felt" : "not reached",
        a.wall_max ? "felt" : "not reached", a.zone_deg, a.inertia_kgm2,
        a.inertia_estimated ? "estimated" : "known", a.inertia_fitted_kgm2, a.inertia_se_kgm2,
        a.inertia_collinearity, a.dynamic_n, a.hysteresis_n);
    if (a.dynamic_n > 0.3) {
      std::printf(
          "  %-9s note: the curve moves %.2f N with the viscous and inertial terms; a "
          "slower mobilization measures it more directly\n",
          kAxisNames[i].data(), a.dynamic_n);
    }
    if (a.hysteresis_n > 0.6) {
      std::printf(
          "  %-9s note: up and down sweeps differ by %.2f N: a speed-dependent force "
          "(spasm?) the model does not hold\n",
          kAxisNames[i].data(), a.hysteresis_n);
    }
  }
  try {
    writeFileAtomically(output, toml);
  } catch (const Error& e) {
    std::cerr << "telehand-records: " << e.what() << "\n";
    return 2;
  }
  std::cout << "model: " << output.string() << " (case '" << name
            << "'; copy it into the server's cases directory to use it)\n";
  std::error_code ec;
  if (!plots.empty()) fs::create_directories(plots, ec);
  const std::vector<Vec3> rates = fitter.rates();
  const std::vector<Vec3> accs = fitter.accelerations();
  for (int i = 0; i < kAxes; ++i) {
    const fs::path p = plots / (name + "-" + std::string(kAxisNames[static_cast<std::size_t>(i)]) +
                                "." + r.plot_format);
    std::string error;
    if (!plotAxis(fitter, rates, accs, fit, geometry.lever_arm_m, i, p, r.plot_format,
                  "session " + std::to_string(r.session) + ": " +
                      std::string(kAxisNames[static_cast<std::size_t>(i)]),
                  error)) {
      std::cerr << "telehand-records: " << error << "\n";
      return 3;
    }
    std::cout << "plot: " << p.string() << "\n";
  }
  return 0;
}

int runSynth(const SynthRequest& r) {
  if (r.technique == "massage") return runSynthMassage(r);
  server::estimate::SyntheticCaptureOptions o;
  if (!r.cases_dir.empty()) {
    o.truth = loadPatientCaseByName(r.cases_dir, r.case_name).model;
  } else if (r.case_name != "healthy") {
    throw ConfigError("no cases directory to find case '" + r.case_name + "' in");
  }
  o.noise_n = r.noise_n;
  o.seconds_per_axis = r.seconds_per_axis;
  o.frequency_hz = r.frequency_hz;
  o.max_force_n = r.max_force_n;
  o.seed = r.seed;
  if (!r.device_file.empty()) o.device = mf2::loadMf2Description(r.device_file);
  const auto cap = server::estimate::synthesizeCapture(o, [&](double f) {
    if (!r.quiet && f > 0.0 && f < 1.0)
      std::cerr << "capturing: " << static_cast<int>(f * 100) << " %\n";
  });
  const auto store = server::store::openStore(r.db);
  const uint64_t id = server::estimate::storeCapture(*store, cap, r.case_name, "synthetic",
                                                     server::estimate::deviceFiles(o.device));
  std::cout << "session " << id << ": synthetic capture of case '" << r.case_name << "', "
            << cap.samples.size() << " samples, thimble noise " << r.noise_n << " N per axis\n";
  for (std::size_t i = 0; i < kAxes; ++i) {
    std::printf("  %-9s swept %.1f .. %.1f deg\n", kAxisNames[i].data(), cap.plan.lo_deg[i],
                cap.plan.hi_deg[i]);
  }
  return 0;
}

}  // namespace telehand::records
