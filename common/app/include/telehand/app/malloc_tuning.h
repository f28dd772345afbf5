#pragma once
/// A long-running server's memory after a burst of sessions: glibc keeps, per thread, up to
/// 7 freed blocks of each small size class (its tcache, 64 classes up to 1 KiB) to reuse
/// without a lock. Those blocks stay where the burst put them, scattered through a heap the
/// burst grew, and each holds its page resident: after a churn of 9,000 sessions the
/// serving and writer threads' caches held 330 blocks on 230 pages, about 1 MB of a 17 MB
/// server (docs/security.md "Memory"). glibc reads its tunables only from the environment
/// at start, so a program that wants the cache off runs itself again with it set.
#include <cstddef>
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

/// glibc serves a block of at least this size from a mapping of its own, given back to the
/// system when the block is freed. Its default is the same size but moves: each such block
/// freed raises it (up to 32 MiB), and the large blocks of a burst's sessions (their hands,
/// their record buffers) then come from the heap the burst grows, and leave it fragmented
/// (after a churn of 9,000 sessions, +6.6 and +6.7 % RSS with it moving, +2.9 and +4.2 % with
/// it held, in one run each; docs/security.md "Memory").
inline constexpr std::size_t kMmapThresholdBytes = 128 * 1024;

/// Whether GLIBC_TUNABLES (its value, null: unset) sets glibc's mmap threshold itself.
bool tunablesSetMmapThreshold(const char* current);

/// Holds glibc's mmap threshold at kMmapThresholdBytes (mallopt), unless GLIBC_TUNABLES sets
/// it (the operator's choice stands). Returns whether it did.
bool holdMmapThreshold();

}  // namespace telehand::app
