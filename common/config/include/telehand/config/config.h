#pragma once
/// Configuration files (TOML). Every program reads the tables it knows; an unknown table or
/// key, a wrong type or an out-of-range value is a ConfigError naming the file, the key and
/// the value.
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "telehand/core/joint_model.h"
#include "telehand/core/safety.h"
#include "telehand/core/tissue_model.h"

namespace telehand {

/// The simulated clinician/student who moves the simulated MF-2 (client/device).
struct OperatorConfig {
  double frequency_hz = 3.0;  ///< mobilization oscillation, 1-6 Hz (docs/facts.md)
  double band_min_n = 12.0;   ///< target force band, reference scale (paper: 12-16 N)
  double band_max_n = 16.0;
  double ramp_s = 1.5;           ///< time to build up to the band
  double sensor_noise_n = 0.02;  ///< FSR noise, 1 sigma
  uint64_t seed = 1;
  /// Skill: how far the operator is from the clinician who performs the mobilization exactly
  /// (all 0 and amplitude_scale 1). A simulated student for lessons and their scoring.
  double force_bias_n = 0.0;        ///< added to the target force (reference scale)
  double frequency_error_hz = 0.0;  ///< added to frequency_hz
  /// Physiological tremor: a random force band-limited to 8-12 Hz (seeded from `seed`), its
  /// RMS in newtons at reference scale; 0 = none.
  double tremor_n = 0.0;
  double amplitude_scale = 1.0;  ///< the oscillation's amplitude, 1 = across the band
};

struct LoopConfig {
  /// The rates a configuration may ask for. The end-of-range wall (1.4 N/mm at the device)
  /// is passive only while K·T/2 < b (Colgate): with the grip's b = 1 N·s/m the tick must be
  /// under 1.43 ms, 700 Hz. On the simulated MF-2 every shipped case and 60 random ones
  /// stayed stable from 600 Hz to 4 kHz; exploration failed on random ones at 550 Hz and
  /// below (not passive; from 500 Hz down some ran away), telehand_bench_stability
  /// --loop-rate, docs/facts.md "Loop rate".
  static constexpr double kMinRateHz = 800.0;
  static constexpr double kMaxRateHz = 4000.0;
  double rate_hz = 1000.0;
  int rt_priority = 0;  ///< SCHED_FIFO priority; 0 = normal scheduling
};

struct ClientConfig {
  OperatorConfig op;
  SafetyLimits safety;
  LoopConfig loop;
};

/// The most server.max_file_bytes may be. The network configs (deploy/cyclonedds) let no DDS
/// sample larger than this and its header through (MaxSampleSize).
inline constexpr int kMaxFileBytesLimit = 64 * 1024 * 1024;

struct ServerConfig {
  std::string db_path = "records/telehand.db";
  double hand_state_hz = 100.0;  ///< decimated HandState, 60-100 Hz (docs/design.md)
  double close_grace_s = 5.0;    ///< how long a closing session waits for in-flight records
  std::string cases_dir;         ///< patient cases (*.toml); empty = the built-in healthy case only
  std::string hand_model;  ///< URDF of the hand; empty = HandState from the shared joint model
  double hand_deadband_weber = 0.0;  ///< HandState deadband (Weber fraction); 0 = every state
  /// Fold persistent drift between the server's hand and the client's proxy into the model
  /// (server/session/drift.h). Off only to measure what it does.
  bool drift_correction = true;
  /// Bounds on what participants can make the server hold (docs/security.md "Bounds"):
  /// sessions open at once, in all and per participant; the largest SessionFile kept (a
  /// capture's device and calibration files are a few kB) and how many per session.
  int max_sessions = 64;
  int max_sessions_per_participant = 4;
  int max_file_bytes = 256 * 1024;  ///< at most kMaxFileBytesLimit
  int max_files_per_session = 8;
  /// How long an ended session's status stays published for late joiners, seconds.
  double status_keep_s = 60.0;
  /// A session found open in the record when the server starts, or suspended by a server
  /// that stopped, waits this long for its client to resume it (docs/recovery.md), then is
  /// closed as interrupted with what the record holds, seconds.
  double resume_wait_s = 120.0;
  /// Once the last session has ended and been retired, the server makes its DDS participant
  /// again, which gives back what Cyclone's domain grew to while serving (docs/security.md
  /// "Memory"); a client asking for a session meanwhile is answered a moment later (clients
  /// ask again every second). Without it a server keeps a quarter more memory after a churn
  /// of 9,000 sessions than before it; false only to measure that, or for a client that
  /// sends its OPEN once (a participant only just made missed some of a flood's).
  bool renew_when_idle = true;
};

/// The ranges server config keys and their command-line flags must lie in (one table for
/// both): throws ConfigError naming `what` (the key or the flag) and the range.
void validateServerConfig(const ServerConfig& c, const std::string& origin);

/// Load from TOML text; `origin` names the source in error messages.
ClientConfig parseClientConfig(const std::string& text, const std::string& origin);
ServerConfig parseServerConfig(const std::string& text, const std::string& origin);
/// Load from a file; a missing or unreadable file is a ConfigError naming it.
ClientConfig loadClientConfig(const std::string& path);
ServerConfig loadServerConfig(const std::string& path);

/// A patient: the joint model a session starts with, and how it changes with treatment;
/// the web between thumb and index for the massage. Files under deploy/cases/ (README
/// "Patient cases").
struct PatientCase {
  std::string name;
  std::string description;
  std::string source;      ///< where the numbers come from
  JointModelParams model;  ///< at the start of a session
  /// The web ([tissue], keys named after TissueParams' fields): the keys given over
  /// tissueCase(name), which is the healthy web for a name it does not know; all of it
  /// when the file has no [tissue] (tissue_given false).
  TissueParams tissue;
  bool tissue_given = false;
  bool recovers = false;  ///< the range grows with treatment time
  std::array<double, kAxes> final_min_deg{};
  std::array<double, kAxes> final_max_deg{};
  double recovery_treatment_s = 0.0;
  /// The joint after this much treatment (ranges interpolated; unchanged if it does not recover).
  JointModelParams at(double treatment_s) const;
};
PatientCase parsePatientCase(const std::string& text, const std::string& origin);
PatientCase loadPatientCase(const std::string& path);
/// `dir`/`name`.toml; ConfigError listing the known cases when there is none by that name.
PatientCase loadPatientCaseByName(const std::string& dir, const std::string& name);
std::vector<std::string> listPatientCases(const std::string& dir);

/// The ranges randomPatientCase draws from (docs/facts.md "Random patient cases").
struct RandomCaseRanges {
  double flexion_max_deg[2] = {85.0, 100.0};   ///< MCP flexion 0-90 deg, to about 100
  double flexion_min_deg[2] = {-60.0, -15.0};  ///< hyperextension up to 45 deg, more when lax
  double abduction_deg[2] = {15.0, 25.0};      ///< each side
  double axial_min_deg[2] = {-12.0, -6.0};     ///< pronation (assumption)
  double axial_max_deg[2] = {10.0, 18.0};      ///< supination (assumption)
  double stiffness_scale[2] = {0.7, 3.0};      ///< times eqs. 3-5, drawn log-uniform
  double flexion_shift_deg[2] = {0.0, 20.0};   ///< rest angle moved toward flexion
  std::array<double, kAxes> neutral_zone_max_deg = {10.0, 5.0, 4.0};  ///< the lax case's
  double damping_nms_per_rad[2] = {0.001, 0.01};  ///< the shipped cases', log-uniform
  double spasm_probability = 1.0 / 3.0;
  double speed_gain_s_per_rad[2] = {0.5, 3.0};
};

/// A patient drawn at random within published ranges: the paper's eqs. 3-5 scaled (and the
/// flexion curve shifted toward flexion), ranges of motion, neutral zones, damping and (for
/// some) a protective spasm. The holding curves always rise across their ranges (the same
/// check the case files pass). The same seed gives the same case; named "random-<seed>".
PatientCase randomPatientCase(uint64_t seed, const RandomCaseRanges& ranges = {});

/// Range checks shared by the file loaders and the command-line options.
void validate(const OperatorConfig& c, const std::string& origin);
void validate(const SafetyLimits& c, const std::string& origin);

}  // namespace telehand
