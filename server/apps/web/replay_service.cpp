#include "replay_service.h"

#include <spdlog/fmt/fmt.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <iterator>
#include <memory>
#include <optional>

#include "frames.h"
#include "telehand/server/store/open_store.h"

namespace telehand::web {

namespace {

/// Frames a chunk carries (2 s of record at 50/s): the page poses what it has while the rest
/// is computed.
constexpr std::size_t kChunk = 100;

/// The record as it stands (the cache's key), nullopt when it cannot be read (replayHand then
/// says why).
std::optional<RecordKey> recordKey(const std::string& db, uint64_t session) {
  try {
    const auto store = server::store::openStore(db, server::store::SessionStore::Mode::kReadOnly);
    const auto info = store->session(session);
    const auto extent = store->extent(session);
    if (!info || !extent) return std::nullopt;
    return RecordKey{session, info->samples, extent->last_seq};
  } catch (const std::exception&) {
    return std::nullopt;
  }
}

std::string endFrame(uint64_t session, const ReplayHandResult& r, const ReplayHandOptions& o,
                     bool cached) {
  std::string message;
  if (!r.ok) {
    message = "no hand for this replay: " + r.error;
  } else if (r.cut) {
    message = fmt::format(
        "the hand covers the first {:.1f} s of the record's {:.1f} s (at most {:.0f} s and {} "
        "frames of a record are simulated: --replay-hand-s)",
        r.simulated_s, r.duration_s, o.max_s, o.max_frames);
  } else {
    message = fmt::format("the hand over the whole record ({:.1f} s, {} frames at {:g}/s)",
                          r.duration_s, r.frames, r.hz);
  }
  return fmt::format(R"({{"type":"replay_hand_end","session":{},"ok":{},"frames":{},"hz":{},)"
                     R"("case":{},"duration_s":{:.3f},"simulated_s":{:.3f},"cut":{},)"
                     R"("compute_s":{:.3f},"cached":{},"message":{}}})",
                     session, r.ok, r.frames, jsonNumber(r.hz), jsonString(r.case_name),
                     r.duration_s, r.simulated_s, r.cut, r.compute_s, cached, jsonString(message));
}

}  // namespace

ReplayHandService::ReplayHandService(std::string db, const server::sim::HandModel& hand,
                                     const ReplayHandOptions& options, std::size_t jobs,
                                     std::size_t cache_bytes)
    : db_(std::move(db)),
      hand_(hand),
      options_(options),
      jobs_(std::max<std::size_t>(jobs, 1)),
      cache_(cache_bytes) {}

void ReplayHandService::run(uint64_t session, const std::function<void(std::string)>& push,
                            const std::function<bool()>& stopped) {
  // A record computed before, unchanged since: sent as it was.
  const std::optional<RecordKey> key = recordKey(db_, session);
  auto fromCache = [&] {
    const auto hit = key ? cache_.find(*key) : nullptr;
    if (!hit) return false;
    for (const auto& chunk : hit->chunks) push(chunk);
    ++cached;
    push(endFrame(session, hit->result, options_, true));
    return true;
  };
  if (fromCache()) return;
  // One core each: the rest wait their turn, saying so.
  {
    std::unique_lock lk(jobs_mutex_);
    bool told = false;
    while (running_ >= jobs_) {
      if (!told) {
        told = true;
        lk.unlock();
        push(fmt::format(R"({{"type":"replay_hand","session":{},"queued":true,"done_s":0,)"
                         R"("frames":[]}})",
                         session));
        lk.lock();
        continue;
      }
      jobs_cv_.wait_for(lk, std::chrono::milliseconds(100));
      if (stopped()) return;
    }
    ++running_;
  }
  struct Turn {
    ReplayHandService& s;
    ~Turn() {
      {
        std::lock_guard lk(s.jobs_mutex_);
        --s.running_;
      }
      s.jobs_cv_.notify_all();
    }
  } turn{*this};
  if (fromCache()) return;  // computed while this one waited

  auto computed = std::make_shared<ComputedHand>();
  std::string chunk;
  std::size_t in_chunk = 0, sent = 0;
  auto flush = [&](double done_s) {
    if (in_chunk == 0) return;
    fmt::format_to(std::back_inserter(chunk), R"(],"done_s":{:.3f}}})", done_s);
    computed->bytes += chunk.size();
    computed->chunks.push_back(chunk);
    push(std::move(chunk));
    chunk.clear();
    sent += in_chunk;
    frames += in_chunk;
    in_chunk = 0;
  };
  const ReplayHandResult r = replayHand(
      db_, session, hand_, options_,
      [&](const telehand_msg_HandState& h) {
        if (in_chunk == 0) {
          chunk = fmt::format(R"({{"type":"replay_hand","session":{},"first":{},"frames":[)",
                              session, sent);
        } else {
          chunk += ',';
        }
        chunk += handFrame(h, h.device_time_ns);
        ++in_chunk;
      },
      [&](double done_s) {
        if (in_chunk >= kChunk) flush(done_s);
        return !stopped();
      });
  flush(r.simulated_s);
  if (r.cancelled) return;  // a newer replay, or the browser is gone
  if (r.ok) {
    ++hands;
    spdlog::info(
        "replay of session {}: {} hand frames at {:g}/s over {:.1f} of {:.1f} s, "
        "computed in {:.2f} s",
        session, r.frames, r.hz, r.simulated_s, r.duration_s, r.compute_s);
    computed->result = r;
    if (key) cache_.put(*key, std::move(computed));
  } else {
    spdlog::warn("replay of session {}: no hand: {}", session, r.error);
  }
  push(endFrame(session, r, options_, false));
}

}  // namespace telehand::web
