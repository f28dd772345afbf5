#include "telehand/server/session/replay.h"

#include <spdlog/spdlog.h>

#include <algorithm>

#include "telehand/core/error.h"
#include "telehand/core/thimble.h"
#include "telehand/server/session/session_manager.h"

namespace telehand::server::session {

Replay::Replay(SessionContext& ctx, uint64_t publish_as, uint64_t source,
               const JointModelParams& model, const sim::HandModel* hand,
               const sim::HandSimConfig& hand_config, int64_t now_ns)
    : ctx_(ctx),
      publish_as_(publish_as),
      source_(source),
      initial_(model),
      hand_model_(hand),
      hand_config_(hand_config),
      params_(model),
      model_(model),
      last_tick_ns_(now_ns) {
  // The record's extent, from its first and last rows (nothing in between is read here).
  const auto extent = ctx.store.extent(source);
  empty_ = !extent;
  if (extent) {
    first_seq_ = extent->first_seq;
    last_seq_ = extent->last_seq;
    duration_s_ = static_cast<double>(extent->last_time_ns - extent->first_time_ns) * 1e-9;
  }
  restart();
}

void Replay::restart() {
  const uint64_t seq = hand_ ? hand_->published() : 0;  // a loop goes on numbering
  params_ = initial_;
  model_ = JointModel(params_);
  live_ = std::make_unique<LiveStream>(last_tick_ns_);
  hand_ = std::make_unique<HandRunner>(publish_as_, hand_model_, params_, hand_config_, 0.0,
                                       last_tick_ns_);
  hand_->continueSeq(seq);
  page_.clear();
  page_pos_ = 0;
  next_seq_ = first_seq_;
  have_first_ = false;
  position_s_ = 0.0;
  finished_ = empty_;
}

void Replay::play(int64_t now_ns) noexcept {
  last_tick_ns_ = now_ns;
  playing_ = !finished_;
}

void Replay::pause(int64_t now_ns) noexcept {
  last_tick_ns_ = now_ns;
  playing_ = false;
}

double Replay::setSpeed(double speed, int64_t now_ns) noexcept {
  speed_ = std::isfinite(speed) ? std::clamp(speed, kMinSpeed, kMaxSpeed) : 1.0;
  last_tick_ns_ = now_ns;
  return speed_;
}

bool Replay::loadPage() {
  page_.clear();
  page_pos_ = 0;
  if (next_seq_ > last_seq_) return false;
  // A gap in the record is stepped over at once (an index look-up), however wide.
  const std::optional<uint64_t> stored = ctx_.store.nextStoredSeq(source_, next_seq_);
  if (!stored || *stored > last_seq_) {
    next_seq_ = last_seq_ + 1;
    return false;
  }
  const uint64_t from = *stored;
  const uint64_t to = from + kPage - 1;
  ctx_.store.forEachSampleIn(source_, from, to, [&](const Sample& s, bool valid) {
    if (valid) page_.push_back(s);  // an invalid sample is not replayed (nor was it live)
  });
  next_seq_ = to + 1;
  return true;
}

void Replay::tick(int64_t now_ns) {
  if (playing_) {
    position_s_ +=
        static_cast<double>(std::max<int64_t>(now_ns - last_tick_ns_, 0)) * 1e-9 * speed_;
    last_tick_ns_ = now_ns;
    // Every sample whose record time has come steps the hand, in order.
    for (;;) {
      if (page_pos_ >= page_.size()) {
        bool more = false, read_all = false;
        for (int pages = 0; !more && pages < kMaxPagesPerTick; ++pages) {
          if (!loadPage()) {
            read_all = true;
            break;
          }
          more = !page_.empty();
        }
        if (!more && !read_all) break;  // a gap in the record: read on next tick
        if (!more) {
          if (loop_) {  // from the start, on a fresh hand: the same states again
            restart();
            break;
          }
          finished_ = true;
          playing_ = false;
          break;
        }
      }
      const Sample& d = page_[page_pos_];
      if (!have_first_) {
        first_time_ns_ = d.source_time_ns;
        have_first_ = true;
      }
      if (static_cast<double>(d.source_time_ns - first_time_ns_) * 1e-9 > position_s_) break;
      ++page_pos_;
      // As Session::onLive does for a live sample (every sample is here: none coded).
      const PerFinger<Vec3> grip = thimblePositions(d);
      Vec3 before = Vec3::Zero();
      if (hand_->simulated() && live_->isNew(d) &&
          hand_->advance(ctx_, d, grip,
                         std::min<uint64_t>(live_->ticksTo(d), SessionManager::kMaxCatchUpSteps),
                         false, model_, telehand_msg_MODE_MOBILIZATION, &before)) {
        ++params_.version;
        params_.grip_offset_rad = hand_->drift().offset();
        model_ = JointModel(params_);
        hand_->setModel(params_);
      }
      live_->accept(d, false);
      ++stepped_;
      if (on_step) on_step(d, *hand_);
    }
  }
  live_->updateRate(now_ns);
  hand_->publishDue(ctx_, *live_, model_, now_ns);
}

}  // namespace telehand::server::session
