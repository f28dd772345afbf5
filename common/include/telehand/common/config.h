#pragma once
/// Configuration files (TOML). Every program reads the tables it knows; an unknown table or
/// key, a wrong type or an out-of-range value is a ConfigError naming the file, the key and
/// the value.
#include <cstdint>
#include <string>

#include "telehand/common/safety.h"

namespace telehand {

/// The simulated clinician/student who moves the simulated MF-2 (client/device).
struct OperatorConfig {
  double frequency_hz = 3.0;    ///< mobilization oscillation, 1-6 Hz (FACTS.md)
  double band_min_n = 12.0;     ///< target force band, reference scale (paper: 12-16 N)
  double band_max_n = 16.0;
  double ramp_s = 1.5;          ///< time to build up to the band
  double sensor_noise_n = 0.02; ///< FSR noise, 1 sigma
  uint64_t seed = 1;
};

struct LoopConfig {
  double rate_hz = 1000.0;
  int rt_priority = 0;          ///< SCHED_FIFO priority; 0 = normal scheduling
};

struct ClientConfig {
  OperatorConfig op;
  SafetyLimits safety;
  LoopConfig loop;
};

struct ServerConfig {
  std::string db_path = "records/telehand.db";
  double hand_state_hz = 100.0;  ///< decimated HandState, 60-100 Hz (DESIGN.md)
  double close_grace_s = 5.0;    ///< how long a closing session waits for in-flight records
};

/// Load from TOML text; `origin` names the source in error messages.
ClientConfig parseClientConfig(const std::string& text, const std::string& origin);
ServerConfig parseServerConfig(const std::string& text, const std::string& origin);
/// Load from a file; a missing or unreadable file is a ConfigError naming it.
ClientConfig loadClientConfig(const std::string& path);
ServerConfig loadServerConfig(const std::string& path);

/// Range checks shared by the file loaders and the command-line options.
void validate(const OperatorConfig& c, const std::string& origin);
void validate(const SafetyLimits& c, const std::string& origin);

}  // namespace telehand
