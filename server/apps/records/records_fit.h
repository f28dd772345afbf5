#pragma once
// telehand-records fit / synth: fit a capture session into a patient-case file with a plot
// per axis, and store synthetic captures of known joints.
#include <cstdint>
#include <string>

namespace telehand::records {

struct FitRequest {
  std::string db;
  uint64_t session = 0;
  std::string output;     ///< case TOML to write; empty: <name>.toml in the current directory
  std::string name;       ///< case name; empty: capture-<session>
  std::string plots_dir;  ///< where the per-axis plots go; empty: next to the output
  std::string plot_format = "png";  ///< png or svg
  std::string cases_dir;  ///< where the session's case (joint frame, lever arm) is looked up
  bool quiet = false;
};

struct SynthRequest {
  std::string db;
  std::string case_name = "healthy";
  std::string cases_dir;
  std::string device_file;  ///< empty: the built-in MF-2 description
  double noise_n = 1.43;
  double seconds_per_axis = 10.0;
  double frequency_hz = 0.5;
  double max_force_n = 18.0;
  uint64_t seed = 1;
  bool quiet = false;
};

/// Exit codes as every telehand program: 0 done, 2 bad input, 3 the result is incomplete.
int runFit(const FitRequest& r);
int runSynth(const SynthRequest& r);

}  // namespace telehand::records
