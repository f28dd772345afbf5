#pragma once
// telehand-records fit / synth: fit a capture session into a patient-case file with a plot
// per axis (per tissue parameter for a massage), and store synthetic captures of known
// joints and webs.
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <functional>
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
  /// What the capture is of: "mobilization" (a joint, the default) or "massage" (the web;
  /// the record does not say which).
  std::string technique = "mobilization";
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
  std::string technique = "mobilization";  ///< or "massage": the web of the case
  double massage_seconds = 60.0;           ///< length of a massage capture
  bool quiet = false;
};

/// Exit codes as every telehand program: 0 done, 2 bad input, 3 the result is incomplete.
int runFit(const FitRequest& r);
int runSynth(const SynthRequest& r);

/// gnuplot into `out` (png or svg, 900×800): `script` writes the data blocks and commands
/// after the terminal. false with `error` set when gnuplot is missing or fails.
bool runGnuplot(const std::filesystem::path& out, const std::string& format, std::string& error,
                const std::function<void(FILE*)>& script);

}  // namespace telehand::records
