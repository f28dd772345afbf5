#pragma once
/// What every part of a session reports to and through: the record, the outbox, the
/// server's configuration and counters, and the manager's events.
#include <cstdint>
#include <functional>
#include <string>

#include "telehand.h"
#include "telehand/config/config.h"
#include "telehand/server/session/outbox.h"
#include "telehand/server/store/store.h"

namespace telehand::server::session {

struct SessionContext {
  store::SessionStore& store;
  Outbox& out;
  const ServerConfig& config;
  ManagerStats& stats;
  /// An event into the session's record and to its clients (session 0: to nobody's record).
  std::function<void(uint64_t session_id, uint64_t client_id, telehand_msg_EventKind kind,
                     const std::string& text, int64_t now_ns)>
      event;
  /// Samples go to the record on a writer thread of the manager's (BatchWriter), not at a
  /// session's tick.
  bool samples_on_writer = false;
};

}  // namespace telehand::server::session
