#pragma once
/// Whether a pool server's serve loop still gets on (docs/pool.md "Ownership"): the lease is
/// renewed on a thread of its own so that a loop held up for a moment keeps its sessions, but
/// a loop that has handled nothing for a while is wedged, and its sessions belong elsewhere.
#include <cstdint>

namespace telehand::server::session {

class ServeWatch {
 public:
  /// `stall_ns`: how long the loop may handle nothing before it counts as wedged.
  explicit ServeWatch(int64_t stall_ns) : stall_ns_(stall_ns) {}
  /// `progress`: the loop's counter (SessionManager::progress()) read at `now_ns`. True while
  /// it has grown within `stall_ns` of now (the first call starts the watch).
  bool alive(uint64_t progress, int64_t now_ns) {
    if (!started_ || progress != progress_) {
      started_ = true;
      progress_ = progress;
      since_ns_ = now_ns;
    }
    return now_ns - since_ns_ <= stall_ns_;
  }
  /// How long the counter has stood still, as of `now_ns`.
  int64_t idleNs(int64_t now_ns) const { return started_ ? now_ns - since_ns_ : 0; }

 private:
  int64_t stall_ns_;
  bool started_ = false;
  uint64_t progress_ = 0;
  int64_t since_ns_ = 0;
};

}  // namespace telehand::server::session
