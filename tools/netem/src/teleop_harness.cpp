#include "telehand/netem/teleop_harness.h"

#include <spdlog/spdlog.h>
#include <time.h>

#include <chrono>
#include <cmath>
#include <deque>
#include <filesystem>
#include <fstream>
#include <optional>
#include <sstream>
#include <variant>

#include "telehand/core/clock.h"
#include "telehand/core/error.h"
#include "telehand/devices/simulated_massage_mf2.h"
#include "telehand/devices/simulated_mf2.h"
#include "telehand/protocol/wire.h"
#include "telehand/server/session/session_manager.h"
#include "telehand/server/store/sqlite_store.h"

namespace telehand::teleop {

namespace {

namespace fs = std::filesystem;

/// What the server sends, kept for the emulated downlink.
class BenchOutbox final : public server::session::Outbox {
 public:
  void publish(const telehand_msg_SessionStatus& s) override { status.push_back(s); }
  void publish(const telehand_msg_JointModel& m) override { models.push_back(m); }
  void publish(const telehand_msg_HandState& h) override {
    ++hand_states;
    Vec3 a(h.mcp_angles_rad[0], h.mcp_angles_rad[1], h.mcp_angles_rad[2]);
    hand_angles.emplace_back(h.device_seq, a);
    if (h.technique == telehand_msg_TECHNIQUE_MASSAGE) {
      PerFinger<Vec3> f;
      for (int k = 0; k < 2; ++k)
        f[k] = Vec3(h.web_force_n[k][0], h.web_force_n[k][1], h.web_force_n[k][2]);
      web_forces.emplace_back(h.device_seq, f);
    }
  }
  void publish(const telehand_msg_SessionEvent&) override {}
  void publish(const telehand_msg_DirectForce& f) override { forces.push_back(f); }

  std::vector<telehand_msg_SessionStatus> status;
  std::vector<telehand_msg_JointModel> models;
  std::vector<telehand_msg_DirectForce> forces;
  uint64_t hand_states = 0;
  std::vector<std::pair<uint64_t, Vec3>>
      hand_angles;  ///< the authoritative MCP angles per device seq
  std::vector<std::pair<uint64_t, PerFinger<Vec3>>> web_forces;  ///< the server's web, per seq
};

/// A directory holding the one patient case the cell uses, its recovery time shortened.
class CaseDir {
 public:
  CaseDir(const std::string& name, double recovery_treatment_s) {
    char tmpl[] = "/tmp/telehand-teleop-XXXXXX";
    if (!mkdtemp(tmpl)) throw Error("cannot create a temporary case directory");
    dir_ = tmpl;
    // The benchmark's own cases first (tests/teleop/cases), then the product's.
    fs::path src = fs::path(TELEHAND_TELEOP_CASES) / (name + ".toml");
    if (!fs::exists(src)) src = fs::path(TELEHAND_DEPLOY_DIR) / "cases" / (name + ".toml");
    std::ifstream in(src);
    if (!in) throw ConfigError("no patient case '" + src.string() + "'");
    std::stringstream ss;
    ss << in.rdbuf();
    std::string text = ss.str();
    const std::string key = "treatment_s = ";
    if (const auto at = text.find(key); at != std::string::npos) {
      const auto end = text.find('\n', at);
      text.replace(at, end - at, key + std::to_string(recovery_treatment_s));
    }
    std::ofstream(fs::path(dir_) / (name + ".toml")) << text;
  }
  ~CaseDir() {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  const std::string& path() const { return dir_; }

 private:
  std::string dir_;
};

/// Second-order Butterworth high-pass (bilinear transform), one per force component.
class HighPass {
 public:
  HighPass(double cutoff_hz, double rate_hz) {
    const double k = std::tan(kPi * cutoff_hz / rate_hz);
    const double q = std::sqrt(2.0);
    const double norm = 1.0 / (1.0 + q * k + k * k);
    b0_ = norm;
    b1_ = -2.0 * norm;
    b2_ = norm;
    a1_ = 2.0 * (k * k - 1.0) * norm;
    a2_ = (1.0 - q * k + k * k) * norm;
  }
  double operator()(double x) noexcept {
    const double y = b0_ * x + b1_ * x1_ + b2_ * x2_ - a1_ * y1_ - a2_ * y2_;
    x2_ = x1_;
    x1_ = x;
    y2_ = y1_;
    y1_ = y;
    return y;
  }

