#pragma once
/// SIGINT and SIGTERM as a request to stop: programs finish their work (close the session,
/// flush the record, stop their children) instead of dying mid-write.
#include <atomic>

namespace telehand {

/// Set by SIGINT or SIGTERM once installStopSignals() has run.
inline std::atomic<bool> g_stop_requested{false};

/// Installs the handler for SIGINT and SIGTERM. With `restart_syscalls` (the default, as
/// std::signal does) an interrupted read or write resumes; without it, blocking calls return
/// EINTR so that a loop waiting in one sees the request at once.
void installStopSignals(bool restart_syscalls = true);

}  // namespace telehand
