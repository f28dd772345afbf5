#include "telehand/server/estimate/live_refit.h"

#include <algorithm>
#include <chrono>

namespace telehand::server::estimate {

LiveRefit::LiveRefit(const JointModelParams& geometry, const JointModelParams& initial,
                     const LiveRefitOptions& options)
    : options_(options), lever_m_(geometry.lever_arm_m), fitter_(geometry), published_(initial) {}

void LiveRefit::add(const Sample& s, bool valid, int64_t arrival_ns) {
  if (fitter_.add(s, valid)) newest_arrival_ns_ = std::max(newest_arrival_ns_, arrival_ns);
}

double LiveRefit::maxForceChange(const JointModelParams& a, const JointModelParams& b,
                                 double jnd_fraction, double jnd_floor_n, bool* felt) {
  const JointModel ma(a), mb(b);
  double worst = 0.0;
  bool any = false;
  for (int i = 0; i < kAxes; ++i) {
    const CubicCurve& c = a.axes[static_cast<std::size_t>(i)];
    const CubicCurve& d = b.axes[static_cast<std::size_t>(i)];
    const double lo = std::min(c.min_deg, d.min_deg), hi = std::max(c.max_deg, d.max_deg);
    for (double deg = lo; deg <= hi + 1e-9; deg += 0.25) {
      const double fa = ma.holdingForceN(i, degToRad(deg)), fb = mb.holdingForceN(i, degToRad(deg));
      const double diff = std::abs(fa - fb);
      worst = std::max(worst, diff);
      any =
          any || (diff > jnd_floor_n && diff > jnd_fraction * std::max(std::abs(fa), std::abs(fb)));
    }
  }
  if (felt) *felt = any;
  return worst;
}

std::optional<LiveRefit::Update> LiveRefit::poll(int64_t now_ns) {
  if (now_ns - last_refit_ns_ < std::max(options_.min_interval_ns, wait_ns_)) return std::nullopt;
  if (fitter_.size() < options_.min_samples || fitter_.size() == fitted_size_) return std::nullopt;
  last_refit_ns_ = now_ns;
  fitted_size_ = fitter_.size();
  Update u;
  const auto t0 = std::chrono::steady_clock::now();
  u.fit = fitter_.fit();
  const auto took =
      std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - t0);
  wait_ns_ =
      options_.max_busy_fraction > 0.0
          ? static_cast<int64_t>(static_cast<double>(took.count()) / options_.max_busy_fraction)
          : 0;
  bool any_axis = false;
  for (auto& a : u.fit.axes) {
    // An axis is taken once the clinician has mobilized it in both directions (the force
    // crossed zero by more than a felt amount each way): a one-sided stretch of data would
    // put an end-of-range wall right where the joint rests.
    a.ok = a.ok && a.curve.eval(a.curve.min_deg) < -options_.jnd_floor_n &&
           a.curve.eval(a.curve.max_deg) > options_.jnd_floor_n &&
           a.curve.max_deg - a.curve.min_deg >= options_.min_span_deg;
    any_axis = any_axis || a.ok;
  }
  if (!any_axis) return std::nullopt;
  u.params = u.fit.model(published_);
  u.params.knn = nullptr;
  bool rising = false;
  for (std::size_t i = 0; i < kAxes; ++i) {
    if (!u.fit.axes[i].ok) continue;
    CubicCurve& c = u.params.axes[i];
    // A wall the capture felt stays where it is; a range end that is only as far as the
    // capture has gone yet moves out by the margin.
    if (!u.fit.axes[i].wall_min) c.min_deg -= options_.range_margin_deg;
    if (!u.fit.axes[i].wall_max) c.max_deg += options_.range_margin_deg;
    // A joint resists being moved: a curve that falls anywhere in the published range (a
    // cubic fitted to too little, noisy data, or extended by the margin), or holds more than
    // a joint can, is not published (a follower would refuse it: the wire's own check); the
    // axis keeps what followers have now. The offline fit refuses such a curve too.
    if (!risesOverRange(c) || passiveCurveProblem(c)) {
      u.params.axes[i] = published_.axes[i];
      u.params.neutral_zone_deg[i] = published_.neutral_zone_deg[i];
      continue;
    }
    rising = true;
  }
  if (!rising) return std::nullopt;
  bool felt = false;
  u.max_change_n =
      maxForceChange(u.params, published_, options_.jnd_fraction, options_.jnd_floor_n, &felt);
  if (!felt) {
    return std::nullopt;
  }
  // The samples for data-driven followers: the passive (restoring) torque is minus what the
  // clinician applied.
  std::vector<KnnPoint> raw;
  raw.reserve(fitter_.points().size());
  for (const auto& p : fitter_.points()) raw.push_back({p.angles_rad, -p.axis_force_n * lever_m_});
  // A client takes at most kMaxKnnSamples: a capture over more cells is sent coarser.
  u.knn_points = voxelAverageAtMost(raw, options_.knn.cell_deg, options_.knn_min_count);
  u.newest_arrival_ns = newest_arrival_ns_;
  published_ = u.params;
  return u;
}

}  // namespace telehand::server::estimate
