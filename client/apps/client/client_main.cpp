// telehand-client: the device PC side. Runs the 1 kHz haptic loop on an MF-2 (simulated by
// default, or over USB), opens a session on the server, streams every sample and renders
// the joint model the server publishes.
//
// options: the command line and config file; device: the MF-2 (USB, simulated, or the
// capture rig); session: running it and its summary.
#include <spdlog/fmt/fmt.h>

#include <chrono>
#include <cstdio>
#include <iostream>
#include <set>
#include <string>

#include "device.h"
#include "lesson.h"
#include "options.h"
#include "session.h"
#include "telehand/client/link/client_link.h"
#include "telehand/core/log.h"
#include "telehand/protocol/wire.h"

namespace telehand::client::app {
namespace {
/// A lesson run: its plan from the server, the simulated student (with the simulated MF-2),
/// the phases, the feedback, the summary.
int runLessonSession(const ClientOptions& o, ClientDevice& mf2, loop::HapticLoop& loop,
                     link::ClientLink& link, uint64_t session) {
  using namespace std::chrono_literals;
  std::string why;
  const auto plan = decodePlan(link.lessonPlan(), &why);
  if (!plan)
    throw Error("session " + std::to_string(session) + ": the server's lesson plan: " + why);
  const bool massage = plan->technique == "massage";
  if (massage != (o.technique_name == "massage")) {
    throw Error("session " + std::to_string(session) + ": lesson " +
                std::to_string(plan->lesson_id) + " teaches the " + plan->technique +
                (massage ? ": run it with --technique massage" : ", not the massage"));
  }
  JointModelParams joint = healthyIndexMcp();
  try {
    joint = loadPatientCaseByName(o.cases_dir, link.openedCase()).model;
  } catch (const ConfigError&) {
  }
  LessonActor* student = mf2.prepareLesson(joint, o);
  const std::vector<LessonStep> steps = lessonSteps(*plan, o);
  double total = 0.0;
  for (const auto& st : steps) total += st.seconds;
  std::cout << "session " << session << " open: " << (massage ? "massage " : "") << "lesson "
            << plan->lesson_id << " on case '" << link.openedCase() << "', " << plan->guided
            << " guided trial(s) and " << plan->attempts << " attempt(s) of " << plan->trial_s
            << " s, " << plan->schedule << " feedback, about " << static_cast<int>(total) << " s"
            << std::endl;
  LessonDriver driver(*plan, steps, loop, link, student,
                      std::set<int>(o.request_feedback.begin(), o.request_feedback.end()), o.quiet);
  const RunTotals totals =
      runSession(o, loop, link, mf2.usb(), [&](double t) { return driver.step(t); });
  const auto closed = link.close(30s);
  driver.finish();
  const int code = printSummary(o, session, false, joint.force_scale, totals, loop.health(), link,
                                mf2.usb(), closed);
  std::printf("  lesson: %d of %d trials run, %zu scores received\n", driver.trialsRun(),
              plan->guided + plan->attempts, driver.scores().size());
  if (const auto fault = faultMessage(loop.health(), o.cfg.safety)) {
    std::cerr << "telehand-client: " << *fault << "\n";
    return kExitRenderingFault;
  }
  if (code == 0 && driver.trialsRun() < plan->guided + plan->attempts) return 3;
  return code;
}
}  // namespace
}  // namespace telehand::client::app

