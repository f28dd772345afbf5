#include "telehand/server/session/exploration.h"

#include <algorithm>
#include <cstdio>

#include "telehand/core/joint_model.h"

namespace telehand::server::session {

void Exploration::begin(const std::string& phase) {
  active_ = true;
  started_ = false;
  holding_ = false;
  reached_ = {};
  phase_ = phase;
}

void Exploration::observe(const Vec3& angles_rad, const Vec3& rest_rad, const Vec3& axis_force_n,
                          bool held, double dt_s) noexcept {
  if (!active_) return;
  if (!held) {
    holding_ = false;  // a new grip starts the filter afresh
    return;
  }
  if (!holding_) {
    holding_ = true;
    angles_rad_ = angles_rad;
    force_n_axis_ = axis_force_n;
  } else {
    const double w = std::min(1.0, dt_s / kSmoothingS);
    angles_rad_ += w * (angles_rad - angles_rad_);
    force_n_axis_ += w * (axis_force_n - force_n_axis_);
  }
  if (!started_) {
    started_ = true;
    start_rad_ = angles_rad;
  }
  for (std::size_t i = 0; i < kDirections.size(); ++i) {
    const int axis = kDirectionAxis[i];
    const double sign = kDirectionSign[i];
    const double deg = radToDeg(angles_rad_[axis]);
    const double past_rest = sign * (deg - radToDeg(rest_rad[axis]));
    const double past_start = sign * (deg - radToDeg(start_rad_[axis]));
    if (past_rest < kMinExcursionDeg || past_start < kMinExcursionDeg) continue;
    if (reached_[i] && sign * deg <= sign * angle_deg_[i]) continue;
    reached_[i] = true;
    angle_deg_[i] = deg;
    force_n_[i] = sign * force_n_axis_[axis];
  }
}

std::vector<SessionStore::Reach> Exploration::finish() {
  std::vector<SessionStore::Reach> out;
  if (active_) {
    for (std::size_t i = 0; i < kDirections.size(); ++i) {
      if (reached_[i]) out.push_back({phase_, kDirections[i], angle_deg_[i], force_n_[i]});
    }
  }
  active_ = false;
  return out;
}

std::string Exploration::summary(const std::vector<SessionStore::Reach>& now,
                                 const std::vector<SessionStore::Reach>& baseline) {
  std::string out;
  for (const char* dir : kDirections) {
    const SessionStore::Reach* r = nullptr;
    for (const auto& x : now) {
      if (x.direction == dir) r = &x;
    }
    char buf[96];
    if (!r) {
      std::snprintf(buf, sizeof buf, "%s%s not reached", out.empty() ? "" : ", ", dir);
      out += buf;
      continue;
    }
    std::snprintf(buf, sizeof buf, "%s%s %.1f deg", out.empty() ? "" : ", ", dir, r->angle_deg);
    out += buf;
    for (const auto& b : baseline) {
      if (b.direction == r->direction) {
        std::snprintf(buf, sizeof buf, " (%+.1f vs baseline)", r->angle_deg - b.angle_deg);
        out += buf;
      }
    }
  }
  return out;
}

}  // namespace telehand::server::session
