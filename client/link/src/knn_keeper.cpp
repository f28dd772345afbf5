#include "telehand/client/link/knn_keeper.h"

#include <algorithm>

namespace telehand::client::link {

const KnnTorqueModel* KnnKeeper::keep(std::shared_ptr<const KnnTorqueModel> model) {
  const KnnTorqueModel* p = model.get();
  kept_.push_back({std::move(model), kNotPushed});
  return p;
}

void KnnKeeper::pushed(const JointModelParams& params, uint64_t index) {
  if (params.knn == nullptr) return;
  for (Kept& k : kept_) {
    if (k.model.get() == params.knn && k.index == kNotPushed) {
      k.index = index;
      return;
    }
  }
}

void KnnKeeper::release(const loop::KnnInUse& in_use, const KnnTorqueModel* pending) {
  std::erase_if(kept_, [&](const Kept& k) {
    const KnnTorqueModel* p = k.model.get();
    if (k.index == kNotPushed) return p != pending;
    if (k.index >= in_use.models_taken) return false;  // still in the ring
    return std::find(in_use.held.begin(), in_use.held.end(), p) == in_use.held.end();
  });
}

}  // namespace telehand::client::link
