#pragma once
/// A long-running server's memory after a burst of sessions: glibc keeps, per thread, up to
/// 7 freed blocks of each small size class (its tcache, 64 classes up to 1 KiB) to reuse
/// without a lock. Those blocks stay where the burst put them, scattered through a heap the
/// burst grew, and each holds its page resident: after a churn of 9,000 sessions the
/// serving and writer threads' caches held 330 blocks on 230 pages, about 1 MB of a 17 MB
/// server (docs/security.md "Memory"). glibc reads its tunables only from the environment
/// at start, so a program that wants the cache off runs itself again with it set.
#include <optional>
#include <string>

namespace telehand::app {

/// The tunable that turns glibc's per-thread cache off.
inline constexpr const char* kNoThreadCacheTunable = "glibc.malloc.tcache_count=0";

/// GLIBC_TUNABLES with the per-thread cache off, given its current value (null: unset), or
/// nullopt when it already sets the cache's size (the operator's choice stands).
std::optional<std::string> tunablesWithoutThreadCache(const char* current);

/// Runs this program again (same PID, same arguments) with glibc's per-thread cache off,
/// unless GLIBC_TUNABLES already sets its size. Call first in main, before any thread
/// starts. Returns only when it did not run again: the cache was already set, or the
/// re-execution failed (then a warning names why on stderr, and the program goes on as is).
void runWithoutMallocThreadCache(char** argv);

}  // namespace telehand::app
