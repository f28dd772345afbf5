#include "telehand/server/sim/web_sim.h"

#include <algorithm>
#include <cmath>

#include "telehand/core/sample.h"

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

int WebSim::resync(const PerFinger<Vec3>& force_n, const PerFinger<double>& depth_m) noexcept {
  namespace b = sample_bounds;
  int changed = 0;
  for (int k = 0; k < 2; ++k) {
    const auto kk = static_cast<std::size_t>(k);
    const Vec3& f = force_n[kk];
    const double depth = depth_m[kk];
    if (!allFinite(f) || f.cwiseAbs().maxCoeff() > b::kThimbleForceN) continue;
    if (!std::isfinite(depth) || !(depth > 0.0) || depth > b::kDepthM) continue;
    const TissueContact& here = out_.contact[kk];
    // The same position gives the same depth under the same model: a client that rendered
    // another depth rendered another web, whose skin is not this one's.
    if (!(here.depth_m > 0.0) || std::abs(here.depth_m - depth) > 1e-9) continue;
    if ((here.force() - f).norm() <= 1e-9) continue;
    if (proxy_.resync(k, f)) ++changed;
  }
  if (changed > 0) out_ = proxy_.renderLast();
  return changed;
}

namespace {
constexpr double kWebStateMagic = 8808.0;  // the first number of a saved web
constexpr std::size_t kContactSize = 12;
constexpr double kMaxGridM = 10.0;  // far beyond two pads pressed 1 m in

void putVec(const Vec3& v, std::vector<double>& out) {
  out.insert(out.end(), {v.x(), v.y(), v.z()});
}
Vec3 getVec(const double* d) noexcept { return {d[0], d[1], d[2]}; }
bool isFlag(double x) noexcept { return x == 0.0 || x == 1.0; }
}  // namespace

std::vector<double> WebSim::saveState() const {
  std::vector<double> out;
  out.reserve(kStateSize);
  out.push_back(kWebStateMagic);
  out.push_back(static_cast<double>(steps_));
  proxy_.saveState(out);
  for (const TissueContact& c : out_.contact) {
    out.push_back(c.depth_m);
    out.push_back(c.depth_rate_m_s);
    putVec(c.normal_n, out);
    putVec(c.tangential_n, out);
    putVec(c.point_w, out);
    out.push_back(c.sticking ? 1.0 : 0.0);
  }
  for (const Vec3& f : out_.force_device_n) putVec(f, out);
  out.push_back(out_.blending ? 1.0 : 0.0);
  out.push_back(out_.potential_j);
  for (const auto& row : grid_) out.insert(out.end(), row.begin(), row.end());
  return out;
}

bool WebSim::restoreState(std::span<const double> s) noexcept {
  if (s.size() != kStateSize || s[0] != kWebStateMagic) return false;
  for (double x : s) {
    if (!std::isfinite(x)) return false;
  }
  // A step count a double holds exactly.
  if (!(s[1] >= 0.0 && s[1] <= 9007199254740992.0 && s[1] == std::floor(s[1]))) return false;
  const std::span<const double> proxy = s.subspan(2, TissueProxy::kStateSize);
  const double* d = s.data() + 2 + TissueProxy::kStateSize;
  TissueOutput out;
  for (std::size_t k = 0; k < 2; ++k, d += kContactSize) {
    TissueContact& c = out.contact[k];
    if (d[0] < 0.0 || !isFlag(d[11])) return false;
    c.depth_m = d[0];
    c.depth_rate_m_s = d[1];
    c.normal_n = getVec(d + 2);
    c.tangential_n = getVec(d + 5);
    c.point_w = getVec(d + 8);
    c.sticking = d[11] == 1.0;
  }
  for (std::size_t k = 0; k < 2; ++k, d += 3) out.force_device_n[k] = getVec(d);
  if (!isFlag(d[0])) return false;
  out.blending = d[0] == 1.0;
  out.potential_j = d[1];
  d += 2;
  std::array<std::array<double, kGrid>, kGrid> grid{};
  for (auto& row : grid) {
    for (double& g : row) {
      if (std::abs(*d) > kMaxGridM) return false;
      g = *d++;
    }
  }
  if (!proxy_.restoreState(proxy)) return false;
  steps_ = static_cast<uint64_t>(s[1]);
  out_ = out;
  grid_ = grid;
  return true;
}

}  // namespace telehand::server::sim
