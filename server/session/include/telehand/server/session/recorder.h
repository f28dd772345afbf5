#pragma once
/// A session's record: every sample stored once, what the store refused kept and retried,
/// and the live samples that were not finite counted and reported.
#include <cstdint>
#include <string>
#include <vector>

#include "telehand/core/sample.h"
#include "telehand/server/session/session_context.h"

namespace telehand::server::session {

class Recorder {
 public:
  explicit Recorder(uint64_t session_id) noexcept : session_id_(session_id) {}

  /// Append to the record, after whatever is still pending (kept on a store error).
  void store(SessionContext& ctx, std::vector<Sample>&& samples, std::vector<uint8_t>&& valid);
  /// Retry what the store refused before.
  void retry(SessionContext& ctx) {
    if (!pending_.empty()) store(ctx, {}, {});
  }
  bool drained() const noexcept { return pending_.empty(); }
  uint64_t recorded() const noexcept { return recorded_; }

  /// A live sample no device could have sent (`why`: firstInvalid's description): counted,
  /// reported at most once per 5 s.
  void invalidSample(SessionContext& ctx, uint64_t client_id, const Sample& d,
                     const std::string& why, int64_t now_ns);
  uint64_t nonfinite() const noexcept { return nonfinite_; }

 private:
  uint64_t session_id_;
  uint64_t recorded_ = 0;
  std::vector<Sample> pending_;  // not yet stored (store error): retried
  std::vector<uint8_t> pending_valid_;
  uint64_t nonfinite_ = 0;
  int64_t nonfinite_reported_ns_ = INT64_MIN / 2;
};

}  // namespace telehand::server::session
