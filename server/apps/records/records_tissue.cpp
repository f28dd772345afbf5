#include "records_tissue.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <utility>
#include <vector>

#include "file_output.h"
#include "telehand/config/config.h"
#include "telehand/core/error.h"
#include "telehand/server/estimate/synthetic_massage.h"
#include "telehand/server/estimate/tissue_fit.h"
#include "telehand/server/store/open_store.h"

namespace telehand::records {

namespace fs = std::filesystem;
using server::estimate::FittedValue;
using server::estimate::TissueFit;
using server::estimate::TissueFitter;
using server::estimate::TissuePlotData;

namespace {

/// The web a session's thimbles pressed (its nominal geometry) and the joint its case file
/// gives: the case file's [tissue] when it is there, else tissueCase(case name).
TissueParams sessionWeb(const std::string& cases_dir, const std::string& case_name,
                        JointModelParams* joint) {
  *joint = healthyIndexMcp();
  std::error_code ec;
  if (!cases_dir.empty() && fs::exists(fs::path(cases_dir) / (case_name + ".toml"), ec)) {
    const PatientCase pc = loadPatientCaseByName(cases_dir, case_name);
    *joint = pc.model;
    return pc.tissue;
  }
  return tissueCase(case_name.c_str());
}

/// Every `stride`-th point, at most about 8000: the plot shows the cloud, the fit used all.
void dataBlock(FILE* gp, const char* name, const std::vector<double>& x,
               const std::vector<double>& y, double x_scale = 1.0) {
  std::fprintf(gp, "$%s << EOD\n", name);
  const std::size_t stride = std::max<std::size_t>(1, x.size() / 8000);
  for (std::size_t i = 0; i < x.size(); i += stride)
    std::fprintf(gp, "%.6g %.6g\n", x[i] * x_scale, y[i]);
  std::fprintf(gp, "EOD\n");
}

/// The mean of y in 20 bins of x (bins with fewer than 50 points left out): the trend under
/// the thimbles' noise.
void binnedBlock(FILE* gp, const char* name, const std::vector<double>& x,
                 const std::vector<double>& y, double x_scale = 1.0) {
  std::fprintf(gp, "$%s << EOD\n", name);
  if (!x.empty()) {
    std::vector<double> xs = x;
    std::sort(xs.begin(), xs.end());
    const double lo = xs[xs.size() / 100], hi = xs[xs.size() - 1 - xs.size() / 100];
    constexpr int kBins = 20;
    std::vector<double> sx(kBins, 0.0), sy(kBins, 0.0);
    std::vector<std::size_t> n(kBins, 0);
    for (std::size_t i = 0; i < x.size(); ++i) {
      if (!(hi > lo) || x[i] < lo || x[i] > hi) continue;
      const int b = std::min(kBins - 1, static_cast<int>((x[i] - lo) / (hi - lo) * kBins));
      sx[b] += x[i];
      sy[b] += y[i];
      ++n[b];
    }
    for (int b = 0; b < kBins; ++b) {
      if (n[b] < 50) continue;
      const double c = static_cast<double>(n[b]);
      std::fprintf(gp, "%.6g %.6g\n", sx[b] / c * x_scale, sy[b] / c);
    }
  }
  std::fprintf(gp, "EOD\n");
}

std::string figure(const char* name, const FittedValue& v, const char* unit) {
  char buf[160];
  if (std::isnan(v.se)) {
    std::snprintf(buf, sizeof buf, "%s = %.4g%s", name, v.value, unit);
  } else {
    std::snprintf(buf, sizeof buf, "%s = %.4g ± %.2g%s", name, v.value, v.se, unit);
  }
  return buf;
}

struct Plot {
  std::string file, title;
};

/// One plot per fitted parameter (k and n share the normal force's, both mu the friction's):
/// the captured points, their means in bins, and the fitted line or curve.
bool plotTissue(const TissueFit& fit, const TissuePlotData& d, const fs::path& dir,
                const std::string& name, const std::string& format, const std::string& session,
                std::vector<std::string>& written, std::string& error) {
  const TissueParams& p = fit.params;
  const char* points = "with points pt 7 ps 0.2 lc rgb '#7799bb'";
  const char* means = "with linespoints pt 5 ps 0.8 lw 1.5 lc rgb '#222222' title 'mean per bin'";
  const char* model = "with lines lw 2.5 lc rgb '#cc2222'";
  auto path = [&](const char* what) { return dir / (name + "-" + what + "." + format); };

  // Normal force against depth (k, n, the surfaces, the patch).
  {
    std::vector<double> dx, dy, px, py;
    for (std::size_t i = 0; i < d.depth_m.size(); ++i) {
      auto& x = d.patch_weight[i] > 0.5 ? px : dx;
      auto& y = d.patch_weight[i] > 0.5 ? py : dy;
      x.push_back(d.depth_m[i]);
      y.push_back(d.normal_n[i]);
    }
    const fs::path out = path("normal");
    if (!runGnuplot(out, format, error, [&](FILE* gp) {
          std::fprintf(gp, "set termoption noenhanced\n");
          dataBlock(gp, "data", dx, dy, 1e3);
          dataBlock(gp, "patch", px, py, 1e3);
          binnedBlock(gp, "means", dx, dy, 1e3);
          std::fprintf(gp, "$model << EOD\n");
          for (double dd = 0.0; dd <= fit.depth_max_m * 1.02; dd += fit.depth_max_m / 200.0) {
            const double f = p.stiffness_n_per_m_pow * std::pow(dd, p.exponent);
            std::fprintf(gp, "%.6g %.6g %.6g\n", dd * 1e3, f, f * p.patch_stiffness_factor);
          }
          std::fprintf(gp, "EOD\n");
          std::fprintf(
              gp,
              "set title \"%s: normal force (Hunt-Crossley), %s, %s; surfaces %+.2f / %+.2f mm; "
              "RMS %.2f N\" noenhanced\nset grid\nset key top left\n"
              "set xlabel 'depth (mm, fitted surfaces)'\nset ylabel 'normal force (N, eq. 2)'\n"
              "set xrange [%.3f:%.3f]\n"
              "plot $data using 1:2 %s title 'captured', %s"
              "$means using 1:2 %s, $model using 1:2 %s title 'F = k depth^n'%s\n",
              session.c_str(), figure("k", fit.stiffness, " N/m^n").c_str(),
              figure("n", fit.exponent, "").c_str(), fit.surface_offset_m[0].value * 1e3,
              fit.surface_offset_m[1].value * 1e3, fit.normal_rms_n, -1.0,
              fit.depth_max_m * 1e3 * 1.05, points,
              px.empty() ? ""
                         : "$patch using 1:2 with points pt 7 ps 0.2 lc rgb '#e6a040' title "
                           "'captured in the patch', ",
              means, model,
              fit.patch_fitted ? ", $model using 1:3 with lines lw 2.5 lc rgb '#e67e22' title "
                                 "'in the patch'"
                               : "");
        }))
      return false;
    written.push_back(out.string());
  }
  struct Line {
    const char* file;
    const char* what;
    const std::vector<double>& x;
    const std::vector<double>& y;
    double x_scale;
    const char* xlabel;
    const char* ylabel;
    std::string fig;
    std::vector<std::pair<double, std::string>> slopes;  ///< per x unit as plotted
  };
  const double mu_mid = 0.5 * (p.mu_static + p.mu_kinetic);
  const std::vector<Line> lines = {
      {"damping",
       "depth-rate damping",
       d.elastic_rate,
       d.normal_excess_n,
       1.0,
       "elastic force x depth rate (N m/s)",
       "normal force beyond the elastic (N)",
       figure("lambda", fit.damping, " s/m"),
       {{p.damping_s_per_m, "lambda"}}},
      {"lateral",
       "stretch of the skin before it first slips",
       d.stick_disp_m,
       d.stick_force_n,
       1e3,
       "displacement from the touch along the thimble side axis (mm)",
       "tangential force less the viscous part (N, eq. 1)",
       figure("lateral stiffness", fit.lateral_stiffness, " N/m"),
       {{p.lateral_stiffness_n_per_m * 1e-3, "lateral stiffness"}}},
      {"friction",
       "sliding friction",
       d.slide_normal_n,
       d.slide_friction_n,
       1.0,
       "normal force (N, times the patch factor)",
       "friction along the stretch (N)",
       figure("mu_static", fit.mu_static, "") + ", " + figure("mu_kinetic", fit.mu_kinetic, ""),
       {{p.mu_static, "mu_static"},
        {mu_mid, "mean of the sawtooth"},
        {p.mu_kinetic, "mu_kinetic"}}},
      {"viscous",
       "viscous skin",
       d.side_speed_m_s,
       d.viscous_force_n,
       1.0,
       "velocity along the thimble side axis (m/s)",
       "tangential force less the stick-slip model (N)",
       figure("b", fit.viscous, " N s/m"),
       {{p.viscous_n_s_per_m, "b"}}},
  };
  for (const Line& l : lines) {
    const fs::path out = path(l.file);
    if (!runGnuplot(out, format, error, [&](FILE* gp) {
          std::fprintf(gp, "set termoption noenhanced\n");
          dataBlock(gp, "data", l.x, l.y, l.x_scale);
          binnedBlock(gp, "means", l.x, l.y, l.x_scale);
          std::fprintf(gp,
                       "set title \"%s: %s, %s (%zu points)\" noenhanced\nset grid\n"
                       "set key top left\nset xlabel '%s'\nset ylabel '%s'\n"
                       "plot $data using 1:2 %s title 'captured', $means using 1:2 %s",
                       session.c_str(), l.what, l.fig.c_str(), l.x.size(), l.xlabel, l.ylabel,
                       points, means);
          const char* colours[] = {"#cc2222", "#888888", "#1f6fb4"};
          for (std::size_t i = 0; i < l.slopes.size(); ++i) {
            std::fprintf(gp, ", %.9g*x with lines lw 2.5 lc rgb '%s' title '%s'", l.slopes[i].first,
                         colours[i % 3], l.slopes[i].second.c_str());
          }
          std::fprintf(gp, "\n");
        }))
      return false;
    written.push_back(out.string());
  }
  return true;
}

}  // namespace

int runFitMassage(const FitRequest& r, server::store::SessionStore& store,
                  const server::store::SessionInfo& info) {
  if (info.mode != "capture" && info.mode != "capture-massage") {
    std::cerr << "telehand-records: session " << r.session << " is a " << info.mode
              << " session; only capture sessions (actuators off) measure a real web\n";
    return 2;
  }
  if (r.plot_format != "svg" && r.plot_format != "png") {
    std::cerr << "telehand-records: --plot-format must be svg or png, not '" << r.plot_format
              << "'\n";
    return 2;
  }
  const std::string name = r.name.empty() ? "capture-" + std::to_string(r.session) : r.name;
  const fs::path output = r.output.empty() ? fs::path(name + ".toml") : fs::path(r.output);
  const fs::path plots = r.plots_dir.empty() ? output.parent_path() : fs::path(r.plots_dir);
  JointModelParams joint;
  const TissueParams nominal = sessionWeb(r.cases_dir, info.case_name, &joint);
  TissueFitter fitter(nominal);
  store.forEachSample(r.session, [&](const Sample& s, bool valid) { fitter.add(s, valid); });
  if (!r.quiet && info.samples > 50'000) std::cerr << "fitting the web\n";
  const TissueFit fit = fitter.fit();
  const auto& k = fit.counts;
  std::cout << "session " << r.session << ": " << info.samples << " samples, " << k.used
            << " used (" << k.invalid << " invalid, " << k.fsr_fault << " with a flagged FSR, "
            << k.not_capture << " with the actuators on)\n";
  if (!fit.ok) {
    std::cerr << "telehand-records: the web could not be fitted: " << fit.why << "\n";
    return 3;
  }
  const std::string toml = server::estimate::massageCaseToml(
      fit, joint, name,
      "fitted from massage capture session " + std::to_string(r.session) + " (" + info.user + ")",
      "telehand-records fit --technique massage of " + store.location() + " session " +
          std::to_string(r.session));
  try {
    parsePatientCase(toml, output.string());
  } catch (const ConfigError& e) {
    std::cerr << "telehand-records: the fitted web is not a valid patient case: " << e.what()
              << "\n";
    return 3;
  }
  auto row = [](const char* what, const FittedValue& v, const char* unit) {
    if (std::isnan(v.se)) {
      std::printf("  %-24s %10.4g %s\n", what, v.value, unit);
    } else {
      std::printf("  %-24s %10.4g ± %-9.2g %s\n", what, v.value, v.se, unit);
    }
  };
  row("stiffness k", fit.stiffness, "N/m^n");
  row("exponent n", fit.exponent, "");
  row("damping lambda", fit.damping, "s/m");
  row("lateral stiffness", fit.lateral_stiffness, "N/m");
  row("mu_static", fit.mu_static, "");
  row("mu_kinetic", fit.mu_kinetic, "");
  row("viscous b", fit.viscous, "N s/m");
  if (fit.patch_fitted) {
    row("patch stiffness factor", fit.patch_stiffness_factor, "");
    row("patch friction factor", fit.patch_friction_factor, "");
  }
  std::printf(
      "  surfaces moved %+.2f (thumb) / %+.2f (index) mm; depths %.1f..%.1f mm, depth rates "
      "%.3f..%.3f m/s (5-95 %%), speeds up to %.3f m/s (95 %%)\n"
      "  RMS residual: normal (eq. 2) %.3f N, tangential (eq. 1) %.3f N over %zu samples in "
      "contact; the skin slides in %.0f %% of them\n",
      fit.surface_offset_m[0].value * 1e3, fit.surface_offset_m[1].value * 1e3,
      fit.depth_min_m * 1e3, fit.depth_max_m * 1e3, fit.depth_rate_p5_m_s, fit.depth_rate_p95_m_s,
      fit.speed_p95_m_s, fit.normal_rms_n, fit.tangential_rms_n, fit.contact_samples,
      100.0 * fit.slip_fraction);
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
  std::vector<std::string> written;
  std::string error;
  const bool plotted =
      plotTissue(fit, server::estimate::tissuePlotData(fitter, fit), plots, name, r.plot_format,
                 "session " + std::to_string(r.session), written, error);
  for (const auto& w : written) std::cout << "plot: " << w << "\n";
  if (!plotted) {
    std::cerr << "telehand-records: " << error << "\n";
    return 3;
  }
  return 0;
}

int runSynthMassage(const SynthRequest& r) {
  server::estimate::SyntheticMassageOptions o;
  if (!r.cases_dir.empty()) {
    o.truth = loadPatientCaseByName(r.cases_dir, r.case_name).tissue;
  } else {
    o.truth = tissueCase(r.case_name.c_str());
  }
  o.noise_n = r.noise_n;
  o.seconds = r.massage_seconds;
  o.seed = r.seed;
  const auto cap = server::estimate::synthesizeMassage(o);
  const auto store = server::store::openStore(r.db);
  const uint64_t id = server::estimate::storeMassageCapture(*store, cap, r.case_name, "synthetic");
  std::cout << "session " << id << ": synthetic massage capture of the web of case '" << r.case_name
            << "', " << cap.samples.size() << " samples, thimble noise " << r.noise_n
            << " N per component (fit it with --technique massage)\n";
  return 0;
}

}  // namespace telehand::records
