#include "telehand/server/sim/web_sim.h"

#include <algorithm>
#include <cmath>

namespace telehand::server::sim {

WebSim::WebSim(const TissueParams& p, double force_scale) noexcept : proxy_(p, force_scale) {}

void WebSim::setParams(const TissueParams& p, double force_scale) noexcept {
  proxy_.setParams(p, force_scale);
}

void WebSim::step(const PerFinger<Vec3>& p_device, int64_t t_ns) noexcept {
  out_ = proxy_.render(p_device, t_ns);
  ++steps_;
  const TissueParams& tp = proxy_.model().params();
  const double h = tp.half_extent_m;
  const double cell = 2.0 * h / (kGrid - 1);
  // Each pad indents the surface over about its contact radius: sqrt(2·R·δ) for a sphere of
  // radius R pressed δ deep (Hertz), spread with a Gaussian of that width.
  const double a = std::min(1.0, 1e-3 / kCreepS);
  for (int r = 0; r < kGrid; ++r) {
    for (int c = 0; c < kGrid; ++c) {
      const double x = -h + r * cell, y = -h + c * cell;
      double target = 0.0;
      for (int k = 0; k < 2; ++k) {
        const TissueContact& ct = out_.contact[k];
        if (ct.depth_m <= 0.0) continue;
        const double width = std::max(std::sqrt(2.0 * tp.pad_radius_m * ct.depth_m), 0.5 * cell);
        const double d2 = (x - ct.point_w.x()) * (x - ct.point_w.x()) +
                          (y - ct.point_w.y()) * (y - ct.point_w.y());
        target += ct.depth_m * std::exp(-0.5 * d2 / (width * width));
      }
      const auto rr = static_cast<std::size_t>(r), cc = static_cast<std::size_t>(c);
      double lap = 0.0;
      int n = 0;
      for (const auto& [dr, dc] : {std::pair{-1, 0}, {1, 0}, {0, -1}, {0, 1}}) {
        const int r2 = r + dr, c2 = c + dc;
        if (r2 < 0 || r2 >= kGrid || c2 < 0 || c2 >= kGrid) continue;
        lap += grid_[static_cast<std::size_t>(r2)][static_cast<std::size_t>(c2)] - grid_[rr][cc];
        ++n;
      }
      next_[rr][cc] = grid_[rr][cc] + a * (target - grid_[rr][cc]) + kTension * a * lap;
    }
  }
  grid_ = next_;
}

}  // namespace telehand::server::sim
