#pragma once
/// The data-driven joint model: k-nearest-neighbour regression (FLANN) over captured
/// (alpha, beta, gamma) -> passive torque samples, for joints whose axes are coupled (e.g.
/// abduction stiffer in flexion, as the collateral ligaments tighten) or otherwise beyond
/// three separable cubics.
///
/// Queries search a single FLANN kd-tree with unlimited checks and a result set allocated
/// once: torqueNm() allocates nothing and can run in the 1 kHz step. (FLANN's single-tree
/// search bounds its pruning loosely: it finds the exact neighbours for about 98 % of
/// queries and near ones otherwise; FLANN's exact single-index tree allocates per query.)
/// One thread queries a given instance (it keeps its search buffers).
#include <cstddef>
#include <memory>
#include <span>
#include <vector>

#include "telehand/core/math.h"

namespace telehand {

struct KnnPoint {
  Vec3 angles_rad = Vec3::Zero();
  Vec3 torque_nm = Vec3::Zero();  ///< passive (restoring) torque per axis, reference scale
};

struct KnnOptions {
  int k = 8;
  /// Distances are measured in these units per axis (flexion ranges three times wider than
  /// abduction or axial rotation); also the cell size of voxelAverage().
  Vec3 cell_deg = Vec3(3.0, 1.0, 1.0);
};

/// Most samples a model from the network may hold (a KnnModel on the wire is refused beyond
/// it, before anything is allocated for it). The server's samples are the capture's cells
/// (voxelAverage with the default cell_deg) holding at least a few samples: the whole range of
/// the healthy joint is 45 x 40 x 25 = 45,000 cells (the lax case's 55 x 50 x 30 = 82,500), and
/// a capture, which sweeps the axes rather than filling the volume, fills a small share of it
/// (a coupled joint's: 998 cells from 45,000 samples).
constexpr std::size_t kMaxKnnSamples = 65'536;

class KnnTorqueModel {
 public:
  /// Builds the index (allocates: not on the real-time path). Throws Error when empty.
  KnnTorqueModel(std::vector<KnnPoint> samples, const KnnOptions& options = {});
  ~KnnTorqueModel();
  KnnTorqueModel(const KnnTorqueModel&) = delete;
  KnnTorqueModel& operator=(const KnnTorqueModel&) = delete;

  /// Inverse-distance weighted mean torque of the k nearest samples. Allocation-free.
  Vec3 torqueNm(const Vec3& angles_rad) const noexcept;

  std::size_t size() const noexcept { return samples_.size(); }
  const std::vector<KnnPoint>& samples() const noexcept { return samples_; }
  const KnnOptions& options() const noexcept { return options_; }

 private:
  struct Index;
  std::vector<KnnPoint> samples_;
  KnnOptions options_;
  std::unique_ptr<Index> index_;
};

/// Mean angle and torque per grid cell (cell_deg per axis) of cells holding at least
/// `min_count` points: the noise of single samples averages out and the model stays small.
std::vector<KnnPoint> voxelAverage(std::span<const KnnPoint> points, const Vec3& cell_deg,
                                   std::size_t min_count = 3);

/// voxelAverage, with the cells widened (by a quarter at a time) until at most `max_points`
/// hold enough points: what the server sends a client, which refuses more than
/// kMaxKnnSamples. `cell_used`, if given, gets the cell size taken.
std::vector<KnnPoint> voxelAverageAtMost(std::span<const KnnPoint> points, const Vec3& cell_deg,
                                         std::size_t min_count,
                                         std::size_t max_points = kMaxKnnSamples,
                                         Vec3* cell_used = nullptr);

}  // namespace telehand
