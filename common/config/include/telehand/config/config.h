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

namespace telehand {

/// The simulated clinician/student who moves the simulated MF-2 (client/device).
struct OperatorConfig {
  double frequency_hz = 3.0;  ///< mobilization oscillation, 1-6 Hz (docs/facts.md)
  double band_min_n = 12.0;   ///< target force band, reference scale (paper: 12-16 N)
  double band_max_n = 16.0;
  double ramp_s = 1.5;           ///< time to build up to the band
  double sensor_noise_n = 0.02;  ///< FSR noise, 1 sigma
  uint64_t seed = 1;
};

struct LoopConfig {
  double rate_hz = 1000.0;
  int rt_priority = 0;  ///< SCHED_FIFO priority; 0 = normal scheduling
};

struct ClientConfig {
  OperatorConfig op;
  SafetyLimits safety;
  LoopConfig loop;
};

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
};

/// Load from TOML text; `origin` names the source in error messages.
ClientConfig parseClientConfig(const std::string& text, const std::string& origin);
ServerConfig parseServerConfig(const std::string& text, const std::string& origin);
/// Load from a file; a missing or unreadable file is a ConfigError naming it.
ClientConfig loadClientConfig(const std::string& path);
ServerConfig loadServerConfig(const std::string& path);

/// A patient: the joint model a session starts with, and how it changes with treatment.
/// Files under deploy/cases/ (README "Patient cases").
struct PatientCase {
  std::string name;
  std::string description;
  std::string source;      ///< where the numbers come from
  JointModelParams model;  ///< at the start of a session
  bool recovers = false;   ///< the range grows with treatment time
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

/// Range checks shared by the file loaders and the command-line options.
void validate(const OperatorConfig& c, const std::string& origin);
void validate(const SafetyLimits& c, const std::string& origin);

}  // namespace telehand
