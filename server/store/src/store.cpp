#include "telehand/server/store/store.h"

#include "telehand/core/error.h"

namespace telehand::server::store {

std::vector<SessionStore::BatchResult> SessionStore::appendSampleBatches(
    std::span<const SampleBatch> batches) {
  std::vector<BatchResult> out(batches.size());
  for (std::size_t i = 0; i < batches.size(); ++i) {
    try {
      out[i].added = appendSamples(batches[i].session_id, batches[i].samples, batches[i].valid);
      out[i].stored = true;
    } catch (const StoreError& e) {
      out[i].error = e.what();
    }
  }
  return out;
}

}  // namespace telehand::server::store
