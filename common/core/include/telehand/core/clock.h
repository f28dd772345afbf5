#pragma once
/// Clocks are injected so that loop and device tests are deterministic.
#include <time.h>

#include <atomic>
#include <cstdint>

namespace telehand {

constexpr int64_t kNsPerMs = 1'000'000;
constexpr int64_t kNsPerS = 1'000'000'000;

/// A monotonic time source in nanoseconds.
class Clock {
 public:
  virtual ~Clock() = default;
  virtual int64_t nowNs() const noexcept = 0;
};

/// CLOCK_MONOTONIC.
class SteadyClock final : public Clock {
 public:
  int64_t nowNs() const noexcept override {
    timespec ts{};
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * kNsPerS + ts.tv_nsec;
  }
};

/// A clock that only moves when told to (tests, deterministic replays).
class ManualClock final : public Clock {
 public:
  explicit ManualClock(int64_t start_ns = 0) : now_ns_(start_ns) {}
  int64_t nowNs() const noexcept override { return now_ns_.load(std::memory_order_acquire); }
  void advance(int64_t dt_ns) noexcept { now_ns_.fetch_add(dt_ns, std::memory_order_acq_rel); }
  void set(int64_t t_ns) noexcept { now_ns_.store(t_ns, std::memory_order_release); }

 private:
  std::atomic<int64_t> now_ns_;
};

/// Wall-clock time (CLOCK_REALTIME) in ns: the source timestamps that cross the network.
inline int64_t wallNs() noexcept {
  timespec ts{};
  clock_gettime(CLOCK_REALTIME, &ts);
  return ts.tv_sec * kNsPerS + ts.tv_nsec;
}

}  // namespace telehand
