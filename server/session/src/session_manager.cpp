#include "telehand/server/session/session_manager.h"

#include <spdlog/spdlog.h>

#include <cmath>
#include <cstdio>
#include <deque>

#include "telehand/core/knn_model.h"

#include "telehand/core/clock.h"
#include "telehand/core/error.h"
#include "telehand/core/thimble.h"
#include "telehand/protocol/wire.h"
#include "telehand/server/sim/hand_sim.h"

namespace telehand::server::session {

struct SessionManager::Session {
  SessionInfo info;
  uint64_t client_id = 0;
  uint32_t request_seq = 0;  // the OPEN this session answers
  telehand_msg_SessionMode mode = telehand_msg_MODE_MOBILIZATION;
  PatientCase patient;
  JointModelParams params;
  JointModel model{params};
  std::unique_ptr<sim::HandSim> sim;   // null: HandState from the shared joint model
  double treatment_s = 0.0;            // time the pads pressed the joint (recovery)
  int64_t next_recovery_check_ns = 0;
  Exploration exploration;
  std::vector<SessionStore::Reach> baseline;
  // live stream
  bool have_live = false;
  Sample last{};
  uint64_t live_count = 0;
  uint64_t live_lost = 0;
  int64_t last_data_ns = 0;
  int64_t rate_window_ns = 0;
  uint64_t rate_window_count = 0;
  float rate_hz = 0.0f;
  Vec3 prev_angles = Vec3::Zero();
  int64_t prev_angles_ns = 0;
  // record
  uint64_t recorded = 0;
  std::vector<Sample> pending;  // not yet stored (store error): retried
  std::vector<uint8_t> pending_valid;
  uint64_t nonfinite = 0;
  int64_t nonfinite_reported_ns = INT64_MIN / 2;
  // HandState
  uint64_t hand_seq = 0;               // HandStates published so far
  int64_t next_hand_ns = 0;
  // capture: live refit, and the sessions that feel it
  std::unique_ptr<estimate::LiveRefit> refit;
  std::vector<uint64_t> followers;
  uint64_t follows = 0;                // the capture session this one renders
  bool wants_knn = false;
  std::deque<std::shared_ptr<const KnnTorqueModel>> knn_alive;  // rendered by model and sim
  HandStateDeadband hand_deadband;
  uint64_t hand_withheld = 0;
  // teleoperation
  bool deadband_coded = false;          // the client withholds samples inside its deadband
  int64_t opened_ns = 0;
  std::unique_ptr<JointProxy> direct;   // direct mode: the server renders the force
  DriftCorrector drift;                 // hand against proxy (sessions with a hand)
  uint64_t direct_sent = 0;
  // closing
  bool closing = false;
  uint64_t expected = 0;
  int64_t close_deadline_ns = 0;
};

SessionManager::SessionManager(SessionStore& store, Outbox& out, const ServerConfig& config,
                               const sim::HandModel* hand)
    : store_(store), out_(out), config_(config), hand_(hand) {}

SessionManager::~SessionManager() = default;

void SessionManager::event(uint64_t session_id, uint64_t client_id, telehand_msg_EventKind kind,
                           const std::string& text, int64_t now_ns) {
  (void)now_ns;
  telehand_msg_SessionEvent e{};
  e.session_id = session_id;
  e.seq = ++event_seq_;
  e.source_time_ns = wallNs();
  e.kind = kind;
  e.client_id = client_id;
  copyString(e.text, text);
  out_.publish(e);
  if (session_id != 0 && sessions_.count(session_id)) {
    try {
      store_.appendEvent(session_id, {e.source_time_ns, std::string(eventKindName(kind)), text});
    } catch (const StoreError& err) {
      ++stats_.store_errors;
      spdlog::error("{}", err.what());
    }
  }
  if (kind == telehand_msg_EVENT_ERROR) {
    spdlog::warn("session {}: {}", session_id, text);
  } else {
    spdlog::info("session {}: {}", session_id, text);
  }
}

void SessionManager::unknownSession(uint64_t session_id, const std::string& what, int64_t now_ns) {
  if (unknown_reported_ns_.size() >= kMaxUnknownIds && !unknown_reported_ns_.count(session_id)) {
    // A flood of made-up ids must not grow memory: forget ids not reported for 5 s, and past
    // the cap leave new ones unreported (they are still counted in the stats).
    std::erase_if(unknown_reported_ns_,
                  [&](const auto& kv) { return now_ns - kv.second >= 5 * kNsPerS; });
    if (unknown_reported_ns_.size() >= kMaxUnknownIds) return;
  }
  auto [it, fresh] = unknown_reported_ns_.try_emplace(session_id, now_ns);
  if (!fresh && now_ns - it->second < 5 * kNsPerS) return;
  it->second = now_ns;
  event(0, 0, telehand_msg_EVENT_ERROR,
        what + " for unknown session " + std::to_string(session_id) + " dropped", now_ns);
}

void SessionManager::onCommand(const telehand_msg_SessionCommand& cmd, int64_t now_ns) {
  switch (cmd.kind) {
    case telehand_msg_CMD_OPEN:
      open(cmd, now_ns);
      return;
    case telehand_msg_CMD_CLOSE:
      requestClose(cmd, now_ns);
      return;
    case telehand_msg_CMD_MARK: {
      if (!sessions_.count(cmd.session_id)) {
        ++stats_.bad_commands;
        event(0, cmd.client_id, telehand_msg_EVENT_ERROR,
              "MARK for unknown session " + std::to_string(cmd.session_id), now_ns);
        return;
      }
      event(cmd.session_id, cmd.client_id, telehand_msg_EVENT_MARK, cmd.text, now_ns);
      Session& s = sessions_.at(cmd.session_id);
      if (std::string(cmd.text) == "reassessment") {
        endExploration(s, now_ns);
        s.exploration.begin("reassessment");
      }
      return;
    }
  }
  ++stats_.bad_commands;
  event(0, cmd.client_id, telehand_msg_EVENT_ERROR,
        "unknown command kind " + std::to_string(static_cast<int>(cmd.kind)), now_ns);
}

void SessionManager::open(const telehand_msg_SessionCommand& cmd, int64_t now_ns) {
  std::string case_name = cmd.case_name;
  PatientCase patient;
  Session* capture = nullptr;
  if (cmd.follow_session != 0) {
    // A follower renders the live fit of a running capture session.
    auto it = sessions_.find(cmd.follow_session);
    if (it == sessions_.end() || it->second.mode != telehand_msg_MODE_CAPTURE || it->second.closing) {
      ++stats_.bad_commands;
      event(0, cmd.client_id, telehand_msg_EVENT_ERROR,
            "cannot follow session " + std::to_string(cmd.follow_session) +
                ": no capture session of that id is running",
            now_ns);
      return;
    }
    if (cmd.mode == telehand_msg_MODE_CAPTURE) {
      ++stats_.bad_commands;
      event(0, cmd.client_id, telehand_msg_EVENT_ERROR, "a capture session cannot follow another", now_ns);
      return;
    }
    capture = &it->second;
    case_name = "capture-" + std::to_string(cmd.follow_session);
    patient.name = case_name;
    patient.model = capture->params;
  } else if (config_.cases_dir.empty()) {
    if (case_name != "healthy") {
      ++stats_.bad_commands;
      event(0, cmd.client_id, telehand_msg_EVENT_ERROR,
            "unknown patient case '" + case_name + "' (known: healthy)", now_ns);
      return;
    }
    patient.name = "healthy";
    patient.model = healthyIndexMcp();
  } else {
    try {
      patient = loadPatientCaseByName(config_.cases_dir, case_name);
    } catch (const ConfigError& e) {
      ++stats_.bad_commands;
      event(0, cmd.client_id, telehand_msg_EVENT_ERROR, e.what(), now_ns);
      return;
    }
  }
  SessionInfo info;
  info.user = cmd.user;
  info.case_name = case_name;
  info.mode = std::string(modeName(cmd.mode));
  info.state = "active";
  info.started_ns = wallNs();
  try {
    info.id = store_.createSession(info);
  } catch (const StoreError& e) {
    ++stats_.store_errors;
    event(0, cmd.client_id, telehand_msg_EVENT_ERROR,
          std::string("cannot open a session record: ") + e.what(), now_ns);
    return;
  }
  Session& s = sessions_[info.id];
  s.info = info;
  s.client_id = cmd.client_id;
  s.mode = cmd.mode;
  s.patient = patient;
  s.params = patient.at(0.0);
  s.params.version = 1;
  s.params.knn = nullptr;
  s.model = JointModel(s.params);
  if (capture) {
    s.follows = cmd.follow_session;
    s.wants_knn = cmd.stiffness == telehand_msg_STIFFNESS_KNN;
    capture->followers.push_back(info.id);
  }
  if (cmd.mode == telehand_msg_MODE_CAPTURE) {
    s.refit = std::make_unique<estimate::LiveRefit>(estimate::captureGeometry(s.params), s.params,
                                                    refit_options_);
  }
  if (hand_) s.sim = std::make_unique<sim::HandSim>(*hand_, s.params, hand_config_);
  if (cmd.mode == telehand_msg_MODE_EXPLORATION) s.exploration.begin("baseline");
  if (cmd.direct_force) s.direct = std::make_unique<JointProxy>(s.params);
  s.hand_deadband = HandStateDeadband(DeadbandConfig{config_.hand_deadband_weber});
  s.opened_ns = now_ns;
  s.next_recovery_check_ns = now_ns + kNsPerS;
  s.last_data_ns = now_ns;
  s.rate_window_ns = now_ns;
  s.next_hand_ns = now_ns;

  s.request_seq = cmd.request_seq;
  publishStatus(s, telehand_msg_SESSION_ACTIVE, now_ns);
  publishModel(s);
  event(s.info.id, cmd.client_id, telehand_msg_EVENT_INFO,
        "opened: " + info.mode + " on case '" + case_name + "' for " + info.user +
            (capture ? std::string(", following capture session ") + std::to_string(cmd.follow_session) +
                           (s.wants_knn ? " (k-nearest-neighbour model)" : " (cubic model)")
                     : "") +
            (cmd.direct_force ? " (direct force: the server renders)" : ""),
        now_ns);
}

void SessionManager::publishStatus(const Session& s, telehand_msg_SessionState state,
                                   int64_t now_ns) {
  (void)now_ns;
  telehand_msg_SessionStatus st{};
  st.session_id = s.info.id;
  st.client_id = s.client_id;
  st.request_seq = s.request_seq;
  st.source_time_ns = wallNs();
  st.state = state;
  st.mode = s.mode;
  st.started_ns = s.info.started_ns;
  st.ended_ns = state == telehand_msg_SESSION_CLOSED ? wallNs() : 0;
  st.samples_recorded = s.recorded;
  st.samples_missing = state == telehand_msg_SESSION_CLOSED && s.expected > s.recorded
                           ? s.expected - s.recorded
                           : 0;
  copyString(st.case_name, s.info.case_name);
  copyString(st.user, s.info.user);
  copyString(st.record, store_.location() + " session " + std::to_string(s.info.id));
  out_.publish(st);
}

void SessionManager::requestClose(const telehand_msg_SessionCommand& cmd, int64_t now_ns) {
  auto it = sessions_.find(cmd.session_id);
  if (it == sessions_.end()) {
    ++stats_.bad_commands;
    event(0, cmd.client_id, telehand_msg_EVENT_ERROR,
          "CLOSE for unknown session " + std::to_string(cmd.session_id), now_ns);
    return;
  }
  Session& s = it->second;
  s.closing = true;
  s.expected = cmd.samples_sent;
  s.close_deadline_ns = now_ns + static_cast<int64_t>(config_.close_grace_s * 1e9);
  publishStatus(s, telehand_msg_SESSION_CLOSING, now_ns);
}

void SessionManager::stepHand(Session& s) {
  s.sim->step();
  const auto f = s.sim->contactForcesDevice();
  if (s.exploration.active()) {
    const Vec3 angles = s.sim->mcpAngles();
    // The force at the reach is what holds the joint there: the pads' torque about it as a
    // force at the lever arm, as the paper's curves give it (the squeeze cancels out).
    const double holding_n =
        s.model.axisTorque(s.sim->contactPointsDevice(), angles, {Vec3(-f[0]), Vec3(-f[1])}).norm() /
        s.model.params().lever_arm_m;
    s.exploration.observe(angles, holding_n);
  }
  if (f[0].norm() + f[1].norm() > 1.0) s.treatment_s += 1e-3;
}

void SessionManager::onDeviceState(const telehand_msg_DeviceState& wire, int64_t now_ns) {
  onSample(fromWire(wire), now_ns);
}

void SessionManager::onSample(const Sample& d, int64_t now_ns) {
  auto it = sessions_.find(d.session_id);
  if (it == sessions_.end()) {
    ++stats_.unknown_session_samples;
    unknownSession(d.session_id, "DeviceState", now_ns);
    return;
  }
  Session& s = it->second;
  s.last_data_ns = now_ns;
  if (auto bad = firstNonFinite(d)) {
    ++stats_.nonfinite_samples;
    ++s.nonfinite;
    if (now_ns - s.nonfinite_reported_ns > 5 * kNsPerS) {
      s.nonfinite_reported_ns = now_ns;
      event(s.info.id, s.client_id, telehand_msg_EVENT_ERROR,
            "DeviceState seq " + std::to_string(d.seq) + " has a non-finite " + *bad +
                "; not used for the hand state (" + std::to_string(s.nonfinite) + " so far)",
            now_ns);
    }
    return;
  }
  ++stats_.live_samples;
  const PerFinger<Vec3> grip = thimblePositions(d);
  const bool coded = (d.flags & sample_flags::kDeadband) != 0;
  s.deadband_coded = coded;
  if (s.direct && (!s.have_live || d.seq > s.last.seq)) {
    // The baseline design: the server renders the force with the same proxy the client
    // would run, on device time, and sends it back.
    const ProxyOutput out = s.direct->render(grip, d.source_time_ns);
    telehand_msg_DirectForce f{};
    f.session_id = s.info.id;
    f.device_seq = d.seq;
    f.source_time_ns = wallNs();
    for (int k = 0; k < 2; ++k) {
      for (int i = 0; i < 3; ++i) f.force_n[k][i] = out.force_device_n[k][i];
    }
    out_.publish(f);
    ++s.direct_sent;
  }
  if (s.sim && (!s.have_live || d.seq > s.last.seq)) {
    // The simulation runs on device time: one 1 ms step per sample, and one per sample lost
    // on the way, with the thimbles moving in a straight line across the gap (jumping the
    // pads to the new sample would kick the finger and leave the hand lagging the
    // thimbles). An overloaded server must not try to catch up on every lost millisecond
    // (each catch-up would fall further behind): past kMaxCatchUpSteps the hand skips time
    // and the gap shows in HandState.device_lost. A deadband-coded stream withholds samples
    // on purpose: those steps run on the last state received.
    const uint64_t gap = s.have_live ? d.seq - s.last.seq : 1;
    const uint64_t steps = std::min<uint64_t>(gap, coded ? kMaxHeldSteps : kMaxCatchUpSteps);
    if (s.have_live && steps > 1) {
      const bool hold = coded;
      const PerFinger<Vec3> from = thimblePositions(s.last), &to = grip;
      for (uint64_t i = 1; i < steps; ++i) {
        const double w = hold ? 0.0 : static_cast<double>(i) / static_cast<double>(steps);
        s.sim->setFingerTargets({from[0] + w * (to[0] - from[0]), from[1] + w * (to[1] - from[1])},
                                true);
        stepHand(s);
      }
    }
    s.sim->setFingerTargets(grip, true);
    stepHand(s);
    correctDrift(s, grip, static_cast<double>(steps) * 1e-3, now_ns);
  } else if (!s.sim && s.exploration.active()) {
    s.exploration.observe(s.model.anglesFromGrip(grip), 0.0);
  }
  if (!coded && s.have_live && d.seq > s.last.seq + 1) s.live_lost += d.seq - s.last.seq - 1;
  if (!s.have_live || d.seq > s.last.seq) s.last = d;
  s.have_live = true;
  ++s.live_count;
}

void SessionManager::onChunk(const telehand_msg_RecordChunk& c, int64_t now_ns) {
  std::vector<Sample> samples;
  samples.reserve(c.samples._length);
  for (uint32_t i = 0; i < c.samples._length; ++i) samples.push_back(fromWire(c.samples._buffer[i]));
  std::vector<uint8_t> valid(samples.size(), 1);
  for (std::size_t i = 0; i < samples.size(); ++i) {
    valid[i] = !firstNonFinite(samples[i]).has_value() && samples[i].session_id == c.session_id;
  }
  auto it = sessions_.find(c.session_id);
  if (it == sessions_.end()) {
    // A late chunk for a session that already closed still belongs in its record.
    try {
      if (store_.session(c.session_id)) {
        const uint64_t added = store_.appendSamples(c.session_id, samples, valid);
        stats_.recorded_samples += added;
        spdlog::info("session {}: {} late samples stored after close", c.session_id, added);
        return;
      }
    } catch (const StoreError& e) {
      ++stats_.store_errors;
      spdlog::error("{}", e.what());
    }
    ++stats_.unknown_session_samples;
    unknownSession(c.session_id, "RecordChunk", now_ns);
    return;
  }
  Session& s = it->second;
  s.last_data_ns = now_ns;
  if (s.refit) {
    for (std::size_t i = 0; i < samples.size(); ++i) s.refit->add(samples[i], valid[i] != 0, now_ns);
  }
  store(s, std::move(samples), std::move(valid));
}

void SessionManager::onFile(const telehand_msg_SessionFile& f, int64_t now_ns) {
  auto it = sessions_.find(f.session_id);
  if (it == sessions_.end()) {
    unknownSession(f.session_id, "SessionFile", now_ns);
    return;
  }
  const std::string name = f.name;
  const std::string content = f.content ? f.content : "";
  try {
    store_.appendFile(f.session_id, {name, content});
  } catch (const StoreError& e) {
    ++stats_.store_errors;
    event(f.session_id, it->second.client_id, telehand_msg_EVENT_ERROR,
          "file '" + name + "' not stored: " + e.what(), now_ns);
    return;
  }
  event(f.session_id, 0, telehand_msg_EVENT_INFO,
        "stored " + name + " (" + std::to_string(content.size()) + " bytes) with the record", now_ns);
}

void SessionManager::publishModel(const Session& s) {
  telehand_msg_JointModel m{};
  toWire(s.params, s.info.id, m);
  m.source_time_ns = wallNs();
  out_.publish(m);
}

void SessionManager::adoptModel(Session& s, JointModelParams next) {
  next.version = s.params.version + 1;
  next.grip_offset_rad = s.drift.offset();
  s.params = next;
  s.model = JointModel(s.params);
  if (s.sim) s.sim->setMcpModel(s.params);
  if (s.direct) s.direct->setModel(s.params);
  publishModel(s);
}

void SessionManager::correctDrift(Session& s, const PerFinger<Vec3>& grip, double dt_s,
                                  int64_t now_ns) {
  // A capture renders nothing (the actuators are off): there is no proxy to correct.
  if (!config_.drift_correction || s.mode == telehand_msg_MODE_CAPTURE) return;
  const auto pads = s.sim->contactForcesDevice();
  const double min_grip = s.drift.options().min_grip_n;
  const bool held = pads[0].norm() >= min_grip && pads[1].norm() >= min_grip;
  Vec3 proxy = s.model.proxyAngles(grip);
  // Past a range end the proxy renders the end-of-range wall while the hand rests on its
  // hard limit: that gap is the wall's give, which the student must feel, not drift.
  for (std::size_t i = 0; i < kAxes; ++i) {
    const auto& axis = s.params.axes[i];
    proxy[static_cast<int>(i)] = std::clamp(proxy[static_cast<int>(i)], degToRad(axis.min_deg),
                                            degToRad(axis.max_deg));
  }
  const Vec3 before = s.drift.offset();
  if (!s.drift.observe(s.sim->mcpAngles(), proxy, held, dt_s, now_ns)) return;
  ++stats_.drift_corrections;
  adoptModel(s, s.params);
  const Vec3 change_deg = radToDeg(1.0) * (s.drift.offset() - before);
  spdlog::debug("session {}: drift correction v{}: {:.2f} {:.2f} {:.2f} deg", s.info.id,
                s.params.version, change_deg[0], change_deg[1], change_deg[2]);
  // A slip anyone would notice goes in the record and to the supervisors.
  if (change_deg.cwiseAbs().maxCoeff() >= kDriftEventDeg) {
    const Vec3 total = radToDeg(1.0) * s.drift.offset();
    char text[200];
    std::snprintf(text, sizeof text,
                  "grip slipped: the hand is %+.1f/%+.1f/%+.1f deg (flexion/abduction/axial) from "
                  "the thimbles; the proxy follows it (model v%u)",
                  total[0], total[1], total[2], s.params.version);
    event(s.info.id, 0, telehand_msg_EVENT_INFO, text, now_ns);
  }
}

void SessionManager::refit(Session& s, int64_t now_ns) {
  auto u = s.refit->poll(now_ns);
  if (!u) return;
  adoptModel(s, u->params);
  ++stats_.live_models;
  stats_.last_refit_latency_ns = now_ns - u->newest_arrival_ns;
  stats_.max_refit_latency_ns = std::max(stats_.max_refit_latency_ns, stats_.last_refit_latency_ns);
  std::string fitted;
  for (std::size_t i = 0; i < kAxes; ++i) {
    const auto& a = u->fit.axes[i];
    if (!a.ok) continue;
    char b[96];
    std::snprintf(b, sizeof b, "%s%s %.0f..%.0f deg RMS %.2f N", fitted.empty() ? "" : ", ",
                  kAxisNames[i].data(), a.curve.min_deg, a.curve.max_deg, a.rms_n);
    fitted += b;
  }
  char text[256];
  std::snprintf(text, sizeof text, "live fit v%u from %zu samples (change %.1f N): %s", s.params.version,
                s.refit->samples(), u->max_change_n, fitted.c_str());
  event(s.info.id, 0, telehand_msg_EVENT_INFO, text, now_ns);

  std::shared_ptr<const KnnTorqueModel> knn;
  for (uint64_t id : s.followers) {
    auto it = sessions_.find(id);
    if (it == sessions_.end()) continue;
    Session& f = it->second;
    JointModelParams p = u->params;
    p.version = f.params.version + 1;  // adoptModel's, for the KnnModel that goes first
    p.case_name = f.params.case_name;
    if (f.wants_knn && !u->knn_points.empty()) {
      if (!knn) knn = std::make_shared<const KnnTorqueModel>(u->knn_points, refit_options_.knn);
      p.knn = knn.get();
      f.knn_alive.push_back(knn);
      while (f.knn_alive.size() > 3) f.knn_alive.pop_front();  // current, previous, spare
      std::vector<telehand_msg_KnnSample> wire(knn->size());
      for (std::size_t i = 0; i < wire.size(); ++i) {
        for (int a = 0; a < 3; ++a) {
          wire[i].angles_rad[a] = static_cast<float>(knn->samples()[i].angles_rad[a]);
          wire[i].torque_nm[a] = static_cast<float>(knn->samples()[i].torque_nm[a]);
        }
      }
      telehand_msg_KnnModel k{};
      k.session_id = f.info.id;
      k.version = p.version;
      k.source_time_ns = wallNs();
      k.k = static_cast<uint32_t>(refit_options_.knn.k);
      k.samples._buffer = wire.data();
      k.samples._length = static_cast<uint32_t>(wire.size());
      k.samples._maximum = static_cast<uint32_t>(wire.size());
      k.samples._release = false;
      out_.publish(k);  // before its JointModel: a client waits for both
    } else {
      p.knn = nullptr;
    }
    adoptModel(f, p);
  }
}

void SessionManager::store(Session& s, std::vector<Sample>&& samples,
                           std::vector<uint8_t>&& valid) {
  s.pending.insert(s.pending.end(), samples.begin(), samples.end());
  s.pending_valid.insert(s.pending_valid.end(), valid.begin(), valid.end());
  if (s.pending.empty()) return;
  try {
    const uint64_t added = store_.appendSamples(s.info.id, s.pending, s.pending_valid);
    s.recorded += added;
    stats_.recorded_samples += added;
    s.pending.clear();
    s.pending_valid.clear();
  } catch (const StoreError& e) {
    ++stats_.store_errors;
    spdlog::error("session {}: {} ({} samples kept in memory, retrying)", s.info.id, e.what(),
                  s.pending.size());
  }
}

void SessionManager::publishHand(Session& s, int64_t now_ns) {
  telehand_msg_HandState h{};
  h.session_id = s.info.id;
  h.source_time_ns = wallNs();
  h.source = telehand_msg_HAND_SOURCE_SHARED_JOINT_MODEL;
  h.device_rate_hz = s.rate_hz;
  h.device_lost = s.live_lost;
  h.model_version = s.params.version;
  if (s.have_live) {
    const auto& d = s.last;
    h.device_seq = d.seq;
    h.device_time_ns = d.source_time_ns;
    const PerFinger<Vec3> p = thimblePositions(d);
    Vec3 mcp, tau;
    if (!s.sim) {
      // No hand: the shared joint model at the thimbles, rates from successive states.
      mcp = s.model.anglesFromGrip(p);
      Vec3 rates = Vec3::Zero();
      if (s.prev_angles_ns != 0 && d.source_time_ns > s.prev_angles_ns) {
        rates = (mcp - s.prev_angles) /
                (static_cast<double>(d.source_time_ns - s.prev_angles_ns) * 1e-9);
      }
      s.prev_angles = mcp;
      s.prev_angles_ns = d.source_time_ns;
      tau = s.model.passiveTorqueNm(mcp, rates);
    } else {
      // The authoritative hand: its angles, torques, bones, spheres and contacts.
      const sim::HandSim& hs = *s.sim;
      h.source = telehand_msg_HAND_SOURCE_BULLET;
      mcp = hs.mcpAngles();
      tau = hs.mcpPassiveTorque();
      const auto dofs = hs.jointAngles();
      h.dof_count = static_cast<uint16_t>(std::min<std::size_t>(dofs.size(), 32));
      for (std::size_t i = 0; i < h.dof_count; ++i) h.joint_angles_rad[i] = dofs[i];
      const auto& bones = hs.model().bones();
      const sim::Pose to_device = hs.deviceToWorld().inverse();
      h.bone_count = static_cast<uint16_t>(std::min<std::size_t>(bones.size(), 24));
      for (std::size_t b = 0; b < h.bone_count; ++b) {
        const sim::Pose pose = to_device * hs.bonePose(static_cast<int>(b));
        const Quat q(pose.linear());
        const double v[7] = {pose.translation().x(), pose.translation().y(), pose.translation().z(),
                             q.w(), q.x(), q.y(), q.z()};
        for (int i = 0; i < 7; ++i) h.bone_pose[b][i] = v[i];
      }
      const auto spheres = hs.spherePositionsDevice();
      const auto contact = hs.contactForcesDevice();
      for (int k = 0; k < 2; ++k) {
        for (int i = 0; i < 3; ++i) {
          h.sphere_m[k][i] = spheres[k][i];
          h.contact_force_n[k][i] = contact[k][i];
        }
      }
    }
    Vec3 applied = Vec3::Zero();
    for (int k = 0; k < 2; ++k) {
      const auto& f = d.fingers[k];
      const Quat q(f.orientation_q[0], f.orientation_q[1], f.orientation_q[2], f.orientation_q[3]);
      const Vec3 fv = thimbleForceVector({f.tangential_n, f.normal_n}, q);
      applied += fv;
      for (int i = 0; i < 3; ++i) {
        h.fingertip_m[k][i] = p[k][i];
        h.fingertip_force_n[k][i] = fv[i];
      }
    }
    for (int i = 0; i < 3; ++i) {
      h.mcp_angles_rad[i] = mcp[i];
      h.mcp_torque_nm[i] = tau[i];
    }
    h.applied_force_ref_n = static_cast<float>(applied.norm() / s.params.force_scale);
  }
  if (!s.hand_deadband.admit(h, now_ns)) {
    ++s.hand_withheld;
    return;
  }
  h.seq = s.hand_seq++;  // viewers see consecutive numbers for what they get
  out_.publish(h);
}

void SessionManager::tick(int64_t now_ns) {
  const int64_t hand_period = static_cast<int64_t>(1e9 / config_.hand_state_hz);
  std::vector<uint64_t> done;
  for (auto& [id, s] : sessions_) {
    if (now_ns - s.rate_window_ns >= kNsPerS / 2) {
      s.rate_hz = static_cast<float>(static_cast<double>(s.live_count - s.rate_window_count) /
                                     (static_cast<double>(now_ns - s.rate_window_ns) * 1e-9));
      s.rate_window_ns = now_ns;
      s.rate_window_count = s.live_count;
    }
    if (now_ns >= s.next_hand_ns) {
      publishHand(s, now_ns);
      s.next_hand_ns += hand_period;
      if (s.next_hand_ns < now_ns) s.next_hand_ns = now_ns + hand_period;
    }
    if (!s.pending.empty()) store(s, {}, {});
    if (s.refit && !s.closing) refit(s, now_ns);
    if (s.patient.recovers && now_ns >= s.next_recovery_check_ns) {
      s.next_recovery_check_ns = now_ns + kNsPerS;
      recover(s, now_ns);
    }
    if (s.closing && ((s.recorded >= s.expected && s.pending.empty()) || now_ns >= s.close_deadline_ns)) {
      done.push_back(id);
    } else if (!s.closing && now_ns - s.last_data_ns > kIdleTimeoutNs) {
      s.expected = s.have_live ? s.last.seq + 1 : 0;
      event(id, s.client_id, telehand_msg_EVENT_ERROR,
            "no data for " + std::to_string(kIdleTimeoutNs / kNsPerS) + " s: closed as abandoned",
            now_ns);
      finish(s, now_ns, "abandoned");
      done.push_back(id);
      continue;
    }
  }
  for (uint64_t id : done) {
    auto it = sessions_.find(id);
    if (it == sessions_.end()) continue;
    Session& s = it->second;
    if (s.closing) finish(s, now_ns, s.recorded >= s.expected ? "closed" : "incomplete");
    sessions_.erase(it);
  }
}

void SessionManager::recover(Session& s, int64_t now_ns) {
  JointModelParams next = s.patient.at(s.treatment_s);
  double grown = 0.0;
  for (std::size_t i = 0; i < kAxes; ++i) {
    grown = std::max({grown, s.params.axes[i].min_deg - next.axes[i].min_deg,
                      next.axes[i].max_deg - s.params.axes[i].max_deg});
  }
  if (grown < kRecoveryStepDeg) return;  // not a change anyone would feel
  adoptModel(s, next);
  char text[160];
  std::snprintf(text, sizeof text, "recovery: after %.0f s of treatment, flexion range %.1f..%.1f deg (model v%u)",
                s.treatment_s, s.params.axes[kFlexion].min_deg, s.params.axes[kFlexion].max_deg,
                s.params.version);
  event(s.info.id, 0, telehand_msg_EVENT_INFO, text, now_ns);
}

void SessionManager::endExploration(Session& s, int64_t now_ns) {
  if (!s.exploration.active()) return;
  const std::string phase = s.exploration.phase();
  const auto reached = s.exploration.finish();
  if (reached.empty()) return;
  for (const auto& r : reached) {
    try {
      store_.appendReach(s.info.id, r);
    } catch (const StoreError& e) {
      ++stats_.store_errors;
      spdlog::error("session {}: {}", s.info.id, e.what());
    }
  }
  const bool baseline = phase == "baseline";
  event(s.info.id, s.client_id, telehand_msg_EVENT_SCORE,
        phase + ": " + Exploration::summary(reached, baseline ? decltype(s.baseline){} : s.baseline),
        now_ns);
  if (baseline) s.baseline = reached;
}

void SessionManager::finish(Session& s, int64_t now_ns, const std::string& state) {
  endExploration(s, now_ns);
  if (s.follows) {
    auto it = sessions_.find(s.follows);
    if (it != sessions_.end()) std::erase(it->second.followers, s.info.id);
  }
  for (uint64_t id : s.followers) {
    auto it = sessions_.find(id);
    if (it != sessions_.end()) it->second.follows = 0;  // keeps the last model it got
  }
  s.followers.clear();
  {
    // The link's packet rates, into the record.
    const double secs = std::max(static_cast<double>(now_ns - s.opened_ns) * 1e-9, 1e-3);
    char text[240];
    std::snprintf(text, sizeof text,
                  "link: DeviceState %.1f packets/s received live (%s), HandState %.1f/s "
                  "published (%llu withheld by the deadband)%s",
                  static_cast<double>(s.live_count) / secs,
                  s.deadband_coded ? "deadband-coded" : "every sample",
                  static_cast<double>(s.hand_seq) / secs,
                  static_cast<unsigned long long>(s.hand_withheld),
                  s.direct ? (", DirectForce " +
                              std::to_string(static_cast<long long>(
                                  std::llround(static_cast<double>(s.direct_sent) / secs))) +
                              "/s sent").c_str()
                           : "");
    event(s.info.id, s.client_id, telehand_msg_EVENT_INFO, text, now_ns);
  }
  try {
    store_.closeSession(s.info.id, wallNs(), s.expected, state);
  } catch (const StoreError& e) {
    ++stats_.store_errors;
    spdlog::error("session {}: {}", s.info.id, e.what());
  }
  const uint64_t missing = s.expected > s.recorded ? s.expected - s.recorded : 0;
  event(s.info.id, s.client_id, missing ? telehand_msg_EVENT_ERROR : telehand_msg_EVENT_INFO,
        state + ": " + std::to_string(s.recorded) + " samples recorded" +
            (missing ? ", " + std::to_string(missing) + " missing" : "") +
            (s.nonfinite ? ", " + std::to_string(s.nonfinite) + " non-finite live samples ignored" : ""),
        now_ns);
  publishStatus(s, telehand_msg_SESSION_CLOSED, now_ns);
}

void SessionManager::closeAll(int64_t now_ns) {
  for (auto& [id, s] : sessions_) {
    if (!s.pending.empty()) store(s, {}, {});
    if (!s.closing) s.expected = s.have_live ? s.last.seq + 1 : s.recorded;
    finish(s, now_ns, s.closing ? (s.recorded >= s.expected ? "closed" : "incomplete") : "interrupted");
  }
  sessions_.clear();
}

}  // namespace telehand::server::session
