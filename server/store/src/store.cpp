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

uint64_t SessionStore::storedPrefix(uint64_t session_id) {
  const auto e = extent(session_id);
  if (!e) return 0;
  uint64_t lo = 0, hi = e->last_seq + 1;  // a prefix of length lo is held; hi bounds it
  if (countSamples(session_id, 0, e->last_seq) == hi) return hi;
  --hi;  // not all of them
  while (lo < hi) {
    const uint64_t mid = lo + (hi - lo + 1) / 2;
    if (countSamples(session_id, 0, mid - 1) == mid) {
      lo = mid;
    } else {
      hi = mid - 1;
    }
  }
  return lo;
}

}  // namespace telehand::server::store
