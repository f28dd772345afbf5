#include "telehand/server/session/exploration.h"

#include <cstdio>

#include "telehand/core/joint_model.h"

namespace telehand::server::session {

void Exploration::begin(const std::string& phase) {
  active_ = true;
  seen_ = false;
  phase_ = phase;
}

void Exploration::observe(const Vec3& angles_rad, double force_n) noexcept {
  if (!active_) return;
  static constexpr int kAxisOf[3] = {kFlexion, kAbduction, kAxial};
  for (int a = 0; a < 3; ++a) {
    const double deg = radToDeg(angles_rad[kAxisOf[a]]);
    const auto hi = static_cast<std::size_t>(2 * a), lo = hi + 1;
    if (!seen_ || deg > angle_deg_[hi]) {
      angle_deg_[hi] = deg;
      force_n_[hi] = force_n;
    }
    if (!seen_ || deg < angle_deg_[lo]) {
      angle_deg_[lo] = deg;
      force_n_[lo] = force_n;
    }
  }
  seen_ = true;
}

std::vector<SessionStore::Reach> Exploration::finish() {
  std::vector<SessionStore::Reach> out;
  if (active_ && seen_) {
    for (std::size_t i = 0; i < kDirections.size(); ++i) {
      out.push_back({phase_, kDirections[i], angle_deg_[i], force_n_[i]});
    }
  }
  active_ = false;
  return out;
}

std::string Exploration::summary(const std::vector<SessionStore::Reach>& now,
                                 const std::vector<SessionStore::Reach>& baseline) {
  std::string out;
  for (const auto& r : now) {
    char buf[96];
    std::snprintf(buf, sizeof buf, "%s%s %.1f deg", out.empty() ? "" : ", ", r.direction.c_str(),
                  r.angle_deg);
    out += buf;
    for (const auto& b : baseline) {
      if (b.direction == r.direction) {
        std::snprintf(buf, sizeof buf, " (%+.1f vs baseline)", r.angle_deg - b.angle_deg);
        out += buf;
      }
    }
  }
  return out;
}

}  // namespace telehand::server::session
