#pragma once
// A massage trial on the simulated MF-2: each millisecond the device is read, the tissue
// proxy renders the web at the thimbles (as the client's loop would, without its safety
// gate) and its device-scale force is written back; in a capture the actuators are off and
// nothing is rendered. Records the samples as the loop records them, with the ground truth.
#include <cmath>
#include <vector>

#include "telehand/config/config.h"
#include "telehand/core/clock.h"
#include "telehand/core/sample.h"
#include "telehand/core/thimble.h"
#include "telehand/core/tissue_model.h"
#include "telehand/devices/simulated_massage_mf2.h"

namespace telehand::test {

struct MassageTrialOptions {
  TissueParams web = tissueCase("healthy");
  OperatorConfig op{};
  double seconds = 20.0;
  double force_scale = 0.25;
  bool capture = false;        ///< the web is real: setPatient(web), actuators off
  double force_noise_n = 0.0;  ///< setForceNoise
  /// In a capture, characterise the web first (setCaptureProtocol) with this seed.
  bool protocol = false;
  uint64_t protocol_seed = 1;
};

struct MassageTrial {
  std::vector<Sample> samples;
  /// Per sample, per finger: the force the device rendered (device frame, after the
  /// actuators) and, in a capture, the web's normal force on the finger (reference N).
  std::vector<PerFinger<Vec3>> rendered;
  std::vector<PerFinger<double>> truth_normal_n;
  std::vector<PerFinger<Vec3>> true_position;
  bool complete = false;  ///< every read succeeded
};

inline MassageTrial runMassageTrial(const MassageTrialOptions& o) {
  ManualClock clock(kNsPerS);
  devices::SimulatedMassageMf2 dev(o.web, o.op, clock, o.force_scale);
  if (o.capture) dev.setPatient(o.web);
  if (o.capture && o.protocol) {
    devices::MassageCaptureProtocol protocol;
    protocol.seed = o.protocol_seed;
    dev.setCaptureProtocol(protocol);
  }
  dev.setForceNoise(o.force_noise_n);
  TissueProxy proxy(o.web, o.force_scale);
  MassageTrial trial;
  const auto ticks = static_cast<std::size_t>(std::lround(o.seconds * 1000.0));
  trial.samples.reserve(ticks);
  trial.rendered.reserve(ticks);
  trial.truth_normal_n.reserve(ticks);
  trial.true_position.reserve(ticks);
  devices::DeviceSample d;
  for (std::size_t i = 0; i < ticks; ++i) {
    clock.advance(kNsPerMs);
    if (!dev.read(d)) return trial;
    const PerFinger<Vec3> p{d.fingers[kThumb].position_m, d.fingers[kIndex].position_m};
    devices::ForceCommand cmd;
    if (!o.capture) cmd.force_n = proxy.render(p, d.time_ns).force_device_n;
    dev.write(cmd);
    Sample s;
    s.seq = i;
    s.source_time_ns = d.time_ns;
    if (o.capture) s.flags |= sample_flags::kCapture;
    for (int k = 0; k < 2; ++k) {
      const devices::FingerSample& f = d.fingers[k];
      SampleFinger& out = s.fingers[k];
      for (int a = 0; a < 3; ++a) {
        out.position_m[a] = f.position_m[a];
        out.command_n[a] = cmd.force_n[k][a];
      }
      out.orientation_q[0] = f.orientation.w();
      out.orientation_q[1] = f.orientation.x();
      out.orientation_q[2] = f.orientation.y();
      out.orientation_q[3] = f.orientation.z();
      for (int j = 0; j < 4; ++j) out.fsr_n[j] = f.fsr_n[j];
      const ThimbleForces tf = thimbleForces(f.fsr_n);
      out.tangential_n = static_cast<float>(tf.tangential_n);
      out.normal_n = static_cast<float>(tf.normal_n);
    }
    trial.samples.push_back(s);
    trial.rendered.push_back(dev.renderedForce());
    trial.truth_normal_n.push_back({dev.patientContact()[kThumb].normal_n.norm(),
                                    dev.patientContact()[kIndex].normal_n.norm()});
    trial.true_position.push_back(dev.positions());
  }
  trial.complete = true;
  return trial;
}

}  // namespace telehand::test
