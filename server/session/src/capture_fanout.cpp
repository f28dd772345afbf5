#include "telehand/server/session/capture_fanout.h"

#include <algorithm>
#include <cstdio>
#include <string>

#include "telehand/core/clock.h"
#include "telehand/protocol/wire.h"
#include "telehand/server/session/session.h"

namespace telehand::server::session {

void CaptureFanout::startRefit(const JointModelParams& params,
                               const estimate::LiveRefitOptions& options) {
  refit_ =
      std::make_unique<estimate::LiveRefit>(estimate::captureGeometry(params), params, options);
}

void CaptureFanout::add(const std::vector<Sample>& samples, const std::vector<uint8_t>& valid,
                        int64_t now_ns) {
  if (!refit_) return;
  for (std::size_t i = 0; i < samples.size(); ++i) refit_->add(samples[i], valid[i] != 0, now_ns);
}

void CaptureFanout::refit(SessionContext& ctx, Session& self,
                          const std::function<Session*(uint64_t)>& find,
                          const KnnOptions& knn_options, int64_t now_ns) {
  auto u = refit_->poll(now_ns);
  if (!u) return;
  self.adoptModel(u->params, nullptr);
  ManagerStats& stats = ctx.stats;
  ++stats.live_models;
  stats.last_refit_latency_ns = now_ns - u->newest_arrival_ns;
  stats.max_refit_latency_ns = std::max(stats.max_refit_latency_ns, stats.last_refit_latency_ns);
  std::string fitted;
  for (std::size_t i = 0; i < kAxes; ++i) {
    const auto& a = u->fit.axes[i];
    if (!a.ok) continue;
    char b[96];
    std::snprintf(b, sizeof b, "%s%s %.0f..%.0f deg RMS %.2f N", fitted.empty() ? "" : ", ",
                  kAxisNames[i].data(), a.curve.min_deg, a.curve.max_deg, a.rms_n);
    fitted += b;
  }
  char text[256];
  std::snprintf(text, sizeof text, "live fit v%u from %zu samples (change %.1f N): %s",
                self.params.version, refit_->samples(), u->max_change_n, fitted.c_str());
  ctx.event(self.info.id, 0, telehand_msg_EVENT_INFO, text, now_ns);

  std::shared_ptr<const KnnTorqueModel> knn;  // one model for every follower that renders it
  for (uint64_t id : followers_) {
    Session* f = find(id);
    if (!f) continue;
    JointModelParams p = u->params;
    p.version = f->params.version + 1;  // adoptModel's, for the KnnModel that goes first
    p.case_name = f->params.case_name;
    if (f->capture.wantsKnn() && !u->knn_points.empty()) {
      if (!knn) knn = std::make_shared<const KnnTorqueModel>(u->knn_points, knn_options);
      p.knn = knn.get();
      std::vector<telehand_msg_KnnSample> wire;
      telehand_msg_KnnModel k{};
      toWire(*knn, f->info.id, p.version, wire, k);
      k.source_time_ns = wallNs();
      ctx.out.publish(k);  // before its JointModel: a client waits for both
      f->adoptModel(p, knn);
    } else {
      p.knn = nullptr;
      f->adoptModel(p, nullptr);
    }
  }
}

}  // namespace telehand::server::session
