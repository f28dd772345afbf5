#pragma once
/// Latest-value handoff between one writer thread and one reader thread: wait-free on both
/// sides, allocation-free, and the reader always gets the newest value written (unlike a
/// ring, which keeps old values when the reader falls behind).
#include <array>
#include <atomic>
#include <cstdint>
#include <type_traits>

namespace telehand {

template <typename T>
class TripleBuffer {
  static_assert(std::is_nothrow_destructible_v<T>, "values must copy without allocating");

 public:
  /// Writer side: publish a value (overwrites one the reader has not taken yet).
  void write(const T& value) noexcept {
    slots_[back_] = value;
    back_ =
        middle_.exchange(static_cast<uint8_t>(back_ | kFresh), std::memory_order_acq_rel) & kIndex;
  }

  /// Reader side: the newest value if one was written since the last read.
  bool read(T& out) noexcept {
    if ((middle_.load(std::memory_order_acquire) & kFresh) == 0) return false;
    front_ = middle_.exchange(front_, std::memory_order_acq_rel) & kIndex;
    out = slots_[front_];
    return true;
  }

 private:
  static constexpr uint8_t kIndex = 0x3;
  static constexpr uint8_t kFresh = 0x4;
  std::array<T, 3> slots_{};
  alignas(64) std::atomic<uint8_t> middle_{1};
  alignas(64) uint8_t back_ = 0;   // writer's slot
  alignas(64) uint8_t front_ = 2;  // reader's slot
};

}  // namespace telehand
