#include "replay_hand.h"

#include <spdlog/fmt/fmt.h>

#include <algorithm>
#include <chrono>
#include <cmath>

#include "telehand/config/config.h"
#include "telehand/core/error.h"
#include "telehand/server/session/replay.h"
#include "telehand/server/session/session.h"
#include "telehand/server/store/open_store.h"

namespace telehand::web {

namespace {

using server::store::SessionStore;

/// The replay's messages: its HandStates to `on_frame`, nothing else leaves.
class FrameOutbox final : public server::session::Outbox {
 public:
  explicit FrameOutbox(const std::function<void(const telehand_msg_HandState&)>& on_frame)
      : on_frame_(on_frame) {}
  void publish(const telehand_msg_SessionStatus&) override {}
  void publish(const telehand_msg_JointModel&) override {}
  void publish(const telehand_msg_SessionEvent&) override {}
  void publish(const telehand_msg_HandState& h) override {
    telehand_msg_HandState f = h;
    f.source_time_ns = f.device_time_ns;  // record time: the replay has no wall clock of its own
    ++frames;
    last_device_ns = f.device_time_ns;
    on_frame_(f);
  }
  std::size_t frames = 0;
  int64_t last_device_ns = 0;

 private:
  const std::function<void(const telehand_msg_HandState&)>& on_frame_;
};

/// The patient case the session ran on, found as the server finds it (SessionManager).
PatientCase caseNamed(const std::string& cases_dir, const std::string& name) {
  if (!cases_dir.empty()) return loadPatientCaseByName(cases_dir, name);
  if (name != "healthy") throw ConfigError("unknown patient case '" + name + "' (known: healthy)");
  PatientCase p;
  p.name = "healthy";
  p.model = healthyIndexMcp();
  return p;
}

}  // namespace

ReplayHandResult replayHand(const std::string& db, uint64_t session,
                            const server::sim::HandModel& hand, const ReplayHandOptions& o,
                            const std::function<void(const telehand_msg_HandState&)>& on_frame,
                            const std::function<bool(double done_s)>& keep_going) {
  ReplayHandResult r;
  const auto t0 = std::chrono::steady_clock::now();
  auto done = [&] {
    r.compute_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return r;
  };
  try {
    const auto opened = server::store::openStore(db, SessionStore::Mode::kReadOnly);
    SessionStore& store = *opened;
    const auto info = store.session(session);
    if (!info) {
      r.error = fmt::format("no session {} in the record", session);
      return done();
    }
    r.case_name = info->case_name;
    if (info->mode == "replay") {
      r.error = "a replay's record has no samples of its own";
      return done();
    }
    const auto extent = store.extent(session);
    if (!extent) {
      r.error = fmt::format("session {} has no samples", session);
      return done();
    }
    // A record whose sequence numbers leave gaps far wider than its samples would have the
    // replay read page after empty page (the server writes none such).
    if (extent->last_seq - extent->first_seq > 16 * info->samples + 1'000'000) {
      r.error = fmt::format("session {}'s sample numbers span {} for {} samples", session,
                            extent->last_seq - extent->first_seq + 1, info->samples);
      return done();
    }
    r.duration_s = static_cast<double>(extent->last_time_ns - extent->first_time_ns) * 1e-9;
    const PatientCase patient = caseNamed(o.cases_dir, info->case_name);

    // The rate: hz, lowered (to min_hz at most) so that the whole record fits max_frames;
    // a whole number of milliseconds per frame. Then as much of the record as the bounds let.
    const double hz = std::clamp(o.hz, 0.1, 1000.0);
    const std::size_t max_frames = std::max<std::size_t>(o.max_frames, 2);
    const double want_hz =
        std::clamp(std::min(hz, static_cast<double>(max_frames) / std::max(r.duration_s, 1e-3)),
                   std::min(o.min_hz, hz), hz);
    const int64_t period_ms = std::max<int64_t>(1, std::llround(std::ceil(1000.0 / want_hz)));
    r.hz = 1000.0 / static_cast<double>(period_ms);
    const double cover_s = std::min(o.max_s, static_cast<double>(max_frames - 1) / r.hz);

    // The server's own replay (Session::startReplay), publishing every period of record.
    ServerConfig config;
    config.hand_state_hz = r.hz;
    FrameOutbox out(on_frame);
    server::session::ManagerStats stats;
    server::session::SessionContext ctx{
        store, out, config, stats,
        [](uint64_t, uint64_t, telehand_msg_EventKind, const std::string&, int64_t) {}};
    JointModelParams start = server::session::openingModel(patient);
    start.guide = GuideParams{};
    // Each tick half a millisecond past the frame's time: the sample of that millisecond is due
    // however the replay's position adds up, and the next one is not.
    int64_t now_ns = 0;
    server::session::Replay replay(ctx, session, session, start, &hand,
                                   server::sim::HandSimConfig{}, now_ns);
    replay.setSpeed(1.0, now_ns);
    replay.play(now_ns);
    const int64_t period_ns = period_ms * 1'000'000;
    now_ns = 500'000;
    for (;;) {
      replay.tick(now_ns);  // steps every sample due by now, then publishes one HandState
      if (replay.finished()) break;
      if (replay.positionS() >= cover_s || out.frames >= max_frames) {
        r.cut = true;
        break;
      }
      if (!keep_going(replay.positionS())) {
        r.cancelled = true;
        break;
      }
      now_ns += period_ns;
    }
    r.ok = true;
    r.frames = out.frames;
    r.samples = replay.stepped();
    r.simulated_s =
        out.frames ? static_cast<double>(out.last_device_ns - extent->first_time_ns) * 1e-9 : 0.0;
  } catch (const std::exception& e) {
    r.ok = false;
    r.error = e.what();
  }
  return done();
}

}  // namespace telehand::web