 private:
  double b0_, b1_, b2_, a1_, a2_;
  double x1_ = 0, x2_ = 0, y1_ = 0, y2_ = 0;
};

using Up = std::variant<telehand_msg_DeviceState, std::vector<telehand_msg_DeviceState>>;
using Down = std::variant<telehand_msg_JointModel, telehand_msg_DirectForce>;

struct Chunk {
  uint64_t chunk_seq;
  std::vector<telehand_msg_DeviceState> samples;
};

/// The servo clinician (Clinician::kServo): flexion follows mid ± amp at the operator's
/// frequency, where the initial joint holds 12 and 16 N; the other axes are held at zero.
class ServoClinician final : public devices::Operator {
 public:
  ServoClinician(const JointModel& joint, const OperatorConfig& op) : op_(op) {
    double lo = joint.restAngleRad(kFlexion), hi = lo;
    // Past the range end too: a short joint is mobilized on its end-of-range wall.
    const double max = degToRad(joint.params().axes[kFlexion].max_deg + 30.0);
    for (double a = lo; a <= max; a += degToRad(0.05)) {
      const double f = joint.holdingForceN(kFlexion, a);
      if (f < op.band_min_n) lo = a;
      if (f < op.band_max_n) hi = a;
    }
    mid_ = 0.5 * (lo + hi);
    amp_ = 0.5 * (hi - lo);
  }
  Vec3 torqueNm(double t_s, const Vec3& angles, const Vec3& rates) noexcept override {
    // A finger about as stiff as a pinching hand (2 kN/m at the 1 cm grip, device scale),
    // critically damped on the grip's 50 g.
    constexpr double kStiffness = 0.2, kDamping = 0.002;
    const double smooth = smoothRamp(t_s, op_.ramp_s);
    const Vec3 target(smooth * (mid_ + amp_ * std::sin(2.0 * kPi * op_.frequency_hz * t_s)), 0.0,
                      0.0);
    return kStiffness * (target - angles) - kDamping * rates;
  }

