#include "telehand/server/session/recorder.h"

#include <spdlog/spdlog.h>

#include "telehand/core/clock.h"
#include "telehand/core/error.h"

namespace telehand::server::session {

void Recorder::store(SessionContext& ctx, std::vector<Sample>&& samples,
                     std::vector<uint8_t>&& valid) {
  pending_.insert(pending_.end(), samples.begin(), samples.end());
  pending_valid_.insert(pending_valid_.end(), valid.begin(), valid.end());
  if (pending_.empty()) return;
  try {
    const uint64_t added = ctx.store.appendSamples(session_id_, pending_, pending_valid_);
    recorded_ += added;
    ctx.stats.recorded_samples += added;
    pending_.clear();
    pending_valid_.clear();
  } catch (const StoreError& e) {
    ++ctx.stats.store_errors;
    spdlog::error("session {}: {} ({} samples kept in memory, retrying)", session_id_, e.what(),
                  pending_.size());
  }
}

void Recorder::invalidSample(SessionContext& ctx, uint64_t client_id, const Sample& d,
                             const std::string& field, int64_t now_ns) {
  ++ctx.stats.nonfinite_samples;
  ++nonfinite_;
  if (now_ns - nonfinite_reported_ns_ <= 5 * kNsPerS) return;
  nonfinite_reported_ns_ = now_ns;
  ctx.event(session_id_, client_id, telehand_msg_EVENT_ERROR,
            "DeviceState seq " + std::to_string(d.seq) + " has a " + field +
                "; not used for the hand state (" + std::to_string(nonfinite_) + " so far)",
            now_ns);
}

}  // namespace telehand::server::session
