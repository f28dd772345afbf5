#pragma once
/// Synthetic captures: a mobilization played on a ground-truth joint through the simulated
/// MF-2 (device model, thimble calibration) and the client's own 1 kHz loop in capture mode
/// (the safety gate holds the actuators at zero), with the paper's thimble error, stored as
/// a capture session like a real one. Every part of capture and fitting can then be tested
/// end to end against a known truth.
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "telehand/core/joint_model.h"
#include "telehand/core/sample.h"
#include "telehand/devices/capture_rig.h"
#include "telehand/devices/mf2_device.h"
#include "telehand/devices/sweep_operator.h"
#include "telehand/server/estimate/capture_fit.h"
#include "telehand/server/store/store.h"

namespace telehand::server::estimate {

struct SyntheticCaptureOptions {
  JointModelParams truth = healthyIndexMcp();
  /// Thimble error as the force each axis sees, N RMS: the paper's ±1.43 N (docs/facts.md).
  double noise_n = 1.43;
  double sensor_noise_n = 0.02;    ///< FSR channel noise before the ADC, N
  double seconds_per_axis = 10.0;  ///< as telehand-client --sweep-seconds
  double frequency_hz = 0.5;
  /// The sweep's slowest frequency as a fraction of frequency_hz (SweepPlan::frequency_spread).
  double frequency_spread = devices::SweepPlan{}.frequency_spread;
  /// The clinician goes no further than this force (the FSRs saturate at about 22 N)...
  double max_force_n = 18.0;
  double wall_deg = 3.0;  ///< ...and this far into the end stop (planSweep)
  uint64_t seed = 1;
  mf2::Mf2Description device = mf2::defaultMf2();
  /// A joint the cubics cannot express (coupled axes): moves the finger instead of `truth`,
  /// which still plans the sweep. Not owned.
  const devices::PatientJoint* patient = nullptr;
  bool combined_sweep = false;  ///< flexion and abduction together (SweepPlan::combined)
  /// The finger's integration steps a sample (CaptureRigOptions::substeps).
  int rig_substeps = devices::CaptureRigOptions{}.substeps;
};

struct SyntheticCapture {
  std::vector<Sample> samples;  ///< as the client's loop recorded them
  JointModelParams geometry;    ///< frame and lever arm, reference scale
  devices::SweepPlan plan;
};

/// Runs the capture (deterministic for a seed). `progress(fraction)` now and then.
SyntheticCapture synthesizeCapture(const SyntheticCaptureOptions& o,
                                   const std::function<void(double)>& progress = {});

/// Store as a capture session with its device and thimble calibration files; returns its id.
uint64_t storeCapture(store::SessionStore& store, const SyntheticCapture& capture,
                      const std::string& case_name, const std::string& user,
                      const std::vector<store::SessionFile>& files);

/// The device and calibration files of a description, as a session stores them: the files it
/// was loaded from, or a note that it was built in.
std::vector<store::SessionFile> deviceFiles(const mf2::Mf2Description& d);

}  // namespace telehand::server::estimate
