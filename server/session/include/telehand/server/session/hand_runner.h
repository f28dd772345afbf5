#pragma once
/// A session's hand: the Bullet hand stepped on device time (catching up on lost samples,
/// holding on withheld ones), the exploration phases it is observed for, the drift between
/// it and the proxy, and the HandState it is published as.
#include <algorithm>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "telehand/core/joint_model.h"
#include "telehand/protocol/deadband.h"
#include "telehand/server/session/drift.h"
#include "telehand/server/session/exploration.h"
#include "telehand/server/session/live_stream.h"
#include "telehand/server/session/session_context.h"
#include "telehand/server/sim/hand_model.h"
#include "telehand/server/sim/hand_sim.h"
#include "telehand/server/sim/web_sim.h"

namespace telehand::server::session {

/// Observe one step of `hand` for `exploration` (if a phase is under way): the MCP angles, the
/// pads' joint torque per axis as a force at the lever arm, held when both pads press the
/// phalanx with at least `min_grip_n`.
void observeHand(Exploration& exploration, const sim::HandSim& hand, const JointModel& model,
                 double min_grip_n);

class HandRunner {
 public:
  /// With `hand`, the Bullet hand runs on `params`; without, HandState comes from the shared
  /// joint model.
  HandRunner(uint64_t session_id, const sim::HandModel* hand, const JointModelParams& params,
             const sim::HandSimConfig& hand_config, double hand_deadband_weber, int64_t now_ns);
  /// The hand is freed where it was built (hand_heap.h).
  ~HandRunner();
  HandRunner(const HandRunner&) = delete;
  HandRunner& operator=(const HandRunner&) = delete;

  bool simulated() const noexcept { return sim_ != nullptr; }
  /// The session adopted a new model.
  void setModel(const JointModelParams& params);
  /// A massage session's web (null otherwise).
  const sim::WebSim* web() const noexcept { return web_.get(); }

  /// A massage's web steps to a finite live sample newer than the last it stepped to
  /// (`steps` as for `advance`) and takes its state back from the force the client rendered.
  void stepWeb(const Sample& d, const PerFinger<Vec3>& grip, uint64_t steps, bool coded,
               const JointModel& model);
  /// Step the Bullet hand to a finite live sample newer than the last it stepped to:
  /// `steps` 1 ms steps (itself and the samples lost or withheld before it, capped), the
  /// thimbles moving in a straight line from the last sample stepped to (held there when
  /// `coded`), and observe it. True when the drift corrector changed its offset (the session
  /// adopts it; `before` is the offset it had).
  bool advance(SessionContext& ctx, const Sample& d, const PerFinger<Vec3>& grip, uint64_t steps,
               bool coded, const JointModel& model, telehand_msg_SessionMode mode, Vec3* before);
  /// Without a Bullet hand: an exploration phase observes the joint model at the thimbles.
  void observeGrip(const PerFinger<Vec3>& grip, const JointModel& model);
  /// The newest sample the Bullet hand stepped to, if any.
  const Sample* lastStepped() const noexcept { return have_last_ ? &last_ : nullptr; }
  /// Report a drift correction just adopted as model `version`.
  void reportDrift(SessionContext& ctx, const Vec3& before, uint32_t version, int64_t now_ns);
  const DriftCorrector& drift() const noexcept { return drift_; }

  /// Publish the HandState if one is due at `now_ns`.
  void publishDue(SessionContext& ctx, const LiveStream& live, const JointModel& model,
                  int64_t now_ns);

  void beginExploration(const std::string& phase) { exploration_.begin(phase); }
  /// Score and store the exploration phase under way, if any. `stepped_over`: the phase's live
  /// samples the hand did not step to (Session::handSkipped), said with the score, since a
  /// reach the hand never saw is not in it.
  void endExploration(SessionContext& ctx, uint64_t client_id, int64_t now_ns,
                      uint64_t stepped_over = 0);

  /// The hand's state as a checkpoint (docs/pool.md): the Bullet hand's bodies, grips and
  /// time, the HandState numbering and the treatment time, and a massage's web (its skin's
  /// anchors, velocity filter, model fade, surface), as bytes ('' without a hand).
  std::string checkpoint() const;
  /// Go on from a checkpoint() of a hand of the same model; false (nothing changed, neither
  /// the hand nor the web) when it does not fit. A checkpoint without a web (written before
  /// the web was kept) restores the hand and leaves a massage's web as it is.
  bool restore(const std::string& data);
  /// Samples on which the web took a finger's depth rate and skin stretch from the client's
  /// recorded force (WebSim::resync): after gaps, until the two agree again.
  uint64_t webResyncs() const noexcept { return web_resyncs_; }

  /// Time the pads pressed the joint (recovery).
  double treatmentS() const noexcept { return treatment_s_; }
  uint64_t published() const noexcept { return hand_seq_; }
  /// Number the next HandState `next`: a session whose HandState comes from elsewhere for a
  /// while (a lesson's replay) keeps one sequence for its viewers.
  void continueSeq(uint64_t next) noexcept { hand_seq_ = std::max(hand_seq_, next); }
  uint64_t withheld() const noexcept { return hand_withheld_; }

 private:
  /// One 1 ms step of the hand, observed for exploration and treatment time.
  void step(const JointModel& model);
  /// After a live sample stepped the hand: fold persistent drift into the model.
  bool correctDrift(SessionContext& ctx, const PerFinger<Vec3>& grip, const JointModel& model,
                    telehand_msg_SessionMode mode, double dt_s, int64_t now_ns, Vec3* before);
  void publish(SessionContext& ctx, const LiveStream& live, const JointModel& model,
               int64_t now_ns);

  uint64_t session_id_;
  std::unique_ptr<sim::HandSim> sim_;  // null: HandState from the shared joint model
  std::unique_ptr<sim::WebSim> web_;   // a massage's web, beside the hand
  double treatment_s_ = 0.0;
  Exploration exploration_;
  std::vector<store::SessionStore::Reach> baseline_;
  DriftCorrector drift_;  // hand against proxy (sessions with a hand)
  Vec3 prev_angles_ = Vec3::Zero();
  int64_t prev_angles_ns_ = 0;
  uint64_t hand_seq_ = 0;  // HandStates published so far
  int64_t next_hand_ns_ = 0;
  HandStateDeadband hand_deadband_;
  uint64_t hand_withheld_ = 0;
  uint64_t web_resyncs_ = 0;
  Sample last_{};  // the newest sample stepped to (have_last_)
  bool have_last_ = false;
  Sample web_last_{};  // the newest sample the web stepped to (have_web_last_)
  bool have_web_last_ = false;
};

}  // namespace telehand::server::session
