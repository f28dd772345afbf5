#pragma once
// telehand-client's command line and the config file it may name.
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "telehand/config/config.h"
#include "telehand/protocol/dds.h"

namespace telehand::client::app {

struct ClientOptions {
  std::string config_path, device_kind = "sim", mode_name = "mobilization", case_name = "healthy";
  std::string technique_name = "mobilization";
  std::string user = "student", log_level = "warn";
  std::string usb_vid = "1209", usb_pid = "4d32", usb_serial, device_file;
  double seconds = 20.0, connect_timeout = 10.0, device_timeout = 5.0;
  bool quiet = false, list_devices = false;
  dds::Options dds;
  bool insecure = false;  ///< --insecure: no DDS Security (loopback tests)
  ClientConfig cfg;
  std::string render = "model";
  double deadband = 0.0;
  bool no_pc = false;
  bool no_fault_stop = false;  ///< --no-fault-stop: the loop's fault detector is off
  uint64_t follow = 0;
  std::string stiffness = "cubic", patient_name = "healthy", cases_dir;
  double thimble_noise = 1.43, sweep_seconds = 10.0;
  // --lesson: run a stored lesson (docs/lessons.md).
  uint64_t lesson = 0;
  double explore_seconds = 30.0;  ///< each exploration phase (baseline, reassessment)
  double watch_speed = 1.0;       ///< the demonstration's replay speed
  std::vector<int> request_feedback{2, 4, 6, 8, 10};  ///< self schedule: trials asked about
  // Given on the command line: these win over the config file.
  bool frequency_given = false, band_min_given = false, band_max_given = false, seed_given = false,
       rt_given = false, skill_given = false;
};

/// Parses the command line into `o`; returns the exit code when the program is done (--help:
/// 0, bad input: 2).
std::optional<int> parseOptions(int argc, char** argv, ClientOptions& o);

/// Loads --config, if given, under what the command line set, and validates the operator.
void applyConfigFile(ClientOptions& o);

}  // namespace telehand::client::app
