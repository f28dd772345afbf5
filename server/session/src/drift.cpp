#include "telehand/server/session/drift.h"

#include <algorithm>
#include <cmath>

namespace telehand::server::session {

bool DriftCorrector::observe(const Vec3& hand_rad, const Vec3& proxy_rad, bool held, double dt_s,
                             int64_t now_ns) noexcept {
  if (!held || !(dt_s > 0.0)) return false;
  const Vec3 raw = hand_rad - proxy_rad;
  if (!raw.allFinite()) return false;
  drift_rad_ += (dt_s / (o_.tau_s + dt_s)) * (raw - drift_rad_);
  const double worst_deg = radToDeg(drift_rad_.cwiseAbs().maxCoeff());
  if (worst_deg < o_.threshold_deg) return false;
  if (corrections_ > 0 &&
      static_cast<double>(now_ns - last_correction_ns_) * 1e-9 < o_.min_interval_s) {
    return false;
  }
  const double limit = degToRad(o_.max_offset_deg);
  const Vec3 next = (offset_rad_ + drift_rad_).cwiseMax(-limit).cwiseMin(limit);
  if ((next - offset_rad_).cwiseAbs().maxCoeff() < 1e-9) return false;  // held at the limit
  // Under the new offset the proxy moves by the change: what is left of the drift is what
  // the limit kept out.
  drift_rad_ -= next - offset_rad_;
  offset_rad_ = next;
  last_correction_ns_ = now_ns;
  ++corrections_;
  return true;
}

}  // namespace telehand::server::session
