#include "telehand/config/config.h"

#include <toml++/toml.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <utility>

#include "telehand/config/toml_reader.h"
#include "telehand/core/error.h"

namespace telehand {
namespace {

using config::fail;
using config::parseToml;
using config::rejectUnknownTables;
using TableReader = config::TomlTable;

std::string readFile(const std::string& path) { return config::readTextFile(path, "config file"); }

toml::table parse(const std::string& text, const std::string& origin) {
  return parseToml(text, origin);
}

void requireRange(const std::string& origin, const char* key, double v, double lo, double hi) {
  if (!(v >= lo && v <= hi)) {
    fail(origin, std::string("'") + key + "' = " + config::formatNumber(v) + " is outside [" +
                     config::formatNumber(lo) + ", " + config::formatNumber(hi) + "]");
  }
}

}  // namespace

void validate(const OperatorConfig& c, const std::string& origin) {
  requireRange(origin, "operator.frequency_hz", c.frequency_hz, 0.1, 10.0);
  requireRange(origin, "operator.band_min_n", c.band_min_n, 0.0, 40.0);
  requireRange(origin, "operator.band_max_n", c.band_max_n, c.band_min_n, 40.0);
  requireRange(origin, "operator.ramp_s", c.ramp_s, 0.0, 60.0);
  requireRange(origin, "operator.sensor_noise_n", c.sensor_noise_n, 0.0, 5.0);
  requireRange(origin, "operator.force_bias_n", c.force_bias_n, -20.0, 20.0);
  requireRange(origin, "operator.frequency_error_hz", c.frequency_error_hz, 0.1 - c.frequency_hz,
               10.0 - c.frequency_hz);
  requireRange(origin, "operator.tremor_n", c.tremor_n, 0.0, 10.0);
  requireRange(origin, "operator.amplitude_scale", c.amplitude_scale, 0.0, 5.0);
}

void validate(const SafetyLimits& c, const std::string& origin) {
  requireRange(origin, "safety.max_force_n", c.max_force_n, 0.0, 4.0);
  requireRange(origin, "safety.max_rate_n_per_s", c.max_rate_n_per_s, 1.0, 10000.0);
  requireRange(origin, "safety.watchdog_ms", static_cast<double>(c.watchdog_ns) / 1e6, 1.0, 1000.0);
}

ClientConfig parseClientConfig(const std::string& text, const std::string& origin) {
  const toml::table root = parse(text, origin);
  rejectUnknownTables(root, {"operator", "safety", "loop"}, origin);
  ClientConfig c;
  TableReader op(root, "operator", origin);
  op.read("frequency_hz", c.op.frequency_hz);
  op.read("band_min_n", c.op.band_min_n);
  op.read("band_max_n", c.op.band_max_n);
  op.read("ramp_s", c.op.ramp_s);
  op.read("sensor_noise_n", c.op.sensor_noise_n);
  op.read("seed", c.op.seed);
  op.read("force_bias_n", c.op.force_bias_n);
  op.read("frequency_error_hz", c.op.frequency_error_hz);
  op.read("tremor_n", c.op.tremor_n);
  op.read("amplitude_scale", c.op.amplitude_scale);
  op.rejectUnknown();
  TableReader sf(root, "safety", origin);
  sf.read("max_force_n", c.safety.max_force_n);
  sf.read("max_rate_n_per_s", c.safety.max_rate_n_per_s);
  double watchdog_ms = static_cast<double>(c.safety.watchdog_ns) / 1e6;
  sf.read("watchdog_ms", watchdog_ms);
  // Before the conversion: inf or 1e300 ms do not fit an int64 (undefined behaviour).
  requireRange(origin, "safety.watchdog_ms", watchdog_ms, 1.0, 1000.0);
  c.safety.watchdog_ns = static_cast<int64_t>(watchdog_ms * 1e6);
  sf.rejectUnknown();
  TableReader lp(root, "loop", origin);
  lp.read("rate_hz", c.loop.rate_hz);
  lp.read("rt_priority", c.loop.rt_priority);
  lp.rejectUnknown();
  validate(c.op, origin);
  validate(c.safety, origin);
  requireRange(origin, "loop.rate_hz", c.loop.rate_hz, LoopConfig::kMinRateHz,
               LoopConfig::kMaxRateHz);
  requireRange(origin, "loop.rt_priority", c.loop.rt_priority, 0, 99);
  return c;
}

ServerConfig parseServerConfig(const std::string& text, const std::string& origin) {
  const toml::table root = parse(text, origin);
  rejectUnknownTables(root, {"server"}, origin);
  ServerConfig c;
  TableReader sv(root, "server", origin);
  sv.read("db", c.db_path);
  sv.read("hand_state_hz", c.hand_state_hz);
  sv.read("close_grace_s", c.close_grace_s);
  sv.read("cases_dir", c.cases_dir);
  sv.read("hand_model", c.hand_model);
  sv.read("hand_deadband_weber", c.hand_deadband_weber);
  sv.read("drift_correction", c.drift_correction);
  sv.read("max_sessions", c.max_sessions);
  sv.read("max_sessions_per_participant", c.max_sessions_per_participant);
  sv.read("max_file_bytes", c.max_file_bytes);
  sv.read("max_files_per_session", c.max_files_per_session);
  sv.read("status_keep_s", c.status_keep_s);
  sv.read("resume_wait_s", c.resume_wait_s);
  sv.read("renew_when_idle", c.renew_when_idle);
  sv.rejectUnknown();
  validateServerConfig(c, origin);
  return c;
}

void validateServerConfig(const ServerConfig& c, const std::string& origin) {
  requireRange(origin, "server.hand_deadband_weber", c.hand_deadband_weber, 0.0, 0.5);
  if (c.db_path.empty()) fail(origin, "'server.db' must not be empty");
  requireRange(origin, "server.hand_state_hz", c.hand_state_hz, 1.0, 1000.0);
  requireRange(origin, "server.close_grace_s", c.close_grace_s, 0.0, 600.0);
  requireRange(origin, "server.max_sessions", c.max_sessions, 1, 4096);
  requireRange(origin, "server.max_sessions_per_participant", c.max_sessions_per_participant, 1,
               4096);
  requireRange(origin, "server.max_file_bytes", c.max_file_bytes, 0, kMaxFileBytesLimit);
  requireRange(origin, "server.max_files_per_session", c.max_files_per_session, 0, 1024);
  requireRange(origin, "server.status_keep_s", c.status_keep_s, 0.0, 86400.0);
  requireRange(origin, "server.resume_wait_s", c.resume_wait_s, 0.0, 7 * 86400.0);
}

ClientConfig loadClientConfig(const std::string& path) {
  return parseClientConfig(readFile(path), path);
}

ServerConfig loadServerConfig(const std::string& path) {
  return parseServerConfig(readFile(path), path);
}

namespace {

/// The [tissue] keys over `p`, each checked against the bounds a web on the wire must keep
/// (TissueParams, docs/security.md "Bounds").
void readTissue(TableReader& t, TissueParams& p, const std::string& origin) {
  using P = TissueParams;
  std::array<double, 3> origin_m = {p.origin_m.x(), p.origin_m.y(), p.origin_m.z()};
  t.readArray("origin_m", origin_m);
  for (std::size_t i = 0; i < 3; ++i) {
    requireRange(origin, ("tissue.origin_m[" + std::to_string(i) + "]").c_str(), origin_m[i], -1.0,
                 1.0);
  }
  p.origin_m = Vec3(origin_m[0], origin_m[1], origin_m[2]);
  std::array<double, 4> q = {p.orientation.w(), p.orientation.x(), p.orientation.y(),
                             p.orientation.z()};
  t.readArray("orientation", q);
  const double norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  if (!(std::abs(norm - 1.0) <= 1e-3)) {
    fail(origin, "'tissue.orientation' = [w, x, y, z] must be a unit quaternion (its norm is " +
                     std::to_string(norm) + ")");
  }
  p.orientation = Quat(q[0], q[1], q[2], q[3]);
  if (std::abs(norm - 1.0) > 1e-12) p.orientation.normalize();
  struct Key {
    const char* name;
    double* value;
    double lo, hi;
  };
  const Key keys[] = {
      {"thickness_m", &p.thickness_m, 0.0, P::kMaxLengthM},
      {"pad_radius_m", &p.pad_radius_m, 0.0, P::kMaxLengthM},
      {"half_extent_m", &p.half_extent_m, 0.001, P::kMaxLengthM},
      {"stiffness_n_per_m_pow", &p.stiffness_n_per_m_pow, 0.0, P::kMaxStiffness},
      {"exponent", &p.exponent, P::kMinExponent, P::kMaxExponent},
      {"damping_s_per_m", &p.damping_s_per_m, 0.0, P::kMaxDamping},
      {"lateral_stiffness_n_per_m", &p.lateral_stiffness_n_per_m, 0.0, P::kMaxLateral},
      {"mu_static", &p.mu_static, 0.0, P::kMaxMu},
      {"mu_kinetic", &p.mu_kinetic, 0.0, P::kMaxMu},
      {"viscous_n_s_per_m", &p.viscous_n_s_per_m, 0.0, P::kMaxViscous},
      {"patch_x_m", &p.patch_x_m, -P::kMaxLengthM, P::kMaxLengthM},
      {"patch_y_m", &p.patch_y_m, -P::kMaxLengthM, P::kMaxLengthM},
      {"patch_radius_m", &p.patch_radius_m, 0.0, P::kMaxLengthM},
      {"patch_stiffness_factor", &p.patch_stiffness_factor, 0.1, P::kMaxPatchFactor},
      {"patch_friction_factor", &p.patch_friction_factor, 0.1, P::kMaxPatchFactor},
      {"patch_rim_m", &p.patch_rim_m, 0.0, P::kMaxLengthM},
  };
  for (const Key& k : keys) {
    t.read(k.name, *k.value);
    requireRange(origin, (std::string("tissue.") + k.name).c_str(), *k.value, k.lo, k.hi);
  }
  t.rejectUnknown();
  if (p.mu_kinetic > p.mu_static) {
    fail(origin, "'tissue.mu_kinetic' = " + std::to_string(p.mu_kinetic) +
                     " is above 'tissue.mu_static' = " + std::to_string(p.mu_static) +
                     ": the skin cannot slip harder than it sticks");
  }
  if (p.patchChangesWeb() && p.patch_rim_m < TissueParams::kMinPatchRimM) {
    fail(origin, "'tissue.patch_rim_m' = " + std::to_string(p.patch_rim_m) +
                     " m: a patch that changes the web is blended over a rim of at least " +
                     std::to_string(TissueParams::kMinPatchRimM) +
                     " m (at a step nothing pushes the finger out of it, and the web returns "
                     "more energy than it took)");
  }
  if (const char* bad = invalidTissueParam(p))
    fail(origin, std::string("'tissue.") + bad + "' is not usable");
}

}  // namespace

PatientCase parsePatientCase(const std::string& text, const std::string& origin) {
  const toml::table root = parse(text, origin);
  rejectUnknownTables(root, {"case", "flexion", "abduction", "axial", "recovery", "tissue"},
                      origin);
  PatientCase pc;
  JointModelParams& m = pc.model;
  m = healthyIndexMcp();  // lever arm, scale, frame; everything a case sets is overwritten
  TableReader cs(root, "case", origin);
  if (!cs.present()) fail(origin, "missing table [case]");
  cs.read("name", pc.name);
  cs.read("description", pc.description);
  cs.read("source", pc.source);
  cs.read("damping_nms_per_rad", m.damping_nms_per_rad);
  cs.read("speed_gain_s_per_rad", m.speed_gain_s_per_rad);
  cs.rejectUnknown();
  if (pc.name.empty()) fail(origin, "'case.name' must be set");
  requireRange(origin, "case.damping_nms_per_rad", m.damping_nms_per_rad, 0.0, 0.5);
  requireRange(origin, "case.speed_gain_s_per_rad", m.speed_gain_s_per_rad, 0.0, 20.0);
  for (int i = 0; i < kAxes; ++i) {
    const auto ax = static_cast<std::size_t>(i);
    const std::string name(kAxisNames[ax]);
    TableReader t(root, name, origin);
    if (!t.present()) fail(origin, "missing table [" + name + "]");
    CubicCurve& curve = m.axes[ax];
    t.readArray("coeffs", curve.coeffs);
    t.read("min_deg", curve.min_deg);
    t.read("max_deg", curve.max_deg);
    t.read("neutral_zone_deg", m.neutral_zone_deg[ax]);
    t.rejectUnknown();
    requireRange(origin, (name + ".min_deg").c_str(), curve.min_deg, kRangeMinDegBounds.lo,
                 kRangeMinDegBounds.hi);
    requireRange(origin, (name + ".max_deg").c_str(), curve.max_deg, kRangeMaxDegBounds.lo,
                 kRangeMaxDegBounds.hi);
    if (!(curve.min_deg < curve.max_deg)) fail(origin, "'" + name + "' range is empty");
    requireRange(origin, (name + ".neutral_zone_deg").c_str(), m.neutral_zone_deg[ax], 0.0, 30.0);
    // A joint must resist being moved, with a force a joint can have: the same check a
    // JointModel from the network passes.
    if (const auto why = passiveCurveProblem(curve)) fail(origin, "'" + name + ".coeffs' " + *why);
  }
  TableReader rec(root, "recovery", origin);
  if (rec.present()) {
    pc.recovers = true;
    rec.readArray("final_min_deg", pc.final_min_deg);
    rec.readArray("final_max_deg", pc.final_max_deg);
    rec.read("treatment_s", pc.recovery_treatment_s);
    rec.rejectUnknown();
    requireRange(origin, "recovery.treatment_s", pc.recovery_treatment_s, 1.0, 36000.0);
    for (std::size_t i = 0; i < kAxes; ++i) {
      // The model at any time lies between the starting and the final ranges.
      const std::string axis(kAxisNames[i]);
      requireRange(origin, ("recovery.final_min_deg (" + axis + ")").c_str(), pc.final_min_deg[i],
                   kRangeMinDegBounds.lo, kRangeMinDegBounds.hi);
      requireRange(origin, ("recovery.final_max_deg (" + axis + ")").c_str(), pc.final_max_deg[i],
                   kRangeMaxDegBounds.lo, kRangeMaxDegBounds.hi);
      if (pc.final_min_deg[i] > m.axes[i].min_deg || pc.final_max_deg[i] < m.axes[i].max_deg) {
        fail(origin, "'recovery' ranges must contain the starting ranges (" +
                         std::string(kAxisNames[i]) + ")");
      }
      // The curve is published over every range between the starting and the final one: it
      // must be a joint's over the widest (and then over every one inside it).
      CubicCurve recovered = m.axes[i];
      recovered.min_deg = pc.final_min_deg[i];
      recovered.max_deg = pc.final_max_deg[i];
      if (const auto why = passiveCurveProblem(recovered)) {
        fail(origin, "'" + axis + ".coeffs' over the recovery's final range " + *why);
      }
    }
  }
  pc.tissue = tissueCase(pc.name.c_str());
  TableReader ts(root, "tissue", origin);
  if (ts.present()) {
    pc.tissue_given = true;
    readTissue(ts, pc.tissue, origin);
  }
  std::memset(m.case_name.data(), 0, m.case_name.size());
  std::memcpy(m.case_name.data(), pc.name.data(), std::min(pc.name.size(), m.case_name.size() - 1));
  return pc;
}

PatientCase loadPatientCase(const std::string& path) {
  return parsePatientCase(readFile(path), path);
}

JointModelParams PatientCase::at(double treatment_s) const {
  JointModelParams p = model;
  if (!recovers) return p;
  const double w = std::clamp(treatment_s / recovery_treatment_s, 0.0, 1.0);
  for (std::size_t i = 0; i < kAxes; ++i) {
    p.axes[i].min_deg = model.axes[i].min_deg + w * (final_min_deg[i] - model.axes[i].min_deg);
    p.axes[i].max_deg = model.axes[i].max_deg + w * (final_max_deg[i] - model.axes[i].max_deg);
  }
  return p;
}

std::vector<std::string> listPatientCases(const std::string& dir) {
  std::vector<std::string> out;
  std::error_code ec;
  for (const auto& e : std::filesystem::directory_iterator(dir, ec)) {
    if (e.path().extension() == ".toml") out.push_back(e.path().stem().string());
  }
  std::sort(out.begin(), out.end());
  return out;
}

PatientCase loadPatientCaseByName(const std::string& dir, const std::string& name) {
  const bool well_formed =
      !name.empty() && name.size() <= 63 && std::all_of(name.begin(), name.end(), [](char ch) {
        return (ch >= 'a' && ch <= 'z') || (ch >= '0' && ch <= '9') || ch == '_' || ch == '-';
      });
  if (!well_formed) {
    throw ConfigError("patient case name '" + name + "' is not of the form [a-z0-9_-]+");
  }
  const std::string path = (std::filesystem::path(dir) / (name + ".toml")).string();
  if (!std::filesystem::exists(path)) {
    std::string known;
    for (const auto& n : listPatientCases(dir)) known += (known.empty() ? "" : ", ") + n;
    throw ConfigError("unknown patient case '" + name +
                      "' (known: " + (known.empty() ? "none" : known) + ")");
  }
  PatientCase pc = loadPatientCase(path);
  if (pc.name != name)
    throw ConfigError(path + ": 'case.name' is '" + pc.name + "', the file name says '" + name +
                      "'");
  return pc;
}

}  // namespace telehand
