#include "options.h"

#include "telehand/app/cli.h"
#include "telehand/app/dds_cli.h"

namespace telehand::client::app {

std::optional<int> parseOptions(int argc, char** argv, ClientOptions& o) {
  CLI::App app{
      "telehand-client: run a session from the device PC. The simulated MF-2 is held "
      "by a virtual clinician performing the paper's MCP mobilization."};
  app.add_option("-c,--config", o.config_path, "TOML file with [operator], [safety], [loop] tables")
      ->check(CLI::ExistingFile);
  app.add_option("--device", o.device_kind, "sim: the simulated MF-2; usb: an MF-2 on USB")
      ->check(CLI::IsMember({"sim", "usb"}))
      ->capture_default_str();
  app.add_flag("--list-devices", o.list_devices, "list the MF-2s attached over USB and exit");
  app.add_option("--device-file", o.device_file,
                 "MF-2 device file: kinematics, encoders, thimble calibration (default: the "
                 "built-in values of deploy/devices/mf2.toml)")
      ->check(CLI::ExistingFile);
  app.add_option("--usb-vid", o.usb_vid, "MF-2 USB vendor ID, hex")->capture_default_str();
  app.add_option("--usb-pid", o.usb_pid, "MF-2 USB product ID, hex")->capture_default_str();
  app.add_option("--usb-serial", o.usb_serial, "use the MF-2 with this serial number");
  app.add_option("--device-timeout", o.device_timeout, "seconds to wait for the USB MF-2 to stream")
      ->capture_default_str()
      ->check(CLI::Range(0.1, 3600.0));
  auto* seconds = app.add_option("--seconds", o.seconds,
                                 "session length (Ctrl-C ends it early); capture mode with the "
                                 "simulated MF-2: 3 × --sweep-seconds + 2, every axis swept")
                      ->capture_default_str()
                      ->check(CLI::PositiveNumber);
  app.add_option("--mode", o.mode_name, "session mode")
      ->check(CLI::IsMember({"mobilization", "exploration", "capture"}))
      ->capture_default_str();
  app.add_option("--technique", o.technique_name,
                 "what is treated: the index MCP (mobilization) or the thumb-index web (massage: "
                 "a circular massage at 10 ± 2 N; with --mode capture, a capture of the web)")
      ->check(CLI::IsMember({"mobilization", "massage"}))
      ->capture_default_str();
  app.add_option("--case", o.case_name, "patient case on the server")->capture_default_str();
  app.add_option("--user", o.user, "who is at the device")->capture_default_str();
  auto* freq = app.add_option("--frequency", o.cfg.op.frequency_hz,
                              "simulated mobilization frequency, Hz (0.1-10; the paper's 1-6)");
  auto* bmin =
      app.add_option("--band-min", o.cfg.op.band_min_n, "force band low end, N at reference scale");
  auto* bmax = app.add_option("--band-max", o.cfg.op.band_max_n,
                              "force band high end, N at reference scale");
  auto* seed = app.add_option("--seed", o.cfg.op.seed, "simulated operator seed");
  // The simulated operator's skill (a student for lessons; all 0: the clinician).
  auto* bias = app.add_option("--force-bias", o.cfg.op.force_bias_n,
                              "simulated operator: pushes this much harder (N at reference scale)");
  auto* ferr = app.add_option("--frequency-error", o.cfg.op.frequency_error_hz,
                              "simulated operator: oscillates this much faster (Hz)");
  auto* tremor = app.add_option("--tremor", o.cfg.op.tremor_n,
                                "simulated operator: 8-12 Hz tremor, N RMS at reference scale")
                     ->check(CLI::Range(0.0, 10.0));
  telehand::app::addDdsOptions(app, o.dds, o.insecure, "device");
  app.add_option("--connect-timeout", o.connect_timeout, "seconds to wait for the server")
      ->check(CLI::Range(0.1, 3600.0))
      ->capture_default_str();
  app.add_flag("-q,--quiet", o.quiet, "no progress line");
  auto* rt =
      app.add_option("--rt-priority", o.cfg.loop.rt_priority,
                     "run the 1 kHz loop at this SCHED_FIFO priority (1-99; needs CAP_SYS_NICE)")
          ->check(CLI::Range(1, 99));
  app.add_option("--render", o.render,
                 "model: render from the local joint model (model-mediated); direct: render the "
                 "force the server computes (the baseline design)")
      ->check(CLI::IsMember({"model", "direct"}))
      ->capture_default_str();
  app.add_option("--deadband", o.deadband,
                 "perceptual deadband on the live DeviceState stream, Weber fraction (e.g. 0.05; 0 "
                 "= every sample)")
      ->check(CLI::Range(0.0, 0.5))
      ->capture_default_str();
  app.add_flag("--no-passivity-control", o.no_pc, "passivity observer only, no added damping");
  app.add_flag("--no-fault-stop", o.no_fault_stop,
               "keep rendering after a rendering fault (clamp storm, range runaway) instead of "
               "ending the session: for bench tests of the device link with no finger in the "
               "thimbles; the safety gate still bounds every force");
  app.add_option("--log-level", o.log_level, "trace, debug, info, warn, error, off")
      ->capture_default_str();
  o.cases_dir = TELEHAND_DEPLOY_DIR "/cases";
  app.add_option("--follow", o.follow,
                 "feel the live fit of this capture session (e.g. an expert's, elsewhere)");
  app.add_option(
         "--stiffness", o.stiffness,
         "with --follow: render the fitted cubics or the captured samples (k nearest neighbours)")
      ->check(CLI::IsMember({"cubic", "knn"}))
      ->capture_default_str();
  app.add_option("--patient", o.patient_name,
                 "capture mode, simulated MF-2: the real finger in the grip (a patient case)")
      ->capture_default_str();
  app.add_option("--cases", o.cases_dir, "patient cases directory (for --patient)")
      ->capture_default_str();
  app.add_option("--thimble-noise", o.thimble_noise,
                 "capture mode, simulated MF-2: thimble error per axis, N RMS (paper: 1.43)")
      ->check(CLI::Range(0.0, 10.0))
      ->capture_default_str();
  app.add_option("--sweep-seconds", o.sweep_seconds,
                 "capture mode, simulated MF-2: seconds the clinician mobilizes each axis")
      ->check(CLI::Range(1.0, 600.0))
      ->capture_default_str();
  app.add_option("--lesson", o.lesson,
                 "run this stored lesson (see telehand-records lesson list): baseline, watch the "
                 "demonstration, guided trials, attempts, reassessment; --mode and --seconds do "
                 "not apply");
  app.add_option("--explore-seconds", o.explore_seconds,
                 "lesson: length of each exploration phase (6 directions take 30 s)")
      ->check(CLI::Range(2.0, 300.0))
      ->capture_default_str();
  app.add_option("--watch-speed", o.watch_speed, "lesson: replay speed of the demonstration")
      ->check(CLI::Range(0.25, 2.0))
      ->capture_default_str();
  app.add_option("--request-feedback", o.request_feedback,
                 "lesson with the self-requested schedule: the trials (1-based) after which the "
                 "student asks for feedback")
      ->delimiter(',')
      ->capture_default_str();
  TELEHAND_CLI_PARSE(app, argc, argv)
  o.frequency_given = static_cast<bool>(*freq);
  o.band_min_given = static_cast<bool>(*bmin);
  o.band_max_given = static_cast<bool>(*bmax);
  o.seed_given = static_cast<bool>(*seed);
  o.skill_given =
      static_cast<bool>(*bias) || static_cast<bool>(*ferr) || static_cast<bool>(*tremor);
  o.rt_given = static_cast<bool>(*rt);
  // A capture is fitted only when every axis was swept: by default it lasts the three
  // sweeps and a little for the session to open.
  if (o.mode_name == "capture" && !*seconds) o.seconds = 3.0 * o.sweep_seconds + 2.0;
  return std::nullopt;
}

void applyConfigFile(ClientOptions& o) {
  ClientConfig& cfg = o.cfg;
  if (!o.config_path.empty()) {
    const ClientConfig file = loadClientConfig(o.config_path);
    const OperatorConfig cli_op = cfg.op;
    const int rt_cli = cfg.loop.rt_priority;
    cfg = file;
    if (o.frequency_given) cfg.op.frequency_hz = cli_op.frequency_hz;
    if (o.band_min_given) cfg.op.band_min_n = cli_op.band_min_n;
    if (o.band_max_given) cfg.op.band_max_n = cli_op.band_max_n;
    if (o.seed_given) cfg.op.seed = cli_op.seed;
    if (o.skill_given) {
      cfg.op.force_bias_n = cli_op.force_bias_n;
      cfg.op.frequency_error_hz = cli_op.frequency_error_hz;
      cfg.op.tremor_n = cli_op.tremor_n;
    }
    if (o.rt_given) cfg.loop.rt_priority = rt_cli;
  }
  validate(cfg.op, "command line");
  // Listing the USB devices joins no DDS domain.
  if (!o.list_devices) {
    telehand::app::resolveDdsSecurity(o.dds, o.insecure, "device", "telehand-client");
  }
}

}  // namespace telehand::client::app
