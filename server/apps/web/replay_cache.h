#pragma once
/// Replays' hands already computed (their replay_hand chunks as sent), the most recently used
/// first, bounded in bytes: the same record asked for again, by another tab or supervisor, is
/// sent at once instead of simulated again. A record is known by its session, sample count and
/// last sample number, so a session still being recorded is computed afresh.
#include <cstdint>
#include <list>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "replay_hand.h"

namespace telehand::web {

struct RecordKey {
  uint64_t session = 0, samples = 0, last_seq = 0;
  bool operator==(const RecordKey&) const = default;
};

struct ComputedHand {
  std::vector<std::string> chunks;  ///< {"type":"replay_hand",...} frames, in order
  ReplayHandResult result;
  std::size_t bytes = 0;
};

class ReplayHandCache {
 public:
  explicit ReplayHandCache(std::size_t max_bytes) : max_bytes_(max_bytes) {}

  std::shared_ptr<const ComputedHand> find(const RecordKey& key) {
    std::lock_guard lk(m_);
    for (auto it = entries_.begin(); it != entries_.end(); ++it) {
      if (it->first == key) {
        entries_.splice(entries_.begin(), entries_, it);
        return entries_.front().second;
      }
    }
    return nullptr;
  }

  /// Keeps `hand` unless it would take more than half the bound; the least recently used go.
  void put(const RecordKey& key, std::shared_ptr<const ComputedHand> hand) {
    if (!hand || hand->bytes > max_bytes_ / 2) return;
    std::lock_guard lk(m_);
    for (auto it = entries_.begin(); it != entries_.end(); ++it) {
      if (it->first == key) {
        bytes_ -= it->second->bytes;
        entries_.erase(it);
        break;
      }
    }
    bytes_ += hand->bytes;
    entries_.emplace_front(key, std::move(hand));
    while (bytes_ > max_bytes_ && !entries_.empty()) {
      bytes_ -= entries_.back().second->bytes;
      entries_.pop_back();
    }
  }

 private:
  std::mutex m_;
  std::size_t max_bytes_;
  std::size_t bytes_ = 0;
  std::list<std::pair<RecordKey, std::shared_ptr<const ComputedHand>>> entries_;
};

}  // namespace telehand::web