int main(int argc, char** argv) {
  using namespace telehand;
  using namespace telehand::client::app;
  using namespace std::chrono_literals;
  ClientOptions o;
  if (const auto done = parseOptions(argc, argv, o)) return *done;

  try {
    setupLogging("telehand-client", o.log_level);
    applyConfigFile(o);
    const ClientConfig& cfg = o.cfg;
    const client::usb::UsbMf2Config usb_cfg = usbConfig(o);
    if (o.list_devices) {
      std::cout << client::usb::formatUsbMf2List(
          client::usb::listUsbMf2(usb_cfg.vendor_id, usb_cfg.product_id), usb_cfg.vendor_id,
          usb_cfg.product_id);
      return 0;
    }

    SteadyClock clock;
    const bool massage = o.technique_name == "massage";
    if (massage && (o.mode_name == "exploration" || o.follow != 0)) {
      throw ConfigError(
          "--technique massage goes with --mode mobilization or capture, or with --lesson");
    }
    JointModelParams initial = healthyIndexMcp();
    if (massage) {  // the web of the case until the server's model arrives
      initial.technique = Technique::kMassage;
      initial.tissue = tissueCase(o.case_name.c_str());
    }
    const mf2::Mf2Description description =
        o.device_file.empty() ? mf2::defaultMf2() : mf2::loadMf2Description(o.device_file);
    telehand_msg_SessionMode mode =
        o.lesson != 0 ? telehand_msg_MODE_LESSON : *parseMode(o.mode_name);
    if (massage && mode == telehand_msg_MODE_MOBILIZATION) mode = telehand_msg_MODE_MASSAGE;
    if (o.follow != 0 && mode == telehand_msg_MODE_CAPTURE) {
      throw ConfigError("--follow needs a mode other than capture");
    }
    ClientDevice mf2(o, description, mode, initial, clock);
    devices::Device& device = mf2.device();
    client::loop::TeleopOptions teleop;
    teleop.render =
        o.render == "direct" ? client::loop::RenderMode::kDirect : client::loop::RenderMode::kModel;
    teleop.passivity.control = !o.no_pc;
    teleop.fault.enabled = !o.no_fault_stop;
    client::loop::HapticLoop loop(device, clock, initial, cfg.safety, cfg.loop, teleop);
    client::link::ClientLink link(o.dds, loop);
    link.setDeadband(DeadbandConfig{o.deadband});

    client::link::OpenRequest req;
    req.mode = mode;
    req.case_name = o.case_name;
    req.user = o.user;
    req.follow_session = o.follow;
    req.stiffness =
        o.stiffness == "knn" ? telehand_msg_STIFFNESS_KNN : telehand_msg_STIFFNESS_CUBIC;
    req.direct_force = teleop.render == client::loop::RenderMode::kDirect;
    req.lesson_id = o.lesson;
    if (massage) req.technique = telehand_msg_TECHNIQUE_MASSAGE;
    const auto timeout = std::chrono::milliseconds(static_cast<int64_t>(o.connect_timeout * 1000));
    const uint64_t session = link.open(req, timeout);
    if (!link.awaitModel(timeout)) {
      throw Error("session " + std::to_string(session) + " opened but no JointModel arrived");
    }
    if (mode == telehand_msg_MODE_LESSON) return runLessonSession(o, mf2, loop, link, session);
    const bool capture = req.mode == telehand_msg_MODE_CAPTURE;
    loop.setActuatorsEnabled(!capture);
    if (capture) {
      link.sendFiles(mf2::descriptionFiles(description));
      std::cout << "session " << session << " open: capture (actuators off) of patient '"
                << o.patient_name << "' with device " << description.name << ", thimbles "
                << description.thimbles[kThumb].serial << " and "
                << description.thimbles[kIndex].serial << std::endl;
    } else {
      std::cout << "session " << session << " open: " << (massage ? "massage" : o.mode_name)
                << " on case '" << o.case_name << "', device " << device.name() << ", "
                << (massage ? std::string("circles on the web at 10 ± 2 N")
                            : fmt::format("{} Hz in {}-{} N", cfg.op.frequency_hz,
                                          cfg.op.band_min_n, cfg.op.band_max_n))
                << (o.follow ? ", following capture session " + std::to_string(o.follow) + " (" +
                                   o.stiffness + ")"
                             : "")
                << std::endl;
    }

    const RunTotals totals = runSession(o, loop, link, mf2.usb());
    const auto closed = link.close(15s);
    const int code = printSummary(o, session, capture, initial.force_scale, totals, loop.health(),
                                  link, mf2.usb(), closed);
    if (const auto fault = faultMessage(loop.health(), cfg.safety)) {
      std::cerr << "telehand-client: " << *fault << "\n";
      return kExitRenderingFault;
    }
    return code;
  } catch (const telehand::Error& e) {
    std::cerr << "telehand-client: " << e.what() << "\n";
    return 2;
  }
}
