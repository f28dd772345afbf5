#pragma once
/// Where the session manager's messages go, and what it counts.
#include <cstdint>

#include "telehand.h"

namespace telehand::server::session {

/// Where the manager's messages go (the DDS link in the server, a recorder in tests).
class Outbox {
 public:
  virtual ~Outbox() = default;
  virtual void publish(const telehand_msg_SessionStatus& s) = 0;
  virtual void publish(const telehand_msg_JointModel& m) = 0;
  virtual void publish(const telehand_msg_HandState& h) = 0;
  virtual void publish(const telehand_msg_SessionEvent& e) = 0;
  /// The samples behind a data-driven JointModel of the same session and version.
  virtual void publish(const telehand_msg_KnnModel& k) { (void)k; }
  /// Direct mode only (the baseline design).
  virtual void publish(const telehand_msg_DirectForce& f) { (void)f; }
  /// An ended session leaves every keyed topic (SessionStatus, JointModel, KnnModel,
  /// SessionEvent, HandState, DirectForce): late joiners no longer receive it and the
  /// writers free its instances.
  virtual void retire(uint64_t session_id) { (void)session_id; }
  /// No session is open or waiting to be retired: what the link keeps for reuse (Cyclone's
  /// pool of freed samples, its writer histories' spare nodes) can be given back.
  virtual void idle() {}
  /// Half a second after idle(), still with no session: what came back for reuse since (what
  /// idle() freed through Cyclone's garbage collector) is given back too.
  virtual void settle() {}
};

struct ManagerStats {
  uint64_t live_samples = 0;
  uint64_t recorded_samples = 0;
  uint64_t nonfinite_samples = 0;
  uint64_t unknown_session_samples = 0;
  uint64_t bad_commands = 0;
  uint64_t store_errors = 0;
  uint64_t live_models = 0;           ///< JointModels published by live refits (captures)
  int64_t last_refit_latency_ns = 0;  ///< newest sample's arrival -> its model published
  int64_t max_refit_latency_ns = 0;
  uint64_t drift_corrections = 0;  ///< JointModels published to correct drift (all sessions)
  /// Messages refused because their sender does not own the session, or outside a bound
  /// (sequence window, file limits, session limits): each is also a security event.
  uint64_t refused = 0;
  uint64_t retired_sessions = 0;  ///< ended sessions taken off the transient-local topics
  /// Bullet steps of the sessions' hands (one per millisecond of device time followed).
  uint64_t hand_steps = 0;
  /// Live samples a deferred hand did not step to: thinned out of a session's full queue
  /// when the hands had less CPU than they needed (SessionManager::setHandSlice).
  uint64_t hand_samples_skipped = 0;
};

}  // namespace telehand::server::session
