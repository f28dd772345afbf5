// The only translation unit that includes FLANN (header-only use; it is heavy to compile).
#include "telehand/core/knn_model.h"

#include <flann/flann.hpp>
#include <map>
#include <tuple>

#include "telehand/core/error.h"

namespace telehand {

struct KnnTorqueModel::Index {
  std::vector<double> coords;  // scaled angles, row-major n x 3
  flann::Matrix<double> data;
  flann::KDTreeIndex<flann::L2<double>> tree;
  flann::SearchParams params{flann::FLANN_CHECKS_UNLIMITED};
  mutable flann::KNNSimpleResultSet<double> result;
  mutable std::vector<std::size_t> idx;
  mutable std::vector<double> dist;
  Vec3 inv_cell;

  Index(std::vector<double> c, std::size_t n, std::size_t k, const Vec3& inv)
      : coords(std::move(c)),
        data(coords.data(), n, 3),
        // One tree, unlimited checks: a search that allocates nothing.
        tree(data, flann::KDTreeIndexParams(1)),
        result(k),
        idx(k),
        dist(k),
        inv_cell(inv) {
    tree.buildIndex();
  }
};

KnnTorqueModel::KnnTorqueModel(std::vector<KnnPoint> samples, const KnnOptions& options)
    : samples_(std::move(samples)), options_(options) {
  if (samples_.empty()) throw Error("k-nearest-neighbour model: no samples");
  if (options_.k < 1) throw Error("k-nearest-neighbour model: k must be at least 1");
  if (!(options_.cell_deg.minCoeff() > 0.0))
    throw Error("k-nearest-neighbour model: cell sizes must be positive");
  const Vec3 inv = options_.cell_deg.unaryExpr([](double d) { return 1.0 / degToRad(d); });
  std::vector<double> c(samples_.size() * 3);
  for (std::size_t i = 0; i < samples_.size(); ++i) {
    if (!allFinite(samples_[i].angles_rad) || !allFinite(samples_[i].torque_nm)) {
      throw Error("k-nearest-neighbour model: sample " + std::to_string(i) + " is not finite");
    }
    for (int a = 0; a < 3; ++a)
      c[i * 3 + static_cast<std::size_t>(a)] = samples_[i].angles_rad[a] * inv[a];
  }
  const std::size_t k =
      std::min<std::size_t>(static_cast<std::size_t>(options_.k), samples_.size());
  index_ = std::make_unique<Index>(std::move(c), samples_.size(), k, inv);
}

KnnTorqueModel::~KnnTorqueModel() = default;

Vec3 KnnTorqueModel::torqueNm(const Vec3& angles_rad) const noexcept {
  Index& ix = *index_;
  double q[3];
  for (int a = 0; a < 3; ++a) q[a] = angles_rad[a] * ix.inv_cell[a];
  ix.result.clear();
  ix.tree.findNeighbors(ix.result, q, ix.params);
  const std::size_t n = ix.result.size();
  ix.result.copy(ix.idx.data(), ix.dist.data(), n);
  // Inverse-distance weights (distances in cells; squared L2 from FLANN). Half a cell keeps
  // a query on top of a sample from ignoring its neighbours.
  Vec3 sum = Vec3::Zero();
  double wsum = 0.0;
  for (std::size_t i = 0; i < n; ++i) {
    const double w = 1.0 / (std::sqrt(ix.dist[i]) + 0.5);
    sum += w * samples_[ix.idx[i]].torque_nm;
    wsum += w;
  }
  return wsum > 0.0 ? Vec3(sum / wsum) : Vec3::Zero();
}

std::vector<KnnPoint> voxelAverage(std::span<const KnnPoint> points, const Vec3& cell_deg,
                                   std::size_t min_count) {
  struct Acc {
    Vec3 a = Vec3::Zero(), t = Vec3::Zero();
    std::size_t n = 0;
  };
  std::map<std::tuple<long, long, long>, Acc> cells;
  for (const auto& p : points) {
    if (!allFinite(p.angles_rad) || !allFinite(p.torque_nm)) continue;
    const Vec3 c =
        p.angles_rad.unaryExpr([](double r) { return radToDeg(r); }).cwiseQuotient(cell_deg);
    Acc& acc = cells[{std::lround(std::floor(c.x())), std::lround(std::floor(c.y())),
                      std::lround(std::floor(c.z()))}];
    acc.a += p.angles_rad;
    acc.t += p.torque_nm;
    ++acc.n;
  }
  std::vector<KnnPoint> out;
  out.reserve(cells.size());
  for (const auto& [key, acc] : cells) {
    if (acc.n < min_count) continue;
    const double inv = 1.0 / static_cast<double>(acc.n);
    out.push_back({acc.a * inv, acc.t * inv});
  }
  return out;
}

std::vector<KnnPoint> voxelAverageAtMost(std::span<const KnnPoint> points, const Vec3& cell_deg,
                                         std::size_t min_count, std::size_t max_points,
                                         Vec3* cell_used) {
  Vec3 cell = cell_deg;
  std::vector<KnnPoint> out = voxelAverage(points, cell, min_count);
  while (out.size() > max_points) {
    cell *= 1.25;
    out = voxelAverage(points, cell, min_count);
  }
  if (cell_used) *cell_used = cell;
  return out;
}

}  // namespace telehand
