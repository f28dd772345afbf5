#pragma once
// The MF-2 the session runs on: over USB, the simulated one held by a virtual clinician
// (mobilizing, or exploring the six directions in exploration mode), or in capture mode the
// simulated one on the capture rig (a patient's finger in the grip).
#include <memory>

#include "lesson.h"
#include "options.h"
#include "telehand/client/usb/usb_mf2.h"
#include "telehand/core/clock.h"
#include "telehand/devices/capture_rig.h"
#include "telehand/devices/exploration_operator.h"
#include "telehand/devices/mf2_device.h"
#include "telehand/devices/simulated_massage_mf2.h"
#include "telehand/protocol/wire.h"

namespace telehand::client::app {

/// --usb-vid, --usb-pid and --usb-serial.
usb::UsbMf2Config usbConfig(const ClientOptions& o);

class ClientDevice {
 public:
  /// Opens the device `o` asks for; a USB MF-2 must be streaming within --device-timeout.
  ClientDevice(const ClientOptions& o, const mf2::Mf2Description& description,
               telehand_msg_SessionMode mode, const JointModelParams& initial, const Clock& clock);

  devices::Device& device() noexcept { return *device_; }
  /// The USB MF-2, or null.
  usb::UsbMf2* usb() noexcept { return usb_.get(); }
  /// A lesson run on the simulated MF-2: the simulated student on case `joint` (before the
  /// loop starts). Null with a real MF-2: the student at it acts the phases out.
  /// A massage lesson's student massages in the trials and rests otherwise.
  LessonActor* prepareLesson(const JointModelParams& joint, const ClientOptions& o);

 private:
  devices::Mf2ModelCalibration usb_calibration_;
  std::unique_ptr<usb::UsbMf2> usb_;
  std::unique_ptr<devices::CaptureRig> rig_;
  std::unique_ptr<devices::SimulatedMf2> sim_;
  std::unique_ptr<devices::SimulatedMassageMf2> massage_;   // --technique massage, simulated
  std::unique_ptr<devices::ExplorationOperator> explorer_;  // --mode exploration, simulated
  std::unique_ptr<LessonOperator> student_;                 // --lesson, simulated
  std::unique_ptr<MassageLessonActor> massage_student_;     // --technique massage --lesson
  devices::Device* device_ = nullptr;
};

}  // namespace telehand::client::app
