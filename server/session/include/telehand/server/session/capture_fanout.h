#pragma once
/// A capture session's live refit and the sessions that feel it: each new fit becomes the
/// capture's model and every follower's, with the k-nearest-neighbour samples sent first to
/// followers that render them. A follower's side holds which capture it follows.
#include <cstdint>
#include <functional>
#include <memory>
#include <utility>
#include <vector>

#include "telehand/core/knn_model.h"
#include "telehand/core/sample.h"
#include "telehand/server/estimate/live_refit.h"
#include "telehand/server/session/session_context.h"

namespace telehand::server::session {

class Session;

class CaptureFanout {
 public:
  /// Fit the capture's joint live from its record, starting from `params`.
  void startRefit(const JointModelParams& params, const estimate::LiveRefitOptions& options);
  bool capturing() const noexcept { return refit_ != nullptr; }
  /// Recorded samples, in record order, for the live fit.
  void add(const std::vector<Sample>& samples, const std::vector<uint8_t>& valid, int64_t now_ns);
  /// Publish a new fit, if there is one, to the capture `self` and its followers (`find`
  /// looks a session up by id; null when it has gone).
  void refit(SessionContext& ctx, Session& self, const std::function<Session*(uint64_t)>& find,
             const KnnOptions& knn_options, int64_t now_ns);

  /// This session renders the live fit of capture `capture_id`.
  void follow(uint64_t capture_id, bool wants_knn) noexcept {
    follows_ = capture_id;
    wants_knn_ = wants_knn;
  }
  uint64_t follows() const noexcept { return follows_; }
  /// The capture closed: keep the last model it sent.
  void unfollow() noexcept { follows_ = 0; }
  bool wantsKnn() const noexcept { return wants_knn_; }

  void addFollower(uint64_t id) { followers_.push_back(id); }
  void removeFollower(uint64_t id) { std::erase(followers_, id); }
  /// The followers, now no longer this session's.
  std::vector<uint64_t> takeFollowers() { return std::exchange(followers_, {}); }

 private:
  std::unique_ptr<estimate::LiveRefit> refit_;
  std::vector<uint64_t> followers_;
  uint64_t follows_ = 0;  // the capture session this one renders
  bool wants_knn_ = false;
};

}  // namespace telehand::server::session
