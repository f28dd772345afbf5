#include "telehand/server/session/hand_runner.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <span>

#include "telehand/core/clock.h"
#include "telehand/core/error.h"
#include "telehand/core/technique_score.h"
#include "telehand/core/thimble.h"
#include "telehand/protocol/wire.h"
#include "telehand/server/session/hand_heap.h"
#include "telehand/server/session/session_manager.h"

namespace telehand::server::session {

HandRunner::HandRunner(uint64_t session_id, const sim::HandModel* hand,
                       const JointModelParams& params, const sim::HandSimConfig& hand_config,
                       double hand_deadband_weber, int64_t now_ns)
    : session_id_(session_id),
      next_hand_ns_(now_ns),
      hand_deadband_(DeadbandConfig{hand_deadband_weber}) {
  if (hand) {
    sim_ = buildOnHandHeap<sim::HandSim>(
        [&] { return std::make_unique<sim::HandSim>(*hand, params, hand_config); });
  }
  if (params.technique == Technique::kMassage)
    web_ = std::make_unique<sim::WebSim>(params.tissue, params.force_scale);
}

void HandRunner::setModel(const JointModelParams& params) {
  if (sim_) sim_->setMcpModel(params);
  if (params.technique != Technique::kMassage) return;
  if (web_) {
    web_->setParams(params.tissue, params.force_scale);
  } else {
    web_ = std::make_unique<sim::WebSim>(params.tissue, params.force_scale);
  }
}

HandRunner::~HandRunner() {
  // Freed on the thread that built it, its blocks go back to that thread's arena rather
  // than into this thread's cache of free blocks, whence later long-lived allocations of the
  // serving thread would be taken from among the hands' pages.
  if (sim_) onHandHeap([&] { sim_.reset(); });
}

namespace {
/// The joint's rest angle on each axis, where exploration's directions start.
Vec3 restAngles(const JointModel& model) {
  return {model.restAngleRad(kFlexion), model.restAngleRad(kAbduction), model.restAngleRad(kAxial)};
}
}  // namespace

void observeHand(Exploration& exploration, const sim::HandSim& hand, const JointModel& model,
                 double min_grip_n) {
  if (!exploration.active()) return;
  const auto f = hand.contactForcesDevice();
  const Vec3 angles = hand.mcpAngles();
  // The force at the reach is what holds the joint there: the joint torque the pads exert on
  // each axis (the generalized torque conjugate to that angle, which the joint model's curves
  // give per axis) as a force at the lever arm. The squeeze cancels out, and the other axes'
  // torques are no part of this direction's force.
  const Vec3 axis_force_n =
      model.axisTorque(hand.contactPointsDevice(), angles, {Vec3(-f[0]), Vec3(-f[1])}) /
      model.params().lever_arm_m;
  // Held: both pads press the phalanx (a finger the pads let go swings to rest by itself).
  const bool held = f[0].norm() >= min_grip_n && f[1].norm() >= min_grip_n;
  exploration.observe(angles, restAngles(model), axis_force_n, held);
}

void HandRunner::step(const JointModel& model) {
  sim_->step();
  observeHand(exploration_, *sim_, model, drift_.options().min_grip_n);
  const auto f = sim_->contactForcesDevice();
  if (f[0].norm() + f[1].norm() > 1.0) treatment_s_ += 1e-3;
}

void HandRunner::stepWeb(const Sample& d, const PerFinger<Vec3>& grip, uint64_t steps, bool coded,
                         const JointModel& model) {
  if (!web_) return;
  // The web steps as the client's proxy did: once per sample at its time; samples lost on
  // the way are stepped on a straight line between the two received (withheld ones of a
  // deadband-coded stream on the last received), as the hand. It is cheap and it is what the
  // checkpoint and HandState carry, so it steps with every live sample, never deferred.
  steps = std::max<uint64_t>(steps, 1);
  if (have_web_last_ && steps > 1) {
    const PerFinger<Vec3> from = thimblePositions(web_last_);
    const int64_t t0 = web_last_.source_time_ns;
    for (uint64_t i = 1; i < steps; ++i) {
      const double w = coded ? 0.0 : static_cast<double>(i) / static_cast<double>(steps);
      const int64_t t =
          t0 + static_cast<int64_t>(static_cast<double>(d.source_time_ns - t0) *
                                    static_cast<double>(i) / static_cast<double>(steps));
      web_->step({from[0] + w * (grip[0] - from[0]), from[1] + w * (grip[1] - from[1])}, t);
    }
  }
  web_->step(grip, d.source_time_ns);
  web_last_ = d;
  have_web_last_ = true;
  // Across a gap the web stepped the straight line, not the client's path: its velocity
  // filter remembers another depth rate, and its skin sticks and slips at other ticks than
  // the client's from then on (a stick-slip sawtooth out of phase: the web force 13-52 %
  // off at the worst HandState on the spain-australia and extreme links, docs/massage.md
  // "The server"). The sample carries the force the client's proxy rendered: wherever the
  // two differ, the depth rate and the skin's stretch are taken from it within the model's
  // bounds (WebSim::resync), as the drift corrector takes the hand back for the joint. On
  // samples stepped in order the two agree and nothing changes. Only for the model the
  // client rendered, and not while its model fades.
  if (d.model_version == model.params().version && (d.flags & sample_flags::kModelBlending) == 0) {
    PerFinger<Vec3> force;
    PerFinger<double> depth;
    for (std::size_t k = 0; k < 2; ++k) {
      const auto& f = d.fingers[k];
      force[k] = Vec3(f.tissue_force_n[0], f.tissue_force_n[1], f.tissue_force_n[2]);
      depth[k] = f.contact_depth_m;
    }
    if (web_->resync(force, depth) > 0) ++web_resyncs_;
  }
}

bool HandRunner::advance(SessionContext& ctx, const Sample& d, const PerFinger<Vec3>& grip,
                         uint64_t steps, bool coded, const JointModel& model,
                         telehand_msg_SessionMode mode, Vec3* before) {
  // The simulation runs on device time: one 1 ms step per sample, and one per sample lost
  // on the way, with the thimbles moving in a straight line across the gap (jumping the pads
  // to the new sample would kick the finger and leave the hand lagging the thimbles). An
  // overloaded server must not try to catch up on every lost millisecond (each catch-up
  // would fall further behind): past kMaxCatchUpSteps the hand skips time and the gap shows
  // in HandState.device_lost. A deadband-coded stream withholds samples on purpose: those
  // steps run on the last state received.
  if (!have_last_) {
    // The first sample: the student takes hold of the finger where their fingers are. The
    // hand's MCP starts there (inside its range), not at the model's neutral pose: pads
    // closing on a phalanx that is still swinging from neutral to rest (or flexed 45 deg
    // away, for a stiff joint) grip it off the thimbles' line, and the hand would stay that
    // far from the script (3.4 deg of abduction measured on the healthy joint).
    Vec3 start = model.anglesFromGrip(grip);
    for (int i = 0; i < kAxes; ++i) {
      const CubicCurve& c = model.params().axes[static_cast<std::size_t>(i)];
      start[i] = std::clamp(start[i], degToRad(c.min_deg), degToRad(c.max_deg));
    }
    if (allFinite(start)) sim_->resetMcp(start);
    steps = 1;
  }
  steps = std::max<uint64_t>(steps, 1);
  if (have_last_ && steps > 1) {
    const bool hold = coded;
    const PerFinger<Vec3> from = thimblePositions(last_), &to = grip;
    for (uint64_t i = 1; i < steps; ++i) {
      const double w = hold ? 0.0 : static_cast<double>(i) / static_cast<double>(steps);
      sim_->setFingerTargets({from[0] + w * (to[0] - from[0]), from[1] + w * (to[1] - from[1])},
                             true);
      step(model);
    }
  }
  sim_->setFingerTargets(grip, true);
  step(model);
  ctx.stats.hand_steps += steps;
  last_ = d;
  have_last_ = true;
  // On device time, like the steps: the hand is a function of the samples alone (a replay of
  // the record reproduces it, docs/lessons.md "Watch").
  return correctDrift(ctx, grip, model, mode, static_cast<double>(steps) * 1e-3, d.source_time_ns,
                      before);
}

void HandRunner::observeGrip(const PerFinger<Vec3>& grip, const JointModel& model) {
  if (sim_ || !exploration_.active()) return;
  // No hand: the thimbles set the angles and the joint model gives the force holding them.
  const Vec3 angles = model.anglesFromGrip(grip);
  Vec3 holding_n;
  for (int i = 0; i < kAxes; ++i) holding_n[i] = model.holdingForceN(i, angles[i]);
  exploration_.observe(angles, restAngles(model), holding_n, true);
}

bool HandRunner::correctDrift(SessionContext& ctx, const PerFinger<Vec3>& grip,
                              const JointModel& model, telehand_msg_SessionMode mode, double dt_s,
                              int64_t now_ns, Vec3* before) {
  // A capture renders nothing (the actuators are off): there is no proxy to correct; a
  // massage renders the web, not the joint.
  if (!ctx.config.drift_correction || mode == telehand_msg_MODE_CAPTURE || web_) return false;
  const auto pads = sim_->contactForcesDevice();
  const double min_grip = drift_.options().min_grip_n;
  const bool held = pads[0].norm() >= min_grip && pads[1].norm() >= min_grip;
  Vec3 proxy = model.proxyAngles(grip);
  // Past a range end the proxy renders the end-of-range wall while the hand rests on its
  // hard limit: that gap is the wall's give, which the student must feel, not drift.
  for (std::size_t i = 0; i < kAxes; ++i) {
    const auto& axis = model.params().axes[i];
    proxy[static_cast<int>(i)] =
        std::clamp(proxy[static_cast<int>(i)], degToRad(axis.min_deg), degToRad(axis.max_deg));
  }
  *before = drift_.offset();
  return drift_.observe(sim_->mcpAngles(), proxy, held, dt_s, now_ns);
}

void HandRunner::reportDrift(SessionContext& ctx, const Vec3& before, uint32_t version,
                             int64_t now_ns) {
  const Vec3 change_deg = radToDeg(1.0) * (drift_.offset() - before);
  spdlog::debug("session {}: drift correction v{}: {:.2f} {:.2f} {:.2f} deg", session_id_, version,
                change_deg[0], change_deg[1], change_deg[2]);
  // A slip anyone would notice goes in the record and to the supervisors.
  if (change_deg.cwiseAbs().maxCoeff() >= SessionManager::kDriftEventDeg) {
    const Vec3 total = radToDeg(1.0) * drift_.offset();
    char text[200];
    std::snprintf(text, sizeof text,
                  "grip slipped: the hand is %+.1f/%+.1f/%+.1f deg (flexion/abduction/axial) from "
                  "the thimbles; the proxy follows it (model v%u)",
                  total[0], total[1], total[2], version);
    ctx.event(session_id_, 0, telehand_msg_EVENT_INFO, text, now_ns);
  }
}

void HandRunner::publishDue(SessionContext& ctx, const LiveStream& live, const JointModel& model,
                            int64_t now_ns) {
  if (now_ns < next_hand_ns_) return;
  const int64_t hand_period = static_cast<int64_t>(1e9 / ctx.config.hand_state_hz);
  publish(ctx, live, model, now_ns);
  next_hand_ns_ += hand_period;
  if (next_hand_ns_ < now_ns) next_hand_ns_ = now_ns + hand_period;
}

void HandRunner::publish(SessionContext& ctx, const LiveStream& live, const JointModel& model,
                         int64_t now_ns) {
  const JointModelParams& params = model.params();
  HandStateFields hf;
  hf.session_id = session_id_;
  hf.source_time_ns = wallNs();
  hf.device_rate_hz = live.rateHz();
  hf.device_lost = live.lost();
  hf.device_overruns = live.overruns();
  hf.model_version = params.version;
  // The Bullet hand shows the sample it stepped to last (behind the live stream while the
  // hand's steps wait for their turn, SessionManager::setHandSlice).
  const Sample* shown = sim_ && have_last_ ? &last_ : live.have() ? &live.last() : nullptr;
  if (shown) {
    const auto& d = *shown;
    hf.have_device = true;
    hf.device_seq = d.seq;
    hf.device_time_ns = d.source_time_ns;
    const PerFinger<Vec3> p = thimblePositions(d);
    if (!sim_) {
      // No hand: the shared joint model at the thimbles, rates from successive states.
      const Vec3 mcp = model.anglesFromGrip(p);
      Vec3 rates = Vec3::Zero();
      if (prev_angles_ns_ != 0 && d.source_time_ns > prev_angles_ns_) {
        rates =
            (mcp - prev_angles_) / (static_cast<double>(d.source_time_ns - prev_angles_ns_) * 1e-9);
      }
      prev_angles_ = mcp;
      prev_angles_ns_ = d.source_time_ns;
      hf.mcp_angles_rad = mcp;
      hf.mcp_torque_nm = model.passiveTorqueNm(mcp, rates);
    } else {
      // The authoritative hand: its angles, torques, bones, spheres and contacts.
      const sim::HandSim& hs = *sim_;
      hf.bullet = true;
      hf.mcp_angles_rad = hs.mcpAngles();
      hf.mcp_torque_nm = hs.mcpPassiveTorque();
      hf.joint_angles_rad = hs.jointAngles();
      const std::size_t bones = std::min<std::size_t>(hs.model().bones().size(), 24);
      const sim::Pose to_device = hs.deviceToWorld().inverse();
      hf.bone_poses.resize(bones);
      for (std::size_t b = 0; b < bones; ++b) {
        const sim::Pose pose = to_device * hs.bonePose(static_cast<int>(b));
        hf.bone_poses[b] = {pose.translation(), Quat(pose.linear())};
      }
      hf.sphere_m = hs.spherePositionsDevice();
      hf.contact_force_n = hs.contactForcesDevice();
    }
    for (std::size_t k = 0; k < 2; ++k) {
      const auto& f = d.fingers[k];
      const Quat q(f.orientation_q[0], f.orientation_q[1], f.orientation_q[2], f.orientation_q[3]);
      hf.fingertip_m[k] = p[k];
      hf.fingertip_force_n[k] = thimbleForceVector({f.tangential_n, f.normal_n}, q);
    }
    if (web_) {
      hf.massage = true;
      const TissueOutput& w = web_->last();
      for (std::size_t k = 0; k < 2; ++k) {
        hf.web_depth_m[k] = w.contact[k].depth_m;
        hf.web_force_n[k] = w.contact[k].force();
      }
      hf.web_grid_m = web_->grid();
    }
    // The same figure the lessons score (technique::appliedForceRefN).
    hf.applied_force_ref_n = static_cast<float>(technique::appliedForceRefN(d, params.force_scale));
  }
  telehand_msg_HandState h;
  toWire(hf, h);
  if (!hand_deadband_.admit(h, now_ns)) {
    ++hand_withheld_;
    return;
  }
  h.seq = hand_seq_++;  // viewers see consecutive numbers for what they get
  ctx.out.publish(h);
}

void HandRunner::endExploration(SessionContext& ctx, uint64_t client_id, int64_t now_ns,
                                uint64_t stepped_over) {
  if (!exploration_.active()) return;
  const std::string phase = exploration_.phase();
  // Only the directions reached are stored: one never explored has no row (not a 0 deg reach)
  // and the score says it was not reached.
  const auto reached = exploration_.finish();
  for (const auto& r : reached) {
    try {
      ctx.store.appendReach(session_id_, r);
    } catch (const StoreError& e) {
      ++ctx.stats.store_errors;
      spdlog::error("session {}: {}", session_id_, e.what());
    }
  }
  const bool baseline = phase == "baseline";
  std::string text =
      phase + ": " + Exploration::summary(reached, baseline ? decltype(baseline_){} : baseline_);
  if (stepped_over > 0) {
    text += " (the hand stepped over " + std::to_string(stepped_over) +
            " of the phase's live samples, the server short of CPU: a reach among them is "
            "not in this score)";
  }
  ctx.event(session_id_, client_id, telehand_msg_EVENT_SCORE, text, now_ns);
  if (baseline) baseline_ = reached;
}

std::string HandRunner::checkpoint() const {
  if (!sim_) return {};
  std::vector<double> v = {static_cast<double>(hand_seq_), treatment_s_};
  const std::vector<double> state = sim_->saveState();
  v.insert(v.end(), state.begin(), state.end());
  if (web_) {
    // A massage's web after the hand (WebSim::saveState, its own magic number first).
    const std::vector<double> web = web_->saveState();
    v.insert(v.end(), web.begin(), web.end());
  }
  return {reinterpret_cast<const char*>(v.data()), v.size() * sizeof(double)};
}

bool HandRunner::restore(const std::string& data) {
  if (!sim_ || data.size() % sizeof(double) != 0 || data.size() < 3 * sizeof(double)) return false;
  std::vector<double> v(data.size() / sizeof(double));
  std::memcpy(v.data(), data.data(), data.size());
  if (!std::isfinite(v[0]) || v[0] < 0.0 || v[0] > 9007199254740992.0 || !std::isfinite(v[1]))
    return false;
  // The hand's part is as long as this hand's own state; what follows it is the web's. A
  // checkpoint with nothing after the hand (from before the web was kept) restores the hand
  // and leaves the web to start afresh.
  const std::size_t hand_size = sim_->saveState().size();
  if (v.size() < 2 + hand_size) return false;
  const std::span<const double> web_part = std::span<const double>(v).subspan(2 + hand_size);
  std::optional<sim::WebSim> web;
  if (!web_part.empty()) {
    if (!web_) return false;  // a web for a session without one
    web.emplace(*web_);
    if (!web->restoreState(web_part)) return false;
  }
  if (!sim_->restoreState(std::vector<double>(
          v.begin() + 2, v.begin() + 2 + static_cast<std::ptrdiff_t>(hand_size))))
    return false;
  if (web) *web_ = *web;
  hand_seq_ = std::max(hand_seq_, static_cast<uint64_t>(v[0]));
  treatment_s_ = v[1];
  return true;
}

}  // namespace telehand::server::session
