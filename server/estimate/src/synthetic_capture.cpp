#include "telehand/server/estimate/synthetic_capture.h"

#include "telehand/core/clock.h"
#include "telehand/core/error.h"
#include "telehand/devices/capture_rig.h"

namespace telehand::server::estimate {

SyntheticCapture synthesizeCapture(const SyntheticCaptureOptions& o,
                                   const std::function<void(double)>& progress) {
  SyntheticCapture out;
  out.geometry = captureGeometry(o.truth);
  out.plan = devices::planSweep(o.truth, o.max_force_n, o.wall_deg);
  out.plan.seconds_per_axis = o.seconds_per_axis;
  out.plan.frequency_hz = o.frequency_hz;
  out.plan.frequency_spread = o.frequency_spread;
  out.plan.repeat = false;
  out.plan.combined = o.combined_sweep;

  ManualClock clock(kNsPerS);
  devices::CaptureRigOptions rig_options;
  rig_options.geometry = out.geometry;
  rig_options.patient = o.truth;
  rig_options.patient_joint = o.patient;
  rig_options.plan = out.plan;
  rig_options.op.sensor_noise_n = o.sensor_noise_n;
  rig_options.op.seed = o.seed;
  rig_options.axis_noise_n = o.noise_n;
  rig_options.device = o.device;
  rig_options.substeps = o.rig_substeps;
  devices::CaptureRig rig(rig_options, clock);

  const auto ticks = static_cast<std::size_t>(out.plan.durationS() * 1000.0);
  out.samples.reserve(ticks);
  Sample s;
  for (std::size_t i = 0; i < ticks; ++i) {
    clock.advance(kNsPerMs);
    if (rig.step(out.samples.size(), s)) out.samples.push_back(s);
    if (progress && i % 5000 == 0) progress(static_cast<double>(i) / static_cast<double>(ticks));
  }
  if (progress) progress(1.0);
  return out;
}

std::vector<store::SessionFile> deviceFiles(const mf2::Mf2Description& d) {
  std::vector<store::SessionFile> files;
  for (auto& f : mf2::descriptionFiles(d))
    files.push_back({std::move(f.name), std::move(f.content)});
  return files;
}

uint64_t storeCapture(store::SessionStore& store, const SyntheticCapture& capture,
                      const std::string& case_name, const std::string& user,
                      const std::vector<store::SessionFile>& files) {
  store::SessionInfo info;
  info.user = user;
  info.case_name = case_name;
  info.mode = "capture";
  info.state = "active";
  info.started_ns = capture.samples.empty() ? 0 : capture.samples.front().source_time_ns;
  const uint64_t id = store.createSession(info);
  for (const auto& f : files) store.appendFile(id, f);
  constexpr std::size_t kBatch = 5000;
  for (std::size_t i = 0; i < capture.samples.size(); i += kBatch) {
    std::vector<Sample> batch(capture.samples.begin() + static_cast<std::ptrdiff_t>(i),
                              capture.samples.begin() + static_cast<std::ptrdiff_t>(std::min(
                                                            i + kBatch, capture.samples.size())));
    for (auto& s : batch) s.session_id = id;
    const std::vector<uint8_t> valid(batch.size(), 1);
    store.appendSamples(id, batch, valid);
  }
  const int64_t end = capture.samples.empty() ? 0 : capture.samples.back().source_time_ns;
  store.closeSession(id, end, capture.samples.size(), "closed");
  return id;
}

}  // namespace telehand::server::estimate