 private:
  OperatorConfig op_;
  double mid_ = 0.0, amp_ = 0.0;
};

}  // namespace

CellResult runCell(const CellSpec& spec, const server::sim::HandModel* hand) {
  using client::loop::HapticLoop;
  CellResult r;
  spdlog::set_level(spdlog::level::warn);  // the server's per-session info lines, 36 times over
  ManualClock clock(1'000 * kNsPerS);
  CaseDir cases(spec.case_name, spec.recovery_treatment_s);
  ServerConfig cfg;
  cfg.cases_dir = cases.path();
  cfg.hand_deadband_weber = spec.deadband.weber;
  cfg.drift_correction = spec.drift_correction;
  server::store::SqliteStore store(":memory:");
  BenchOutbox out;
  server::session::SessionManager manager(store, out, cfg, hand);

  telehand_msg_SessionCommand open{};
  open.client_id = 1;
  open.request_seq = 1;
  open.kind = telehand_msg_CMD_OPEN;
  const bool massage = spec.technique == Technique::kMassage;
  open.mode = massage ? telehand_msg_MODE_MASSAGE : telehand_msg_MODE_MOBILIZATION;
  open.direct_force = spec.render == client::loop::RenderMode::kDirect;
  copyString(open.case_name, spec.case_name);
  copyString(open.user, "bench");
  copyString(open.text, "");
  manager.onCommand(open, clock.nowNs());
  if (out.status.empty() || out.models.empty()) throw Error("the server did not open the session");
  const uint64_t session = out.status.back().session_id;
  std::string why;
  const auto initial = fromWire(out.models.front(), &why);
  if (!initial) throw Error("bad initial model: " + why);
  out.models.clear();  // the client waits for this one before it starts (ClientLink::awaitModel)

  OperatorConfig op = spec.op;
  op.seed = spec.seed;
  std::optional<devices::SimulatedMf2> mobilization;
  std::optional<devices::SimulatedMassageMf2> massage_device;
  std::optional<ServoClinician> servo;
  devices::Device* device = nullptr;
  if (massage) {
    if (initial->technique != Technique::kMassage) throw Error("the server opened no massage");
    device = &massage_device.emplace(initial->tissue, op, clock, initial->force_scale);
  } else {
    device = &mobilization.emplace(*initial, op, clock);
    if (spec.clinician == Clinician::kServo) {
      servo.emplace(JointModel(*initial), op);
      mobilization->setOperator(&*servo);
    }
  }
  client::loop::TeleopOptions teleop;
  teleop.render = spec.render;
  teleop.passivity.control = spec.passivity_control;
  HapticLoop loop(*device, clock, *initial, SafetyLimits{}, LoopConfig{}, teleop);
  loop.setSession(session);

  DelayLine<Up> up(spec.link, spec.seed * 2 + 1);
  DelayLine<Down> down(spec.link, spec.seed * 2 + 2);
  // Reliable topics (record chunks up, joint models down): a lost packet is repaired after a
  // round trip plus Cyclone's heartbeat/NACK exchange; a newer JointModel supersedes.
  const int64_t repair_ns = static_cast<int64_t>(spec.link.rtt_ms * 1e6) + 10 * kNsPerMs;
  std::deque<std::pair<int64_t, Chunk>> chunk_retry;
  std::deque<std::pair<int64_t, telehand_msg_JointModel>> model_retry;
  uint64_t up_packets = 0, down_packets = 0, live_packets = 0, chunk_seq = 0;

  DeviceStateDeadband deadband(spec.deadband);
  std::vector<telehand_msg_DeviceState> chunk;
  chunk.reserve(100);
  std::array<double, 4> held_applied{};  // what the server holds: last sample sent live
  double recon_err2 = 0.0, recon_ref2 = 0.0;

  std::array<HighPass, 6> hp{HighPass(15.0, 1000.0), HighPass(15.0, 1000.0),
                             HighPass(15.0, 1000.0), HighPass(15.0, 1000.0),
                             HighPass(15.0, 1000.0), HighPass(15.0, 1000.0)};
  double hp2 = 0.0, all2 = 0.0;

  const int64_t period = kNsPerMs;
  const uint64_t ticks = static_cast<uint64_t>(spec.seconds * 1000.0);
  const uint64_t steady_tick = static_cast<uint64_t>(spec.steady_from_s * 1000.0);
  r.force.reserve(ticks);
  std::vector<Vec3> proxy_angles;  // what the client rendered, per seq
  proxy_angles.reserve(ticks);
  std::vector<PerFinger<Vec3>> proxy_web;  // the web force the client's proxy rendered, per seq
  if (massage) proxy_web.reserve(ticks);

  auto sendChunk = [&](Chunk c, int64_t now) {
    ++up_packets;
    if (!up.send(Up{c.samples}, now)) chunk_retry.emplace_back(now + repair_ns, std::move(c));
  };
  auto sendModel = [&](const telehand_msg_JointModel& m, int64_t now) {
    ++down_packets;
    if (!down.send(Down{m}, now)) model_retry.emplace_back(now + repair_ns, m);
  };

  for (uint64_t tick = 0; tick < ticks; ++tick) {
    clock.advance(period);
    const int64_t now = clock.nowNs();

    // Server -> client.
    down.deliver(now, [&](const Down& d) {
      if (const auto* m = std::get_if<telehand_msg_JointModel>(&d)) {
        if (auto p = fromWire(*m, &why)) loop.models().tryPush(*p);
      } else {
        const auto& f = std::get<telehand_msg_DirectForce>(d);
        client::loop::DirectForceSample s;
        s.device_seq = f.device_seq;
        for (int k = 0; k < 2; ++k)
          s.force_n[k] = Vec3(f.force_n[k][0], f.force_n[k][1], f.force_n[k][2]);
        loop.directForces().tryPush(s);
      }
    });

    // CPU time of this thread: the step's own work, not the scheduler's preemptions.
    timespec c0{}, c1{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &c0);
    loop.step();
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &c1);
    const double us =
        static_cast<double>((c1.tv_sec - c0.tv_sec) * kNsPerS + (c1.tv_nsec - c0.tv_nsec)) * 1e-3;
    r.step_max_us = std::max(r.step_max_us, us);
    if (us > 1000.0) ++r.overruns;

    // The client's link thread: live stream through the deadband, every sample into chunks.
    Sample s;
    while (loop.samples().tryPop(s)) {
      std::array<float, 6> f{};
      for (int k = 0; k < 2; ++k) {
        for (int i = 0; i < 3; ++i)
          f[static_cast<std::size_t>(3 * k + i)] = static_cast<float>(s.fingers[k].command_n[i]);
      }
      r.force.push_back(f);
      proxy_angles.emplace_back(s.mcp_angles_rad[0], s.mcp_angles_rad[1], s.mcp_angles_rad[2]);
      const bool steady = s.seq >= steady_tick;
      if (massage) {
        PerFinger<Vec3> w;
        for (int k = 0; k < 2; ++k) {
          w[k] = Vec3(s.fingers[k].tissue_force_n[0], s.fingers[k].tissue_force_n[1],
                      s.fingers[k].tissue_force_n[2]);
          if (steady) r.web_force_max_n = std::max(r.web_force_max_n, w[k].norm());
        }
        proxy_web.push_back(w);
      }
      for (std::size_t i = 0; i < 6; ++i) {
        const double h = hp[i](f[i]);
        if (steady) {
          hp2 += h * h;
          all2 += static_cast<double>(f[i]) * f[i];
        }
      }
      if (spec.deadband.enabled()) s.flags |= sample_flags::kDeadband;
      if (deadband.admit(s, s.source_time_ns)) {
        s.flags |= sample_flags::kSentLive;
        ++live_packets;
        ++up_packets;
        up.send(Up{toWire(s)}, now);
        held_applied = {s.fingers[0].tangential_n, s.fingers[0].normal_n, s.fingers[1].tangential_n,
                        s.fingers[1].normal_n};
      }
      if (steady) {
        const std::array<double, 4> truth = {s.fingers[0].tangential_n, s.fingers[0].normal_n,
                                             s.fingers[1].tangential_n, s.fingers[1].normal_n};
        for (std::size_t i = 0; i < 4; ++i) {
          recon_err2 += (truth[i] - held_applied[i]) * (truth[i] - held_applied[i]);
          recon_ref2 += truth[i] * truth[i];
        }
      }
      chunk.push_back(toWire(s));
      if (chunk.size() == 100) {
        sendChunk(Chunk{chunk_seq++, std::move(chunk)}, now);
        chunk = {};
        chunk.reserve(100);
      }
    }
    while (!chunk_retry.empty() && chunk_retry.front().first <= now) {
      Chunk c = std::move(chunk_retry.front().second);
      chunk_retry.pop_front();
      sendChunk(std::move(c), now);
    }

    // Client -> server, then the server's tick.
    up.deliver(now, [&](const Up& u) {
      if (const auto* d = std::get_if<telehand_msg_DeviceState>(&u)) {
        manager.onDeviceState(*d, now);
      } else {
        const auto& samples = std::get<std::vector<telehand_msg_DeviceState>>(u);
        telehand_msg_RecordChunk c{};
        c.session_id = session;
        c.samples._buffer = const_cast<telehand_msg_DeviceState*>(samples.data());
        c.samples._length = static_cast<uint32_t>(samples.size());
        c.samples._maximum = c.samples._length;
        c.samples._release = false;
        manager.onChunk(c, now);
      }
    });
    manager.tick(now);
    for (const auto& m : out.models) {
      std::erase_if(model_retry, [](const auto&) { return true; });  // superseded (keep-last 1)
      sendModel(m, now);
    }
    out.models.clear();
    while (!model_retry.empty() && model_retry.front().first <= now) {
      const auto m = model_retry.front().second;
      model_retry.pop_front();
      sendModel(m, now);
    }
    for (const auto& f : out.forces) {
      ++down_packets;
      down.send(Down{f}, now);
    }
    out.forces.clear();
  }

  // Close: the rest of the record reaches the server (reliable), then the session ends.
  if (!chunk.empty()) {
    telehand_msg_RecordChunk c{};
    c.session_id = session;
    c.samples._buffer = chunk.data();
    c.samples._length = static_cast<uint32_t>(chunk.size());
    c.samples._maximum = c.samples._length;
    manager.onChunk(c, clock.nowNs());
  }
  int64_t flush = clock.nowNs();
  while (up.inFlight() > 0 || !chunk_retry.empty()) {
    flush += kNsPerMs;
    up.deliver(flush, [&](const Up& u) {
      if (const auto* samples = std::get_if<std::vector<telehand_msg_DeviceState>>(&u)) {
        telehand_msg_RecordChunk c{};
        c.session_id = session;
        c.samples._buffer = const_cast<telehand_msg_DeviceState*>(samples->data());
        c.samples._length = static_cast<uint32_t>(samples->size());
        c.samples._maximum = c.samples._length;
        manager.onChunk(c, flush);
      }
    });
    while (!chunk_retry.empty() && chunk_retry.front().first <= flush) {
      Chunk c = std::move(chunk_retry.front().second);
      chunk_retry.pop_front();
      sendChunk(std::move(c), flush);
    }
  }
  telehand_msg_SessionCommand close{};
  close.client_id = 1;
  close.request_seq = 2;
  close.kind = telehand_msg_CMD_CLOSE;
  close.session_id = session;
  close.samples_sent = loop.nextSeq();
  close.last_seq = loop.nextSeq() - 1;
  manager.onCommand(close, flush);
  manager.tick(flush);
  if (const auto info = store.session(session)) r.samples_recorded = info->samples;

  const auto& h = loop.health();
  const double secs = spec.seconds;
  r.ticks = ticks;
  r.po_min_j = h.passivity_min_energy_j.load();
  r.po_final_j = h.passivity_energy_j.load();
  r.pc_ticks = h.passivity_activations.load();
  r.clamped = h.clamped.load();
  r.update_step_max_n = h.update_step_max_n.load();
  r.update_step_ratio = h.update_step_max_ratio.load();
  r.models_applied = h.models_applied.load();
  r.fade_unpaid_j = h.fade_unpaid_energy_j.load();
  r.oscillation = all2 > 0.0 ? std::sqrt(hp2 / all2) : 0.0;
  r.device_state_pps = static_cast<double>(live_packets) / secs;
  r.up_pps = static_cast<double>(up_packets) / secs;
  r.down_pps = static_cast<double>(down_packets) / secs;
  r.hand_state_pps = static_cast<double>(out.hand_states) / secs;
  r.reconstruction_error = recon_ref2 > 0.0 ? std::sqrt(recon_err2 / recon_ref2) : 0.0;
  // Drift: the server's hand against the client's proxy for the same device sample, per axis:
  // its mean (what persists, and what the server corrects) and its RMS (the mean plus the
  // hand's lag behind the moving thimbles).
  Vec3 sum = Vec3::Zero(), sum2 = Vec3::Zero();
  uint64_t drift_n = 0;
  for (const auto& [seq, a] : out.hand_angles) {
    if (seq < steady_tick || seq >= proxy_angles.size()) continue;
    const Vec3 d = (a - proxy_angles[seq]) * (180.0 / kPi);
    sum += d;
    sum2 += d.cwiseProduct(d);
    ++drift_n;
  }
  if (drift_n > 0) {
    const double n = static_cast<double>(drift_n);
    r.drift_mean_deg = (sum / n).cwiseAbs().maxCoeff();
    r.drift_rms_deg = (sum2 / n).cwiseSqrt().maxCoeff();
  }
  r.drift_corrections = manager.stats().drift_corrections;
  r.fault = h.fault.load();
  if (massage) {
    const double all = static_cast<double>(h.massage_ticks.load());
    r.massage_in_band = all > 0.0 ? static_cast<double>(h.massage_in_band.load()) / all : 0.0;
    double e2 = 0.0;
    for (const auto& [seq, f] : out.web_forces) {
      if (seq < steady_tick || seq >= proxy_web.size()) continue;
      for (int k = 0; k < 2; ++k) {
        const Vec3& c = proxy_web[seq][k];
        const double e = (f[k] - c).norm() / std::max(c.norm(), 1.0);
        r.web_error_max = std::max(r.web_error_max, std::isfinite(e) ? e : 1e9);
        e2 += e * e;
      }
      ++r.web_compared;
    }
    if (r.web_compared > 0)
      r.web_error_rms = std::sqrt(e2 / (2.0 * static_cast<double>(r.web_compared)));
  }
  return r;
}

double forceError(const CellResult& cell, const CellResult& ref, const CellSpec& spec) {
  const std::size_t from = static_cast<std::size_t>(spec.steady_from_s * 1000.0);
  const std::size_t to = std::min(cell.force.size(), ref.force.size());
  double e2 = 0.0, r2 = 0.0;
  for (std::size_t t = from; t < to; ++t) {
    for (std::size_t i = 0; i < 6; ++i) {
      const double d = static_cast<double>(cell.force[t][i]) - ref.force[t][i];
      e2 += d * d;
      r2 += static_cast<double>(ref.force[t][i]) * ref.force[t][i];
    }
  }
  return r2 > 0.0 ? std::sqrt(e2 / r2) : 0.0;
}

bool stable(const CellResult& r) noexcept { return r.oscillation < kMaxOscillation; }
bool passive(const CellResult& r) noexcept { return r.po_min_j >= -kPassivityToleranceJ; }
bool massageStable(const CellResult& r) noexcept { return r.fault == 0; }

}  // namespace telehand::teleop
