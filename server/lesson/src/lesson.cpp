#include "telehand/server/lesson/lesson.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include "telehand/config/toml_reader.h"
#include "telehand/core/error.h"
#include "telehand/core/parse.h"

namespace telehand::server::lesson {

namespace {

void put(std::string& out, const char* key, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%s=%.9g;", key, v);
  out += buf;
}

std::map<std::string, std::string> splitPairs(const std::string& text) {
  std::map<std::string, std::string> kv;
  std::size_t pos = 0;
  while (pos < text.size()) {
    const std::size_t end = std::min(text.find(';', pos), text.size());
    const std::string item = text.substr(pos, end - pos);
    const std::size_t eq = item.find('=');
    if (eq != std::string::npos) kv[item.substr(0, eq)] = item.substr(eq + 1);
    pos = end + 1;
  }
  return kv;
}

/// A targets text's value of `key` as a number in [lo, hi]; throws Error naming the key.
double targetNumber(const std::map<std::string, std::string>& kv, const std::string& key, double lo,
                    double hi) {
  const auto it = kv.find(key);
  double d = 0.0;
  if (it == kv.end()) throw Error("lesson targets: '" + key + "' is missing");
  if (!parseFiniteNumber(it->second, d) || d < lo || d > hi) {
    throw Error("lesson targets: '" + key + "' = '" + it->second + "' is not a number in [" +
                config::formatNumber(lo) + ", " + config::formatNumber(hi) + "]");
  }
  return d;
}

}  // namespace

std::string encodeTargets(const technique::Targets& t) {
  std::string out;
  put(out, "band_min_n", t.band_min_n);
  put(out, "band_max_n", t.band_max_n);
  put(out, "force_peak_n", t.force_peak_n);
  put(out, "force_trough_n", t.force_trough_n);
  put(out, "force_mean_n", t.force_mean_n);
  put(out, "frequency_hz", t.frequency_hz);
  put(out, "amplitude_deg", t.amplitude_deg);
  put(out, "jerk", t.jerk);
  for (int i = 0; i < 3; ++i) {
    put(out, ("rom_min_deg" + std::to_string(i)).c_str(), t.rom_min_deg[i]);
    put(out, ("rom_max_deg" + std::to_string(i)).c_str(), t.rom_max_deg[i]);
  }
  put(out, "path_period_s", t.path_period_s);
  // The demonstration's own figures: an attempt is scored against them (technique::score).
  put(out, "time_in_band", t.time_in_band);
  put(out, "path_error_deg", t.path_error_deg);
  out += "path=";
  char buf[64];
  for (std::size_t k = 0; k < t.path_rad.size(); ++k) {
    for (int i = 0; i < 3; ++i) {
      std::snprintf(buf, sizeof buf, "%s%.12g", (k == 0 && i == 0) ? "" : ",", t.path_rad[k][i]);
      out += buf;
    }
  }
  return out;
}

technique::Targets decodeTargets(const std::string& text) {
  const auto kv = splitPairs(text);
  auto num = [&](const std::string& key, double lo, double hi) {
    return targetNumber(kv, key, lo, hi);
  };
  technique::Targets t{};
  t.band_min_n = num("band_min_n", 0, 200);
  t.band_max_n = num("band_max_n", t.band_min_n, 200);
  t.force_peak_n = num("force_peak_n", 0, 200);
  t.force_trough_n = num("force_trough_n", 0, 200);
  t.force_mean_n = num("force_mean_n", 0, 200);
  t.frequency_hz = num("frequency_hz", 0.1, 10);
  t.amplitude_deg = num("amplitude_deg", 0, 360);
  t.jerk = num("jerk", -1e6, 1e6);
  for (int i = 0; i < 3; ++i) {
    t.rom_min_deg[i] = num("rom_min_deg" + std::to_string(i), -180, 180);
    t.rom_max_deg[i] = num("rom_max_deg" + std::to_string(i), -180, 180);
  }
  t.path_period_s = num("path_period_s", 0.1, 10);
  for (const char* key : {"time_in_band", "path_error_deg"}) {
    if (!kv.contains(key)) {
      // Scored without them, every attempt would get the time-in-band share whatever its force.
      throw Error(std::string("lesson targets: '") + key +
                  "' (the demonstration's own figure an attempt is scored against) is "
                  "missing; create the lesson again from its demonstration (telehand-records "
                  "lesson create --demo N)");
    }
  }
  t.time_in_band = num("time_in_band", 0, 1);
  t.path_error_deg = num("path_error_deg", 0, 360);
  const auto it = kv.find("path");
  if (it == kv.end()) throw Error("lesson targets: 'path' is missing");
  std::vector<double> v;
  std::size_t pos = 0;
  const std::string& s = it->second;
  while (pos <= s.size() && !s.empty()) {
    const std::size_t end = std::min(s.find(',', pos), s.size());
    double d = 0.0;
    if (!parseFiniteNumber(s.substr(pos, end - pos), d) || std::abs(d) > M_PI) {
      throw Error("lesson targets: path value " + std::to_string(v.size()) +
                  " is not an angle within ±pi");
    }
    v.push_back(d);
    pos = end + 1;
  }
  if (v.size() != 3 * static_cast<std::size_t>(GuideParams::kPoints)) {
    throw Error("lesson targets: the path has " + std::to_string(v.size()) + " values, not " +
                std::to_string(3 * GuideParams::kPoints));
  }
  t.path_rad.resize(GuideParams::kPoints);
  for (int k = 0; k < GuideParams::kPoints; ++k) {
    const auto u = static_cast<std::size_t>(k);
    t.path_rad[u] = Vec3(v[3 * u], v[3 * u + 1], v[3 * u + 2]);
  }
  return t;
}

std::string encodeMassageTargets(const technique::MassageTargets& t) {
  std::string out = "technique=massage;";
  put(out, "normal_mean_n", t.normal_mean_n);
  put(out, "normal_sd_n", t.normal_sd_n);
  put(out, "band_min_n", t.band_min_n);
  put(out, "band_max_n", t.band_max_n);
  put(out, "time_in_band", t.time_in_band);
  put(out, "tangential_ratio", t.tangential_ratio);
  put(out, "centre_x_m", t.centre_w.x());
  put(out, "centre_y_m", t.centre_w.y());
  put(out, "radius_m", t.radius_m);
  put(out, "frequency_hz", t.frequency_hz);
  put(out, "circularity", t.circularity);
  put(out, "radial_rms_m", t.radial_rms_m);
  put(out, "laps", t.laps);
  return out;
}

technique::MassageTargets decodeMassageTargets(const std::string& text) {
  const auto kv = splitPairs(text);
  const auto tech = kv.find("technique");
  if (tech == kv.end() || tech->second != "massage") {
    throw Error("lesson targets: not a massage's ('technique=massage' is missing)");
  }
  auto num = [&](const std::string& key, double lo, double hi) {
    return targetNumber(kv, key, lo, hi);
  };
  technique::MassageTargets t;
  t.normal_mean_n = num("normal_mean_n", 0, 200);
  t.normal_sd_n = num("normal_sd_n", 0, 200);
  t.band_min_n = num("band_min_n", 0, 200);
  t.band_max_n = num("band_max_n", t.band_min_n, 200);
  t.time_in_band = num("time_in_band", 0, 1);
  t.tangential_ratio = num("tangential_ratio", 0, 10);
  t.centre_w = Vec3(num("centre_x_m", -0.1, 0.1), num("centre_y_m", -0.1, 0.1), 0.0);
  // A demonstration draws a circle (deriving refuses one that does not).
  t.radius_m = num("radius_m", technique::kMinCircleRadiusM, 0.1);
  const double f = num("frequency_hz", -10, 10);
  if (std::abs(f) < 0.1) {
    throw Error("lesson targets: 'frequency_hz' = " + std::to_string(f) +
                " is not a circling of 0.1 to 10 laps per second");
  }
  t.frequency_hz = f;
  t.circularity = num("circularity", 0, 1);
  t.radial_rms_m = num("radial_rms_m", 0, 0.1);
  t.laps = num("laps", 1, 1e6);
  return t;
}

std::string encodeMassageScore(const technique::MassageScore& s) {
  std::string out;
  const technique::MassageFigures& f = s.figures;
  put(out, "overall", s.overall);
  put(out, "normal_error_n", s.normal_error_n);
  put(out, "spread_delta_n", s.spread_delta_n);
  put(out, "frequency_error_hz", s.frequency_error_hz);
  put(out, "radius_ratio", s.radius_ratio);
  put(out, "circularity_delta", s.circularity_delta);
  put(out, "tangential_ratio_error", s.tangential_ratio_error);
  put(out, "centre_offset_m", s.centre_offset_m);
  put(out, "normal_mean_n", f.normal_mean_n);
  put(out, "normal_sd_n", f.normal_sd_n);
  put(out, "time_in_band", f.time_in_band);
  put(out, "tangential_ratio", f.tangential_ratio);
  put(out, "radius_m", f.radius_m);
  put(out, "frequency_hz", f.frequency_hz);
  put(out, "circularity", f.circularity);
  put(out, "laps", f.laps);
  put(out, "duration_s", f.duration_s);
  put(out, "circling_share", f.circling_share);
  put(out, "contact_share", f.contact_share);
  return out;
}

std::string encodeScore(const technique::TrialScore& s) {
  std::string out;
  const technique::TrialFigures& f = s.figures;
  put(out, "overall", s.overall);
  put(out, "peak_error_n", s.peak_error_n);
  put(out, "mean_error_n", s.mean_error_n);
  put(out, "frequency_error_hz", s.frequency_error_hz);
  put(out, "amplitude_error_deg", s.amplitude_error_deg);
  put(out, "time_in_band", s.time_in_band);
  put(out, "path_error_deg", s.path_error_deg);
  put(out, "jerk_delta", s.jerk_delta);
  put(out, "oscillations", static_cast<double>(f.oscillations.size()));
  put(out, "force_peak_n", f.force_peak_n);
  put(out, "force_trough_n", f.force_trough_n);
  put(out, "force_mean_n", f.force_mean_n);
  put(out, "frequency_zc_hz", f.frequency_zc_hz);
  put(out, "frequency_spectrum_hz", f.frequency_spectrum_hz);
  put(out, "amplitude_deg", f.amplitude_deg);
  put(out, "jerk", f.jerk);
  put(out, "duration_s", f.duration_s);
  return out;
}

std::map<std::string, double> decodeFigures(const std::string& text) {
  std::map<std::string, double> out;
  for (const auto& [k, v] : splitPairs(text)) {
    double d = 0.0;
    if (parseFiniteNumber(v, d)) out[k] = d;
  }
  return out;
}

technique::Targets targetsFromRecord(store::SessionStore& store, uint64_t demo_session,
                                     double force_scale, double settle_s) {
  return targetsFromRecord(store, demo_session, 0, UINT64_MAX, force_scale, settle_s);
}

technique::Targets targetsFromRecord(store::SessionStore& store, uint64_t demo_session,
                                     uint64_t first_seq, uint64_t last_seq, double force_scale,
                                     double settle_s) {
  const auto info = store.session(demo_session);
  if (!info) throw Error("session " + std::to_string(demo_session) + " is not in the record");
  std::vector<Sample> samples;
  if (last_seq >= first_seq) {
    samples.reserve(
        static_cast<std::size_t>(std::min<uint64_t>(info->samples, last_seq - first_seq + 1)));
  }
  store.forEachSampleIn(demo_session, first_seq, last_seq, [&](const Sample& s, bool valid) {
    if (valid) samples.push_back(s);
  });
  if (samples.size() < 3000) {
    throw Error("session " + std::to_string(demo_session) + " has " +
                std::to_string(samples.size()) +
                " valid samples: a demonstration needs at least 3 s of record");
  }
  const technique::Series series = technique::seriesFromSamples(samples, force_scale);
  technique::Targets t = technique::deriveTargets(series, settle_s);
  if (!(t.frequency_hz >= 0.1 && t.frequency_hz <= 10.0) ||
      t.path_rad.size() != static_cast<std::size_t>(GuideParams::kPoints)) {
    throw Error("session " + std::to_string(demo_session) +
                " does not oscillate (no frequency between 0.1 and 10 Hz found): not a "
                "demonstration of a mobilization");
  }
  return t;
}

technique::MassageTargets massageTargetsFromRecord(store::SessionStore& store,
                                                   uint64_t demo_session, double force_scale,
                                                   const TissueParams& web, double settle_s) {
  const auto info = store.session(demo_session);
  if (!info) throw Error("session " + std::to_string(demo_session) + " is not in the record");
  std::vector<Sample> samples;
  samples.reserve(static_cast<std::size_t>(std::min<uint64_t>(info->samples, 600'000)));
  store.forEachSampleIn(demo_session, 0, UINT64_MAX, [&](const Sample& s, bool valid) {
    if (valid) samples.push_back(s);
  });
  if (samples.size() < 3000) {
    throw Error("session " + std::to_string(demo_session) + " has " +
                std::to_string(samples.size()) +
                " valid samples: a demonstration needs at least 3 s of record");
  }
  const technique::MassageSeries series = technique::massageSeriesFromSamples(samples, force_scale);
  const technique::MassageTargets t = technique::deriveMassageTargets(series, web, settle_s);
  if (!(t.laps >= 1.0) || !(t.radius_m >= technique::kMinCircleRadiusM) ||
      !(std::abs(t.frequency_hz) >= 0.1 && std::abs(t.frequency_hz) <= 10.0)) {
    throw Error("session " + std::to_string(demo_session) +
                " draws no whole circle of 0.1 to 10 laps per second on the web: not a "
                "demonstration of a massage");
  }
  return t;
}

std::string trialLabel(int index, const std::string& phase, double authority) {
  std::string label = "trial " + std::to_string(index) + " (" + phase;
  if (phase == "guided") label += " " + std::to_string(std::lround(100 * authority)) + " %";
  return label + ")";
}

GuideParams guideFor(const technique::Targets& t, double authority) {
  GuideParams g;
  g.authority = std::clamp(authority, 0.0, 1.0);
  g.period_s = t.path_period_s;
  for (int k = 0; k < GuideParams::kPoints && static_cast<std::size_t>(k) < t.path_rad.size(); ++k)
    g.path_rad[static_cast<std::size_t>(k)] = t.path_rad[static_cast<std::size_t>(k)];
  return g;
}

LessonPlan planOf(const store::LessonInfo& l, const technique::Targets& t, double demo_s) {
  LessonPlan p;
  p.lesson_id = l.id;
  p.schedule = l.schedule;
  p.guided = l.guided;
  p.attempts = l.attempts;
  p.trial_s = l.trial_s;
  p.assessment = l.assessment;
  p.takeover = l.takeover;
  p.demo_s = demo_s;
  p.band_min_n = t.band_min_n;
  p.band_max_n = t.band_max_n;
  p.frequency_hz = t.frequency_hz;
  return p;
}

GuideParams guideFor(const technique::MassageTargets& t, double authority) {
  GuideParams g;
  g.authority = std::clamp(authority, 0.0, 1.0);
  g.period_s = 1.0 / std::max(std::abs(t.frequency_hz), 0.1);
  const double turn = t.frequency_hz < 0.0 ? -1.0 : 1.0;
  for (int k = 0; k < GuideParams::kPoints; ++k) {
    const double a = turn * 2.0 * M_PI * k / GuideParams::kPoints;
    g.path_rad[static_cast<std::size_t>(k)] = Vec3(t.centre_w.x() + t.radius_m * std::cos(a),
                                                   t.centre_w.y() + t.radius_m * std::sin(a), 0.0);
  }
  return g;
}

LessonPlan planOf(const store::LessonInfo& l, const technique::MassageTargets& t, double demo_s) {
  LessonPlan p;
  p.lesson_id = l.id;
  p.technique = "massage";
  p.schedule = l.schedule;
  p.guided = l.guided;
  p.attempts = l.attempts;
  p.trial_s = l.trial_s;
  p.assessment = false;
  p.takeover = false;
  p.demo_s = demo_s;
  p.band_min_n = t.band_min_n;
  p.band_max_n = t.band_max_n;
  p.frequency_hz = std::abs(t.frequency_hz);
  return p;
}

}  // namespace telehand::server::lesson
