#include "telehand/core/velocity.h"

#include <algorithm>

namespace telehand {

AdaptiveVelocity::AdaptiveVelocity(double uncertainty_m, int max_window) noexcept
    : uncertainty_m_(std::max(uncertainty_m, 0.0)),
      max_window_(std::clamp(max_window, 1, kMaxWindow)) {}

void AdaptiveVelocity::reset() noexcept {
  head_ = -1;
  count_ = 0;
  v_ = Vec3::Zero();
  window_ = 0;
  resolution_ = 0.0;
}

const Vec3& AdaptiveVelocity::update(const Vec3& p, int64_t t_ns) noexcept {
  if (!allFinite(p)) return v_;  // keep the last estimate; a bad sample is not motion
  if (count_ > 0) {
    const int64_t newest = t_[static_cast<std::size_t>(head_)];
    if (t_ns == newest) return v_;  // the same sample again (a failed read): nothing new
    if (t_ns < newest) reset();
  }
  head_ = (head_ + 1) % kSlots;
  p_[static_cast<std::size_t>(head_)] = p;
  t_[static_cast<std::size_t>(head_)] = t_ns;
  count_ = std::min(count_ + 1, kSlots);
  if (count_ < 2) {
    v_ = Vec3::Zero();
    window_ = 0;
    resolution_ = 0.0;
    return v_;
  }
  const Vec3& p0 = p;
  const double band2 = uncertainty_m_ * uncertainty_m_;
  const int longest = std::min(count_ - 1, max_window_);
  // Grow the window while the line through its ends passes within the band of every sample
  // inside it; the one-tick difference always qualifies.
  for (int m = 1; m <= longest; ++m) {
    const std::size_t sm = static_cast<std::size_t>(slot(m));
    const double span_s = static_cast<double>(t_ns - t_[sm]) * 1e-9;
    const Vec3 slope = (p0 - p_[sm]) / span_s;
    bool fits = true;
    for (int j = 1; j < m && fits; ++j) {
      const std::size_t sj = static_cast<std::size_t>(slot(j));
      const double back_s = static_cast<double>(t_ns - t_[sj]) * 1e-9;
      fits = (p_[sj] - (p0 - slope * back_s)).squaredNorm() <= band2;
    }
    if (!fits) break;
    v_ = slope;
    window_ = m;
    resolution_ = uncertainty_m_ / span_s;
  }
  return v_;
}

}  // namespace telehand
