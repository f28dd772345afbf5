#include "server/estimate/synthetic_capture.h"


#include "client/device/simulated_mf2.h"
#include "client/loop/haptic_loop.h"
#include "telehand/common/clock.h"
#include "telehand/common/error.h"

namespace telehand::server::estimate {

namespace {
constexpr double kPhalanxInertiaKgM2 = 2.1e-5;
}  // namespace

SyntheticCapture synthesizeCapture(const SyntheticCaptureOptions& o,
                                   const std::function<void(double)>& progress) {
  SyntheticCapture out;
  out.geometry = captureGeometry(o.truth);
  out.plan = client::device::planSweep(o.truth, o.max_force_n, o.range_fraction);
  out.plan.seconds_per_axis = o.seconds_per_axis;
  out.plan.frequency_hz = o.frequency_hz;
  out.plan.repeat = false;
  out.plan.combined = o.combined_sweep;
  client::device::SweepOperator clinician(out.plan);

  ManualClock clock(kNsPerS);
  OperatorConfig op;
  op.sensor_noise_n = o.sensor_noise_n;
  op.seed = o.seed;
  client::device::SimulatedMf2Dynamics dyn;
  dyn.operator_damping = 0.0;  // the clinician's damping is in the servo: the FSRs see it
  // The patient's proximal phalanx moves with the grip: 2.1e-5 kg m^2 about the MCP
  // (FACTS.md "Ground truth") is 0.21 kg at the 1 cm lever arm.
  dyn.mass_kg += kPhalanxInertiaKgM2 / (o.truth.lever_arm_m * o.truth.lever_arm_m);
  client::device::SimulatedMf2 dev(out.geometry, op, clock, dyn, o.device);
  dev.setPatient(o.truth);
  if (o.patient) dev.setPatient(o.patient);
  dev.setOperator(&clinician);
  dev.setAxisForceNoise(o.noise_n);

  client::loop::HapticLoop loop(dev, clock, out.geometry, SafetyLimits{});
  loop.setActuatorsEnabled(false);  // capture: the gate holds every output at zero
  loop.setSession(0);
  const auto ticks = static_cast<std::size_t>(out.plan.durationS() * 1000.0);
  out.samples.reserve(ticks);
  telehand_msg_DeviceState s;
  for (std::size_t i = 0; i < ticks; ++i) {
    clock.advance(kNsPerMs);
    loop.step();
    while (loop.samples().tryPop(s)) out.samples.push_back(s);
    if (progress && i % 5000 == 0) progress(static_cast<double>(i) / static_cast<double>(ticks));
  }
  if (progress) progress(1.0);
  return out;
}

std::vector<session::SessionFile> deviceFiles(const mf2::Mf2Description& d) {
  std::vector<session::SessionFile> files;
  for (auto& f : mf2::descriptionFiles(d)) files.push_back({std::move(f.name), std::move(f.content)});
  return files;
}

uint64_t storeCapture(session::SessionStore& store, const SyntheticCapture& capture,
                      const std::string& case_name, const std::string& user,
                      const std::vector<session::SessionFile>& files) {
  session::SessionInfo info;
  info.user = user;
  info.case_name = case_name;
  info.mode = "capture";
  info.state = "active";
  info.started_ns = capture.samples.empty() ? 0 : capture.samples.front().source_time_ns;
  const uint64_t id = store.createSession(info);
  for (const auto& f : files) store.appendFile(id, f);
  constexpr std::size_t kBatch = 5000;
  for (std::size_t i = 0; i < capture.samples.size(); i += kBatch) {
    std::vector<telehand_msg_DeviceState> batch(
        capture.samples.begin() + static_cast<std::ptrdiff_t>(i),
        capture.samples.begin() + static_cast<std::ptrdiff_t>(std::min(i + kBatch, capture.samples.size())));
    for (auto& s : batch) s.session_id = id;
    const std::vector<uint8_t> valid(batch.size(), 1);
    store.appendSamples(id, batch, valid);
  }
  const int64_t end = capture.samples.empty() ? 0 : capture.samples.back().source_time_ns;
  store.closeSession(id, end, capture.samples.size(), "closed");
  return id;
}

}  // namespace telehand::server::estimate
