#include "device.h"

#include <spdlog/fmt/fmt.h>

#include <chrono>

namespace telehand::client::app {

usb::UsbMf2Config usbConfig(const ClientOptions& o) {
  usb::UsbMf2Config c;
  c.vendor_id = usb::parseUsbId(o.usb_vid, "--usb-vid");
  c.product_id = usb::parseUsbId(o.usb_pid, "--usb-pid");
  c.serial = o.usb_serial;
  return c;
}

ClientDevice::ClientDevice(const ClientOptions& o, const mf2::Mf2Description& description,
                           telehand_msg_SessionMode mode, const JointModelParams& initial,
                           const Clock& clock)
    : usb_calibration_(description) {
  if (o.device_kind == "usb") {
    usb_ = std::make_unique<usb::UsbMf2>(usbConfig(o), usb_calibration_, clock);
    device_ = usb_.get();
    usb_->start();
    if (!usb_->waitReady(
            std::chrono::milliseconds(static_cast<int64_t>(o.device_timeout * 1000)))) {
      throw DeviceError(fmt::format("the MF-2 is not streaming after {:.1f} s: {}",
                                    o.device_timeout, usb_->statusText()));
    }
  } else if (initial.technique == Technique::kMassage) {
    // The massage: the clinician (or the configured student) circles on the web. A capture
    // has a real web between the fingers and the actuators off; the thimbles measure its
    // forces at reference scale with the thimble error.
    massage_ = std::make_unique<devices::SimulatedMassageMf2>(
        initial.tissue, o.cfg.op, clock, initial.force_scale, devices::MassagePlan{},
        devices::SimulatedMassageDynamics{}, description);
    if (mode == telehand_msg_MODE_CAPTURE) {
      TissueParams truth = tissueCase(o.patient_name.c_str());
      try {
        const PatientCase patient = loadPatientCaseByName(o.cases_dir, o.patient_name);
        truth = patient.tissue;
      } catch (const ConfigError&) {
      }
      massage_->setPatient(truth);
      massage_->setForceNoise(o.thimble_noise);
      // Characterise the web first (indentations, strokes), then the circles.
      devices::MassageCaptureProtocol protocol;
      protocol.seed = o.cfg.op.seed;
      massage_->setCaptureProtocol(protocol);
    }
    device_ = massage_.get();
  } else if (mode == telehand_msg_MODE_CAPTURE) {
    // Capture: a real (simulated) finger in the grip, moved by a clinician with the
    // actuators off; the thimbles measure real forces (no 1:4 rendering scale).
    devices::CaptureRigOptions rig;
    rig.geometry = initial;
    rig.patient = loadPatientCaseByName(o.cases_dir, o.patient_name).model;
    rig.plan = devices::planSweep(rig.patient);
    rig.plan.seconds_per_axis = o.sweep_seconds;
    rig.op = o.cfg.op;
    rig.axis_noise_n = o.thimble_noise;
    rig.device = description;
    rig_ = std::make_unique<devices::CaptureRig>(rig, clock);
    device_ = &rig_->device();
  } else {
    sim_ = std::make_unique<devices::SimulatedMf2>(initial, o.cfg.op, clock,
                                                   devices::SimulatedMf2Dynamics{}, description);
    device_ = sim_.get();
    // The clinician places the finger at the case's rest pose and, exploring, plans against
    // its ranges: from the case file when this machine has it (the server's copy rules what
    // is rendered), else the healthy joint.
    JointModelParams joint = initial;
    try {
      joint = loadPatientCaseByName(o.cases_dir, o.case_name).model;
    } catch (const ConfigError&) {
    }
    const JointModel rest(joint);
    sim_->setPose(Vec3(rest.restAngleRad(kFlexion), rest.restAngleRad(kAbduction),
                       rest.restAngleRad(kAxial)));
    if (mode == telehand_msg_MODE_EXPLORATION) {
      devices::ExplorationPlan plan = devices::planExploration(joint, o.cfg.op.band_max_n);
      plan.force_scale = initial.force_scale;
      plan.lever_arm_m = initial.lever_arm_m;
      plan.seed = o.cfg.op.seed;
      explorer_ = std::make_unique<devices::ExplorationOperator>(plan);
      sim_->setOperator(explorer_.get());
    }
  }
}

LessonActor* ClientDevice::prepareLesson(const JointModelParams& joint, const ClientOptions& o) {
  if (massage_) {
    massage_student_ = std::make_unique<MassageLessonActor>(*massage_);
    massage_->setPerforming(false);  // the trials start the massage
    return massage_student_.get();
  }
  if (!sim_) return nullptr;
  const JointModel rest(joint);
  sim_->setPose(
      Vec3(rest.restAngleRad(kFlexion), rest.restAngleRad(kAbduction), rest.restAngleRad(kAxial)));
  devices::ExplorationPlan plan = devices::planExploration(joint, o.cfg.op.band_max_n);
  plan.force_scale = joint.force_scale;
  plan.lever_arm_m = joint.lever_arm_m;
  plan.seed = o.cfg.op.seed;
  student_ = std::make_unique<LessonOperator>(*sim_, plan, joint,
                                              devices::SimulatedMf2Dynamics{}.operator_stiffness);
  sim_->setOperator(student_.get());
  return student_.get();
}

}  // namespace telehand::client::app
