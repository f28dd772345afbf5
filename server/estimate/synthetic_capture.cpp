#include "server/estimate/synthetic_capture.h"

#include <filesystem>
#include <fstream>
#include <sstream>

#include "client/device/simulated_mf2.h"
#include "client/loop/haptic_loop.h"
#include "telehand/common/clock.h"
#include "telehand/common/error.h"

namespace telehand::server::estimate {

namespace {
constexpr double kPhalanxInertiaKgM2 = 2.1e-5;
}  // namespace

JointModelParams captureGeometry(const JointModelParams& joint) {
  JointModelParams g = joint;
  g.force_scale = 1.0;  // the thimbles measure real forces; 1:4 is a rendering scale
  return g;
}

SyntheticCapture synthesizeCapture(const SyntheticCaptureOptions& o,
                                   const std::function<void(double)>& progress) {
  SyntheticCapture out;
  out.geometry = captureGeometry(o.truth);
  out.plan = client::device::planSweep(o.truth, o.max_force_n, o.range_fraction);
  out.plan.seconds_per_axis = o.seconds_per_axis;
  out.plan.frequency_hz = o.frequency_hz;
  out.plan.repeat = false;
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
  auto read = [](const std::string& path) {
    std::ifstream in(path);
    if (!in) throw ConfigError("cannot read '" + path + "' to store it with the session");
    std::ostringstream ss;
    ss << in.rdbuf();
    return ss.str();
  };
  if (d.path.empty()) {
    files.push_back({"device.toml", "# built-in MF-2 description (mf2::defaultMf2): " + d.source + "\n"});
    return files;
  }
  files.push_back({"device/" + std::filesystem::path(d.path).filename().string(), read(d.path)});
  for (const auto& t : d.thimble_files) {
    files.push_back({"thimble/" + std::filesystem::path(t).filename().string(), read(t)});
  }
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
