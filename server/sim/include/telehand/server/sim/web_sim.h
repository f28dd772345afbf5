#pragma once
/// The web between the thumb and index metacarpals on the authoritative side (docs/massage.md
/// "Server"): the shared tissue model (common/core tissue_model.h) stepped at 1 ms on device
/// time with the thimble positions the client sends, so that its forces are the ones the
/// client's proxy rendered, and a deformable surface over the web's contact area for viewers:
/// an 8×8 grid of nodes whose compression relaxes toward the pads' indentation with the
/// tissue's creep time (a Kelvin–Voigt node per grid point, coupled to its neighbours by the
/// skin's tension). It is not a Bullet soft body: the force the student feels must be the
/// shared model's, and Bullet's soft-body contacts are penalty springs of their own whose
/// forces would differ from it (docs/massage.md gives the reasons and the figures).
/// Allocation-free after construction (its checkpoint, saveState, allocates).
#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "telehand/core/tissue_model.h"

namespace telehand::server::sim {

class WebSim {
 public:
  static constexpr int kGrid = 8;
  /// Creep time of the surface (s): how fast the grid follows the pads.
  static constexpr double kCreepS = 0.05;
  /// Share of the Laplacian's pull a node takes per step (the skin's tension).
  static constexpr double kTension = 0.15;

  explicit WebSim(const TissueParams& p, double force_scale = 0.25) noexcept;
  void setParams(const TissueParams& p, double force_scale) noexcept;

  /// One 1 ms step at device time `t_ns` with the thimbles at `p_device`.
  void step(const PerFinger<Vec3>& p_device, int64_t t_ns) noexcept;

  /// After a step on a sample: where this web's force on a finger differs from the one the
  /// client's proxy recorded for that sample (`force_n`, reference N, device frame, and the
  /// depth it rendered) - after a gap, stepped here on interpolated positions - take the
  /// finger's depth rate and skin stretch from it within the model's bounds
  /// (TissueProxy::resync) and render the sample again. A finger is left as it is where the
  /// client's depth is not this web's (another model), where either number is not finite or
  /// out of the sample's bounds, or where the forces already agree. Returns the fingers
  /// taken.
  int resync(const PerFinger<Vec3>& force_n, const PerFinger<double>& depth_m) noexcept;

  /// The web's state (the proxy's, its last output, the surface and the step count) as
  /// kStateSize doubles, for a checkpoint (docs/pool.md).
  static constexpr std::size_t kStateSize = 2 + TissueProxy::kStateSize + 32 + kGrid * kGrid;
  std::vector<double> saveState() const;
  /// Go on from a saveState(): false, with nothing changed, for anything else (a size, a
  /// number not finite or outside what stepping could leave, TissueProxy::restoreState).
  bool restoreState(std::span<const double> state) noexcept;

  const TissueOutput& last() const noexcept { return out_; }
  /// Compression of the web at each grid node (m, + pressed in), rows along x, columns along y.
  const std::array<std::array<double, kGrid>, kGrid>& grid() const noexcept { return grid_; }
  const TissueModel& model() const noexcept { return proxy_.model(); }
  uint64_t steps() const noexcept { return steps_; }

 private:
  TissueProxy proxy_;
  TissueOutput out_;
  std::array<std::array<double, kGrid>, kGrid> grid_{};
  std::array<std::array<double, kGrid>, kGrid> next_{};
  uint64_t steps_ = 0;
};

}  // namespace telehand::server::sim
