#pragma once
/// Where sessions' hands are built. A Bullet hand is thousands of small blocks (bodies,
/// shapes, constraints); built on the serving thread they would share its malloc arena with
/// the server's long-lived small allocations (the record's SQLite pages, Cyclone's instances
/// and samples), and once a burst of sessions ended, those would pin the freed hands' pages
/// in memory: the server's RSS after 1,000 sessions came and went stayed ~8 MB above what it
/// was before. Built on a thread of their own, the hands keep to that thread's arena, which
/// malloc_trim hands back to the system whole once they are gone (docs/security.md, Bounds).
#include <functional>
#include <memory>

namespace telehand::server::session {

/// Runs `job` on the hand-building thread (started on first use, one per process) and waits
/// for it; an exception it throws is rethrown here.
void onHandHeap(const std::function<void()>& job);

/// `build()` (a std::unique_ptr<T>), run on the hand-building thread.
template <typename T, typename Fn>
std::unique_ptr<T> buildOnHandHeap(Fn&& build) {
  std::unique_ptr<T> out;
  onHandHeap([&] { out = build(); });
  return out;
}

}  // namespace telehand::server::session
