#include "telehand/devices/capture_rig.h"

#include <algorithm>

#include "telehand/devices/record.h"

namespace telehand::devices {

namespace {
JointModelParams forCapture(JointModelParams g) {
  g.force_scale = 1.0;
  g.knn = nullptr;
  return g;
}

SimulatedMf2Dynamics rigDynamics(const JointModelParams& geometry, int substeps) {
  SimulatedMf2Dynamics dyn;
  dyn.operator_damping = 0.0;  // the clinician's damping is in the servo: the FSRs see it
  dyn.mass_kg += kPhalanxInertiaKgM2 / (geometry.lever_arm_m * geometry.lever_arm_m);
  dyn.substeps = std::clamp(substeps, 1, 100);
  return dyn;
}
}  // namespace

CaptureRig::CaptureRig(const CaptureRigOptions& o, const Clock& clock)
    : clinician_(o.plan),
      device_(std::make_unique<SimulatedMf2>(forCapture(o.geometry), o.op, clock,
                                             rigDynamics(o.geometry, o.substeps), o.device)),
      proxy_(forCapture(o.geometry)),
      clock_(clock),
      wall_offset_ns_(wallNs() - clock.nowNs()) {
  device_->setPatient(o.patient);
  if (o.patient_joint) device_->setPatient(o.patient_joint);
  device_->setOperator(&clinician_);
  device_->setAxisForceNoise(o.axis_noise_n);
  // The clinician has the finger in the grip, held where the sweep starts, before the
  // capture begins: no start-up transient from the device's own neutral pose in the record.
  device_->setPose(clinician_.target(0.0));
}

bool CaptureRig::step(uint64_t seq, Sample& s) noexcept {
  const int64_t now = clock_.nowNs();
  if (!device_->read(reading_)) return false;
  const PerFinger<Vec3> zero{Vec3::Zero(), Vec3::Zero()};
  device_->write(ForceCommand{});
  const PerFinger<Vec3> p{reading_.fingers[kThumb].position_m, reading_.fingers[kIndex].position_m};
  const ProxyOutput rendered = proxy_.render(p, now);
  s = Sample{};
  s.seq = seq;
  s.source_time_ns = reading_.time_ns + wall_offset_ns_;
  s.model_version = proxy_.version();
  s.flags = sample_flags::kCapture;
  recordTick(reading_, zero, rendered, s);
  return true;
}

}  // namespace telehand::devices
