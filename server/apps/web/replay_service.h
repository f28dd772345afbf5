#pragma once
/// The gateway's replays' hands (docs/web.md "How it works"): each computed on the thread of
/// the browser that asked (replay_hand.h), a bounded number at once, sent in chunks of frames
/// as it goes, and kept in a cache for the next browser that replays the same record.
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>

#include "replay_cache.h"
#include "replay_hand.h"
#include "telehand/server/sim/hand_model.h"

namespace telehand::web {

class ReplayHandService {
 public:
  /// `jobs`: hands computed at once (each takes a core); `cache_bytes`: hands kept.
  ReplayHandService(std::string db, const server::sim::HandModel& hand,
                    const ReplayHandOptions& options, std::size_t jobs, std::size_t cache_bytes);

  /// Sends session `session`'s hand through `push`: {"type":"replay_hand",...} chunks (or one
  /// saying it is queued), then {"type":"replay_hand_end",...}; nothing more once `stopped()`
  /// (asked between frames and while it waits its turn). Never throws.
  void run(uint64_t session, const std::function<void(std::string)>& push,
           const std::function<bool()>& stopped);
  /// Wakes those waiting their turn to look at `stopped()` again.
  void wake() { jobs_cv_.notify_all(); }

  std::atomic<uint64_t> hands{0};   ///< computed (to their end or a bound)
  std::atomic<uint64_t> frames{0};  ///< frames those sent
  std::atomic<uint64_t> cached{0};  ///< sent from the cache

 private:
  std::string db_;
  const server::sim::HandModel& hand_;
  ReplayHandOptions options_;
  std::size_t jobs_;
  ReplayHandCache cache_;
  std::mutex jobs_mutex_;
  std::condition_variable jobs_cv_;
  std::size_t running_ = 0;
};

}  // namespace telehand::web
