// telehand-client: the device PC side. Runs the 1 kHz haptic loop on an MF-2 (simulated by
// default, or over USB), opens a session on the server, streams every sample and renders
// the joint model the server publishes.
#include "telehand/app/cli.h"
#include <algorithm>
#include <cstring>
#include <atomic>
#include <chrono>
#include <thread>
#include <csignal>
#include <cstdio>
#include <iostream>
#include <memory>
#include <optional>
#include <unistd.h>

#include "telehand/devices/simulated_mf2.h"
#include "telehand/devices/sweep_operator.h"
#include "telehand/client/usb/usb_mf2.h"
#include "telehand/config/config.h"
#include "telehand/devices/mf2_device.h"
#include "telehand/client/link/client_link.h"
#include "telehand/core/log.h"
#include "telehand/protocol/wire.h"

int main(int argc, char** argv) {
  using namespace telehand;
  using namespace std::chrono_literals;
  CLI::App app{"telehand-client: run a session from the device PC. The simulated MF-2 is held "
               "by a virtual clinician performing the paper's MCP mobilization."};
  std::string config_path, device_kind = "sim", mode_name = "mobilization", case_name = "healthy";
  std::string user = "student", log_level = "warn";
  std::string usb_vid = "1209", usb_pid = "4d32", usb_serial, device_file;
  double seconds = 20.0, connect_timeout = 10.0, device_timeout = 5.0;
  bool quiet = false, list_devices = false;
  dds::Options dds_opts;
  ClientConfig cfg;
  app.add_option("-c,--config", config_path, "TOML file with [operator], [safety], [loop] tables")
      ->check(CLI::ExistingFile);
  app.add_option("--device", device_kind, "sim: the simulated MF-2; usb: an MF-2 on USB")
      ->check(CLI::IsMember({"sim", "usb"}))->capture_default_str();
  app.add_flag("--list-devices", list_devices, "list the MF-2s attached over USB and exit");
  app.add_option("--device-file", device_file,
                 "MF-2 device file: kinematics, encoders, thimble calibration (default: the "
                 "built-in values of deploy/devices/mf2.toml)")
      ->check(CLI::ExistingFile);
  app.add_option("--usb-vid", usb_vid, "MF-2 USB vendor ID, hex")->capture_default_str();
  app.add_option("--usb-pid", usb_pid, "MF-2 USB product ID, hex")->capture_default_str();
  app.add_option("--usb-serial", usb_serial, "use the MF-2 with this serial number");
  app.add_option("--device-timeout", device_timeout, "seconds to wait for the USB MF-2 to stream")
      ->capture_default_str()->check(CLI::PositiveNumber);
  app.add_option("--seconds", seconds, "session length (Ctrl-C ends it early)")->capture_default_str()->check(CLI::PositiveNumber);
  app.add_option("--mode", mode_name, "session mode")->check(CLI::IsMember({"mobilization", "exploration", "capture"}))->capture_default_str();
  app.add_option("--case", case_name, "patient case on the server")->capture_default_str();
  app.add_option("--user", user, "who is at the device")->capture_default_str();
  auto* freq = app.add_option("--frequency", cfg.op.frequency_hz, "simulated mobilization frequency, Hz (1-6)");
  auto* bmin = app.add_option("--band-min", cfg.op.band_min_n, "force band low end, N at reference scale");
  auto* bmax = app.add_option("--band-max", cfg.op.band_max_n, "force band high end, N at reference scale");
  auto* seed = app.add_option("--seed", cfg.op.seed, "simulated operator seed");
  app.add_option("--domain", dds_opts.domain, "DDS domain id")->check(CLI::Range(0, 230));
  app.add_option("--partition", dds_opts.partition, "DDS partition")->capture_default_str();
  app.add_option("--dds-config", dds_opts.config, "Cyclone DDS XML config file");
  app.add_option("--connect-timeout", connect_timeout, "seconds to wait for the server")->capture_default_str();
  app.add_flag("-q,--quiet", quiet, "no progress line");
  auto* rt = app.add_option("--rt-priority", cfg.loop.rt_priority,
                            "run the 1 kHz loop at this SCHED_FIFO priority (1-99; needs CAP_SYS_NICE)")
                 ->check(CLI::Range(1, 99));
  std::string render = "model";
  double deadband = 0.0;
  bool no_pc = false;
  app.add_option("--render", render,
                 "model: render from the local joint model (model-mediated); direct: render the "
                 "force the server computes (the baseline design)")
      ->check(CLI::IsMember({"model", "direct"}))->capture_default_str();
  app.add_option("--deadband", deadband,
                 "perceptual deadband on the live DeviceState stream, Weber fraction (e.g. 0.05; 0 = every sample)")
      ->check(CLI::Range(0.0, 0.5))->capture_default_str();
  app.add_flag("--no-passivity-control", no_pc, "passivity observer only, no added damping");
  app.add_option("--log-level", log_level, "trace, debug, info, warn, error, off")->capture_default_str();
  uint64_t follow = 0;
  std::string stiffness = "cubic", patient_name = "healthy", cases_dir = TELEHAND_DEPLOY_DIR "/cases";
  double thimble_noise = 1.43, sweep_seconds = 10.0;
  app.add_option("--follow", follow, "feel the live fit of this capture session (e.g. an expert's, elsewhere)");
  app.add_option("--stiffness", stiffness, "with --follow: render the fitted cubics or the captured samples (k nearest neighbours)")
      ->check(CLI::IsMember({"cubic", "knn"}))->capture_default_str();
  app.add_option("--patient", patient_name, "capture mode, simulated MF-2: the real finger in the grip (a patient case)")->capture_default_str();
  app.add_option("--cases", cases_dir, "patient cases directory (for --patient)")->capture_default_str();
  app.add_option("--thimble-noise", thimble_noise, "capture mode, simulated MF-2: thimble error per axis, N RMS (paper: 1.43)")
      ->check(CLI::Range(0.0, 10.0))->capture_default_str();
  app.add_option("--sweep-seconds", sweep_seconds, "capture mode, simulated MF-2: seconds the clinician mobilizes each axis")
      ->check(CLI::Range(1.0, 600.0))->capture_default_str();
  TELEHAND_CLI_PARSE(app, argc, argv)

  try {
    setupLogging("telehand-client", log_level);
    if (!config_path.empty()) {
      const ClientConfig file = loadClientConfig(config_path);
      const OperatorConfig cli_op = cfg.op;
      const int rt_cli = cfg.loop.rt_priority;
      cfg = file;
      if (*freq) cfg.op.frequency_hz = cli_op.frequency_hz;
      if (*bmin) cfg.op.band_min_n = cli_op.band_min_n;
      if (*bmax) cfg.op.band_max_n = cli_op.band_max_n;
      if (*seed) cfg.op.seed = cli_op.seed;
      if (*rt) cfg.loop.rt_priority = rt_cli;
    }
    validate(cfg.op, "command line");
    client::usb::UsbMf2Config usb_cfg;
    usb_cfg.vendor_id = client::usb::parseUsbId(usb_vid, "--usb-vid");
    usb_cfg.product_id = client::usb::parseUsbId(usb_pid, "--usb-pid");
    usb_cfg.serial = usb_serial;
    if (list_devices) {
      std::cout << client::usb::formatUsbMf2List(
          client::usb::listUsbMf2(usb_cfg.vendor_id, usb_cfg.product_id), usb_cfg.vendor_id,
          usb_cfg.product_id);
      return 0;
    }

    SteadyClock clock;
    const JointModelParams initial = healthyIndexMcp();
    const mf2::Mf2Description description =
        device_file.empty() ? mf2::defaultMf2() : mf2::loadMf2Description(device_file);
    const telehand_msg_SessionMode mode = *parseMode(mode_name);
    if (follow != 0 && mode == telehand_msg_MODE_CAPTURE) throw ConfigError("--follow needs a mode other than capture");
    // Capture: a real (simulated) finger in the grip, moved by a clinician with the
    // actuators off; the thimbles measure real forces (no 1:4 rendering scale).
    JointModelParams geometry = initial;
    devices::SimulatedMf2Dynamics dyn;
    std::optional<devices::SweepOperator> clinician;
    JointModelParams patient;
    if (mode == telehand_msg_MODE_CAPTURE && device_kind != "usb") {
      patient = loadPatientCaseByName(cases_dir, patient_name).model;
      geometry.force_scale = 1.0;
      dyn.operator_damping = 0.0;  // the clinician's damping is in the servo: the FSRs see it
      dyn.mass_kg += 2.1e-5 / (initial.lever_arm_m * initial.lever_arm_m);  // the phalanx (docs/facts.md)
      devices::SweepPlan plan = devices::planSweep(patient);
      plan.seconds_per_axis = sweep_seconds;
      clinician.emplace(plan);
    }
    devices::Mf2ModelCalibration usb_calibration(description);
    std::unique_ptr<devices::Device> device_owner;
    client::usb::UsbMf2* usb = nullptr;
    if (device_kind == "usb") {
      auto d = std::make_unique<client::usb::UsbMf2>(usb_cfg, usb_calibration, clock);
      usb = d.get();
      device_owner = std::move(d);
      usb->start();
      if (!usb->waitReady(std::chrono::milliseconds(static_cast<int64_t>(device_timeout * 1000)))) {
        char waited[32];
        std::snprintf(waited, sizeof waited, "%.1f s", device_timeout);
        throw DeviceError(std::string("the MF-2 is not streaming after ") + waited + ": " +
                          usb->statusText());
      }
    } else {
      auto sim = std::make_unique<devices::SimulatedMf2>(geometry, cfg.op, clock, dyn, description);
      if (clinician) {
        sim->setPatient(patient);
        sim->setOperator(&*clinician);
        sim->setAxisForceNoise(thimble_noise);
      }
      device_owner = std::move(sim);
    }
    devices::Device& device = *device_owner;
    client::loop::TeleopOptions teleop;
    teleop.render = render == "direct" ? client::loop::RenderMode::kDirect : client::loop::RenderMode::kModel;
    teleop.passivity.control = !no_pc;
    client::loop::HapticLoop loop(device, clock, initial, cfg.safety, cfg.loop, teleop);
    client::link::ClientLink link(dds_opts, loop);
    link.setDeadband(DeadbandConfig{deadband});

    client::link::OpenRequest req;
    req.mode = mode;
    req.case_name = case_name;
    req.user = user;
    req.follow_session = follow;
    req.stiffness = stiffness == "knn" ? telehand_msg_STIFFNESS_KNN : telehand_msg_STIFFNESS_CUBIC;
    req.direct_force = teleop.render == client::loop::RenderMode::kDirect;
    const auto timeout = std::chrono::milliseconds(static_cast<int64_t>(connect_timeout * 1000));
    const uint64_t session = link.open(req, timeout);
    if (!link.awaitModel(timeout)) {
      throw Error("session " + std::to_string(session) + " opened but no JointModel arrived");
    }
    loop.setActuatorsEnabled(req.mode != telehand_msg_MODE_CAPTURE);
    if (req.mode == telehand_msg_MODE_CAPTURE) {
      link.sendFiles(mf2::descriptionFiles(description));
      std::cout << "session " << session << " open: capture (actuators off) of patient '" << patient_name
                << "' with device " << description.name << ", thimbles " << description.thimbles[kThumb].serial
                << " and " << description.thimbles[kIndex].serial << std::endl;
    } else {
      std::cout << "session " << session << " open: " << mode_name << " on case '" << case_name
                << "', device " << device.name() << ", " << cfg.op.frequency_hz << " Hz in "
                << cfg.op.band_min_n << "-" << cfg.op.band_max_n << " N"
                << (follow ? ", following capture session " + std::to_string(follow) + " (" + stiffness + ")" : "")
                << std::endl;
    }

    installStopSignals();
    link.start();
    loop.start();
    if (cfg.loop.rt_priority > 0) {
      std::this_thread::sleep_for(10ms);
      if (const int err = loop.realtimeError()) {
        std::cerr << "telehand-client: SCHED_FIFO priority " << cfg.loop.rt_priority
                  << " refused (" << std::strerror(err) << "): the loop runs at normal priority\n";
      }
    }
    const auto t0 = std::chrono::steady_clock::now();
    const bool tty = isatty(STDOUT_FILENO) != 0;
    double applied_min = 1e9, applied_max = 0.0;
    auto next_print = t0 + 1s;
    uint64_t live_prev = 0;
    while (!g_stop_requested.load()) {
      std::this_thread::sleep_for(50ms);
      const auto now = std::chrono::steady_clock::now();
      const double t = std::chrono::duration<double>(now - t0).count();
      const auto& h = loop.health();
      if (t > cfg.op.ramp_s + 0.5) {
        applied_min = std::min(applied_min, h.applied_ref_n.load());
        applied_max = std::max(applied_max, h.applied_ref_n.load());
      }
      for (const auto& m : link.takeMessages()) std::cerr << "server: " << m << "\n";
      if (usb != nullptr) {
        for (const auto& m : usb->takeMessages()) std::cerr << "device: " << m << "\n";
      }
      if (t >= seconds) break;
      if (!quiet && now >= next_print) {
        next_print += 1s;
        const uint64_t live = link.stats().live_sent.load();
        char line[240];
        std::snprintf(line, sizeof line,
                      "%s t=%5.1fs  sent %7llu  live %4llu/s  overruns %llu  force %.2f N  applied %5.1f N ref  model v%u  PO %.3f J",
                      tty ? "\r" : "", t, static_cast<unsigned long long>(link.stats().samples_sent.load()),
                      static_cast<unsigned long long>(live - live_prev),
                      static_cast<unsigned long long>(h.overruns.load()), h.last_force_n.load(),
                      h.applied_ref_n.load(), h.model_version.load(), h.passivity_energy_j.load());
        live_prev = live;
        std::cout << line << (tty ? "" : "\n") << std::flush;
      }
    }
    loop.stop();
    if (usb != nullptr) {
      usb->stop();
      for (const auto& m : usb->takeMessages()) std::cerr << "device: " << m << "\n";
    }
    const double duration = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    link.stop();
    if (!quiet && tty) std::cout << "\n";
    const auto closed = link.close(15s);
    const auto& h = loop.health();
    const uint64_t sent = link.stats().samples_sent.load();
    std::printf("summary: session %llu, %.1f s, %llu ticks, %llu samples sent (%llu in %llu record chunks)\n",
                static_cast<unsigned long long>(session), duration,
                static_cast<unsigned long long>(h.ticks.load()), static_cast<unsigned long long>(sent),
                static_cast<unsigned long long>(link.stats().samples_chunked.load()),
                static_cast<unsigned long long>(link.stats().chunks_sent.load()));
    std::printf("  loop: %llu overruns, worst wake-up %.0f us late, %llu watchdog trips, "
                "%llu clamps, %llu rate-limited, %llu samples dropped\n",
                static_cast<unsigned long long>(h.overruns.load()), static_cast<double>(h.max_lateness_ns.load()) / 1e3,
                static_cast<unsigned long long>(h.watchdog_trips.load()),
                static_cast<unsigned long long>(h.clamped.load()),
                static_cast<unsigned long long>(h.rate_limited.load()),
                static_cast<unsigned long long>(h.samples_dropped.load()));
    if (req.mode == telehand_msg_MODE_CAPTURE) {
      // The loop scales what the thimbles measure by the rendering scale; a capture has none.
      const double scale = initial.force_scale;
      std::printf("  force: commanded %.2f N (actuators off); the thimbles measured %.1f..%.1f N\n",
                  h.force_max_n.load(), applied_min > applied_max ? 0.0 : applied_min * scale,
                  applied_max * scale);
    } else {
      std::printf("  force: commanded up to %.2f N per finger; applied %.1f..%.1f N at reference scale "
                  "(band %.0f-%.0f N)\n",
                  h.force_max_n.load(), applied_min > applied_max ? 0.0 : applied_min, applied_max,
                  cfg.op.band_min_n, cfg.op.band_max_n);
    }
    std::printf("  teleop: render %s; DeviceState live %.1f packets/s (%llu of %llu samples%s)%s; "
                "passivity energy %.4f J (lowest %.4f J), controller active %llu ticks; "
                "%llu model updates, largest update step %.3f N (%.2f of the bound)\n",
                render.c_str(), static_cast<double>(link.stats().live_sent.load()) / std::max(duration, 1e-3),
                static_cast<unsigned long long>(link.stats().live_sent.load()),
                static_cast<unsigned long long>(sent), deadband > 0.0 ? ", deadband" : "",
                render == "direct" ? (", " + std::to_string(link.stats().direct_forces.load()) +
                                      " server forces received").c_str()
                                   : "",
                h.passivity_energy_j.load(), h.passivity_min_energy_j.load(),
                static_cast<unsigned long long>(h.passivity_activations.load()),
                static_cast<unsigned long long>(h.models_applied.load()), h.update_step_max_n.load(),
                h.update_step_max_ratio.load());
    if (usb != nullptr) {
      const auto& u = usb->stats();
      const uint64_t rtts = u.rtt_count.load();
      std::printf("  usb: %llu state packets, %llu commands, %llu rejected (%llu stale, %llu out of "
                  "order), %llu lost, %llu stalls, %llu timeouts, %llu overflows, %llu disconnects; "
                  "command round trip mean %.0f us, max %.0f us\n",
                  static_cast<unsigned long long>(u.packets_in.load()),
                  static_cast<unsigned long long>(u.commands_out.load()),
                  static_cast<unsigned long long>(u.rejectedTotal()),
                  static_cast<unsigned long long>(u.stale.load()),
                  static_cast<unsigned long long>(u.out_of_order.load()),
                  static_cast<unsigned long long>(u.lost.load()),
                  static_cast<unsigned long long>(u.stalls.load()),
                  static_cast<unsigned long long>(u.timeouts.load()),
                  static_cast<unsigned long long>(u.overflows.load()),
                  static_cast<unsigned long long>(u.disconnects.load()),
                  rtts ? static_cast<double>(u.rtt_sum_ns.load()) / static_cast<double>(rtts) / 1e3 : 0.0,
                  static_cast<double>(u.rtt_max_ns.load()) / 1e3);
    }
    if (!closed.confirmed) {
      std::printf("  record: the server did not confirm the close within 15 s\n");
      return 3;
    }
    std::printf("  record: %llu samples recorded, %llu missing, in %s\n",
                static_cast<unsigned long long>(closed.samples_recorded),
                static_cast<unsigned long long>(closed.samples_missing), closed.record.c_str());
    return closed.samples_missing == 0 && closed.samples_recorded == sent ? 0 : 3;
  } catch (const telehand::Error& e) {
    std::cerr << "telehand-client: " << e.what() << "\n";
    return 2;
  }
}
