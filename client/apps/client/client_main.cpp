// telehand-client: the device PC side. Runs the 1 kHz haptic loop on an MF-2 (simulated by
// default, or over USB), opens a session on the server, streams every sample and renders
// the joint model the server publishes.
//
// options: the command line and config file; device: the MF-2 (USB, simulated, or the
// capture rig); session: running it and its summary.
#include <chrono>
#include <iostream>
#include <string>

#include "device.h"
#include "options.h"
#include "session.h"
#include "telehand/client/link/client_link.h"
#include "telehand/core/log.h"
#include "telehand/protocol/wire.h"

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
    const JointModelParams initial = healthyIndexMcp();
    const mf2::Mf2Description description =
        o.device_file.empty() ? mf2::defaultMf2() : mf2::loadMf2Description(o.device_file);
    const telehand_msg_SessionMode mode = *parseMode(o.mode_name);
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
    const auto timeout = std::chrono::milliseconds(static_cast<int64_t>(o.connect_timeout * 1000));
    const uint64_t session = link.open(req, timeout);
    if (!link.awaitModel(timeout)) {
      throw Error("session " + std::to_string(session) + " opened but no JointModel arrived");
    }
    const bool capture = req.mode == telehand_msg_MODE_CAPTURE;
    loop.setActuatorsEnabled(!capture);
    if (capture) {
      link.sendFiles(mf2::descriptionFiles(description));
      std::cout << "session " << session << " open: capture (actuators off) of patient '"
                << o.patient_name << "' with device " << description.name << ", thimbles "
                << description.thimbles[kThumb].serial << " and "
                << description.thimbles[kIndex].serial << std::endl;
    } else {
      std::cout << "session " << session << " open: " << o.mode_name << " on case '" << o.case_name
                << "', device " << device.name() << ", " << cfg.op.frequency_hz << " Hz in "
                << cfg.op.band_min_n << "-" << cfg.op.band_max_n << " N"
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
