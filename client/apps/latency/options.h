#pragma once
// telehand-latency's command line.
#include <optional>
#include <string>

#include "telehand/protocol/dds.h"

namespace telehand::latency {

struct Settings {
  double seconds = 10.0;
  double rate_hz = 1000.0;
  double warmup_s = 1.0;
  /// --compare-ddsperf: alternate telehand and ddsperf this many times, each for
  /// seconds / rounds (plus its own warm-up), so that both meet the same load over the run.
  int rounds = 1;
  std::string echo = "auto";
  /// How the probe's pong reader and a self echo take samples: "listener" (inside Cyclone's
  /// receive thread, as ddsperf does) or "waitset" (a thread woken by a waitset, as
  /// telehand-server's serve loop takes DeviceState).
  std::string take = "listener";
  bool echo_only = false;
  bool compare = false;
  bool quiet = false;
  std::string ddsperf = "ddsperf";
  std::string json_path;
  std::string dds_config;  // as given, for messages and the self echo's command line
  dds::Options dds;
  bool insecure = false;  // --insecure: no DDS Security (loopback tests)
};

/// Parses the command line into `s`; returns the exit code when the program is done (--help:
/// 0, bad input: 2) and sets `seconds_given` when --seconds was on it.
std::optional<int> parseOptions(int argc, char** argv, Settings& s, bool& seconds_given);

}  // namespace telehand::latency
