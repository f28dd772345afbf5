#pragma once
/// Fixed-size single-producer/single-consumer ring: wait-free, allocation-free after
/// construction. The only way data crosses the real-time thread boundary.
#include <array>
#include <atomic>
#include <cstddef>
#include <new>
#include <type_traits>

namespace telehand {

template <typename T, std::size_t Capacity>
class SpscRing {
  static_assert(Capacity >= 2 && (Capacity & (Capacity - 1)) == 0, "capacity: power of two");
  static_assert(std::is_nothrow_destructible_v<T>, "ring elements must copy without allocating");

 public:
  /// Producer side. False when full (the element is not stored).
  bool tryPush(const T& value) noexcept {
    const std::size_t head = head_.load(std::memory_order_relaxed);
    if (head - tail_cache_ == Capacity) {
      tail_cache_ = tail_.load(std::memory_order_acquire);
      if (head - tail_cache_ == Capacity) return false;
    }
    slots_[head & kMask] = value;
    head_.store(head + 1, std::memory_order_release);
    return true;
  }

  /// Consumer side. False when empty.
  bool tryPop(T& out) noexcept {
    const std::size_t tail = tail_.load(std::memory_order_relaxed);
    if (tail == head_cache_) {
      head_cache_ = head_.load(std::memory_order_acquire);
      if (tail == head_cache_) return false;
    }
    out = slots_[tail & kMask];
    tail_.store(tail + 1, std::memory_order_release);
    return true;
  }

  /// Approximate fill level (exact when called from either side while the other is idle).
  std::size_t size() const noexcept {
    return head_.load(std::memory_order_acquire) - tail_.load(std::memory_order_acquire);
  }
  static constexpr std::size_t capacity() noexcept { return Capacity; }

 private:
  static constexpr std::size_t kMask = Capacity - 1;
  static constexpr std::size_t kLine = 64;
  alignas(kLine) std::atomic<std::size_t> head_{0};
  alignas(kLine) std::size_t tail_cache_ = 0;  // producer's view of tail_
  alignas(kLine) std::atomic<std::size_t> tail_{0};
  alignas(kLine) std::size_t head_cache_ = 0;  // consumer's view of head_
  alignas(kLine) std::array<T, Capacity> slots_{};
};

}  // namespace telehand
