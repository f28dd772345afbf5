#pragma once
/// Velocity from quantized positions by first-order adaptive windowing (Janabi-Sharifi,
/// Hayward & Chen, "Discrete-time adaptive windowing for velocity estimation", IEEE Trans.
/// Control Systems Technology 8(6), 2000). A one-tick difference of encoder positions is
/// mostly quantization at low speed: one count of the MF-2's actuator encoders moves a thimble
/// by a few µm, i.e. several mm/s at 1 kHz. The estimate is instead the slope of the longest
/// recent window whose every sample lies within `uncertainty` of the straight line through its
/// ends: long (quiet) where the motion is slow, one tick (no lag) where it is fast or turns.
/// Fixed storage, allocation-free, noexcept.
#include <array>
#include <cstdint>

#include "telehand/core/math.h"

namespace telehand {

class AdaptiveVelocity {
 public:
  static constexpr int kMaxWindow = 32;  ///< samples a window may span, at most

  /// `uncertainty_m`: bound of the position measurement error (the band each sample must lie
  /// in around the window's line). `max_window`: 1..kMaxWindow ticks.
  explicit AdaptiveVelocity(double uncertainty_m = 8e-6, int max_window = 20) noexcept;

  /// Forget the history (the next estimate is zero).
  void reset() noexcept;

  /// Take the position measured at `t_ns` and return the velocity estimate (units/s). A
  /// sample with the newest time again is ignored (a repeated reading); one from before it
  /// restarts the history.
  const Vec3& update(const Vec3& p, int64_t t_ns) noexcept;

  const Vec3& velocity() const noexcept { return v_; }
  /// Ticks spanned by the last estimate (0: no estimate yet).
  int window() const noexcept { return window_; }
  /// The smallest speed the last estimate resolves: the uncertainty over the window's span
  /// (units/s; 0 with no estimate). A still position flickering by a count gives an estimate
  /// under it.
  double resolution() const noexcept { return resolution_; }

 private:
  /// Sample `age` ticks back (0 = newest).
  int slot(int age) const noexcept { return (head_ - age + kSlots) % kSlots; }

  static constexpr int kSlots = kMaxWindow + 1;
  double uncertainty_m_;
  int max_window_;
  std::array<Vec3, kSlots> p_{};
  std::array<int64_t, kSlots> t_{};
  int head_ = -1;  // slot of the newest sample
  int count_ = 0;
  Vec3 v_ = Vec3::Zero();
  int window_ = 0;
  double resolution_ = 0.0;
};

}  // namespace telehand
