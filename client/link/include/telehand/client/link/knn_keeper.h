#pragma once
/// The k-nearest-neighbour models the link built, kept alive for as long as the haptic loop
/// may read them: a model handed to the loop lives until the loop has taken it from its ring
/// and no longer holds it (HapticLoop::knnInUse), however many models arrive meanwhile (a fade
/// that waits for its energy budget holds the old model for up to two seconds). Freed here,
/// on the link's thread, never on the loop's. Link thread only.
#include <cstdint>
#include <memory>
#include <vector>

#include "telehand/client/loop/haptic_loop.h"
#include "telehand/core/joint_model.h"
#include "telehand/core/knn_model.h"

namespace telehand::client::link {

class KnnKeeper {
 public:
  /// Keeps a model just built for a JointModel that is not in the loop's ring yet.
  const KnnTorqueModel* keep(std::shared_ptr<const KnnTorqueModel> model);
  /// `params` went into the loop's model ring as the `index`-th model handed to it (from 0).
  void pushed(const JointModelParams& params, uint64_t index);
  /// Frees what the loop does not read and never will: models it took from the ring and no
  /// longer holds, and models never handed to it other than `pending` (the one waiting for
  /// room in the ring; a newer one replaced the others).
  void release(const loop::KnnInUse& in_use, const KnnTorqueModel* pending);
  std::size_t size() const noexcept { return kept_.size(); }

 private:
  static constexpr uint64_t kNotPushed = UINT64_MAX;
  struct Kept {
    std::shared_ptr<const KnnTorqueModel> model;
    uint64_t index = kNotPushed;  ///< its place in the loop's ring order
  };
  std::vector<Kept> kept_;
};

}  // namespace telehand::client::link
