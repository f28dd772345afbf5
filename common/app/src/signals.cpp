#include "telehand/app/signals.h"

#include <csignal>

namespace telehand {

static_assert(std::atomic<bool>::is_always_lock_free, "set from a signal handler");

void installStopSignals(bool restart_syscalls) {
  struct sigaction sa {};
  sa.sa_handler = [](int) { g_stop_requested.store(true); };
  sigemptyset(&sa.sa_mask);
  sa.sa_flags = restart_syscalls ? SA_RESTART : 0;
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);
}

}  // namespace telehand
