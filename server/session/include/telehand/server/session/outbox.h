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
};

}  // namespace telehand::server::session
