#pragma once
/// Live refit of a capture session (docs/design.md "cross-continent demonstration"): samples are
/// added as they arrive; poll() refits at most every `min_interval_ns` and returns a new
/// model only when it differs from the one last published by more than a force JND
/// somewhere in the captured range, so followers get a new JointModel version only when
/// they would feel the change.
#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include "telehand/core/knn_model.h"
#include "telehand/server/estimate/capture_fit.h"

namespace telehand::server::estimate {

struct LiveRefitOptions {
  int64_t min_interval_ns = 500'000'000;  ///< at most two refits a second
  /// ...and a refit that took t keeps the next one at least t / max_busy_fraction away, so
  /// that refits take at most this share of the caller's time (a long capture, or one with
  /// a spasm, whose fit alternates the gain with the curve, takes longer to fit).
  double max_busy_fraction = 0.25;
  /// A change is felt when the force differs by more than this fraction of it (force JND
  /// 7-10 %, docs/facts.md "Rendering and perception")...
  double jnd_fraction = 0.07;
  /// ...and by more than this many newtons at reference scale (an assumption: 0.5 N at the
  /// lever arm is 0.125 N at the device, near the smallest forces a fingertip resolves).
  double jnd_floor_n = 0.5;
  std::size_t min_samples = 1000;  ///< before the first refit
  double min_span_deg = 6.0;       ///< an axis is published once it spans this much
  /// The published range extends the captured one by this much each way: while the capture
  /// grows, the end-of-range wall (whose stiffness adds to the curve's end slope) stays
  /// beyond where followers are, instead of jumping onto them.
  double range_margin_deg = 5.0;
  KnnOptions knn;                 ///< for followers that render the samples
  std::size_t knn_min_count = 3;  ///< samples a cell needs to become a kNN sample
};

class LiveRefit {
 public:
  /// `geometry`: the capture's joint frame and lever arm; `initial`: what is published now.
  LiveRefit(const JointModelParams& geometry, const JointModelParams& initial,
            const LiveRefitOptions& options = {});

  /// A recorded sample, in the order the record holds them; `arrival_ns` on the server clock.
  void add(const Sample& s, bool valid, int64_t arrival_ns);

  struct Update {
    JointModelParams params;           ///< the fitted joint (version and knn left to the caller)
    std::vector<KnnPoint> knn_points;  ///< the captured samples, cell-averaged
    int64_t newest_arrival_ns = 0;     ///< when the newest sample in this fit arrived
    double max_change_n = 0.0;         ///< largest force change against the last published
    CaptureFit fit;
  };
  /// A new model to publish, or nullopt (too early, too little data, or not a felt change).
  std::optional<Update> poll(int64_t now_ns);

  std::size_t samples() const noexcept { return fitter_.size(); }

  /// Largest |F_a - F_b| over `a`'s ranges (each axis), and whether it is a felt change.
  static double maxForceChange(const JointModelParams& a, const JointModelParams& b,
                               double jnd_fraction, double jnd_floor_n, bool* felt);

 private:
  LiveRefitOptions options_;
  double lever_m_;
  CaptureFitter fitter_;
  JointModelParams published_;
  int64_t last_refit_ns_ = INT64_MIN / 2;
  int64_t wait_ns_ = 0;  ///< after the last refit, before the next
  int64_t newest_arrival_ns_ = 0;
  std::size_t fitted_size_ = 0;
};

}  // namespace telehand::server::estimate
