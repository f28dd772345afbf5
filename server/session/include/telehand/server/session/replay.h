#pragma once
/// A recorded session replayed at real time (docs/lessons.md "Watch"): its samples, read from
/// the record a page at a time, step a hand of its own exactly as the live samples stepped the
/// session's hand (HandRunner::advance, on device time), and that hand is published as
/// HandState under the session that asked for the replay: every viewer shows a replay as it
/// shows a live session. Deterministic: the same record gives the same states whatever the
/// speed, the pauses or the machine. Pause, speed 0.25-2x, loop.
#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

#include "telehand/config/config.h"
#include "telehand/core/joint_model.h"
#include "telehand/server/session/hand_runner.h"
#include "telehand/server/session/live_stream.h"
#include "telehand/server/session/session_context.h"
#include "telehand/server/sim/hand_model.h"

namespace telehand::server::session {

class Replay {
 public:
  static constexpr double kMinSpeed = 0.25, kMaxSpeed = 2.0;
  /// Samples read from the record at a time.
  static constexpr uint64_t kPage = 1000;
  /// Pages read in one tick at most: a record with gaps (sequence numbers far apart) is
  /// read through them over several ticks, never stalling the serve loop on empty pages.
  static constexpr int kMaxPagesPerTick = 8;
  /// Replays `source` (its record in ctx.store, rendered on `model`) as session
  /// `publish_as`; starts paused at the beginning until play().
  Replay(SessionContext& ctx, uint64_t publish_as, uint64_t source, const JointModelParams& model,
         const sim::HandModel* hand, const sim::HandSimConfig& hand_config, int64_t now_ns);
  void play(int64_t now_ns) noexcept;
  void pause(int64_t now_ns) noexcept;
  /// Clamped to [kMinSpeed, kMaxSpeed]; returns the speed set.
  double setSpeed(double speed, int64_t now_ns) noexcept;
  void setLoop(bool loop) noexcept { loop_ = loop; }
  bool playing() const noexcept { return playing_; }
  /// Played to the end (and not looping).
  bool finished() const noexcept { return finished_; }
  /// Step the hand over every sample due by now, publish a HandState when one is due.
  void tick(int64_t now_ns);
  /// Seconds of record played so far (record time).
  double positionS() const noexcept { return position_s_; }
  double durationS() const noexcept { return duration_s_; }
  uint64_t stepped() const noexcept { return stepped_; }
  /// HandStates published so far (their sequence continues the session's, see continueSeq).
  uint64_t published() const noexcept { return hand_->published(); }
  void continueSeq(uint64_t next) noexcept { hand_->continueSeq(next); }
  /// Called for every sample after the hand stepped to it (tests compare the states).
  std::function<void(const Sample&, const HandRunner&)> on_step;

 private:
  void restart();
  bool loadPage();
  SessionContext& ctx_;
  uint64_t publish_as_, source_;
  JointModelParams initial_;
  const sim::HandModel* hand_model_;
  sim::HandSimConfig hand_config_;
  JointModelParams params_;
  JointModel model_;
  std::unique_ptr<LiveStream> live_;
  std::unique_ptr<HandRunner> hand_;
  std::vector<Sample> page_;
  std::size_t page_pos_ = 0;
  uint64_t first_seq_ = 0;
  uint64_t next_seq_ = 0;  // the first sequence number the next page starts at
  uint64_t last_seq_ = 0;  // the record's last
  int64_t first_time_ns_ = 0;
  bool have_first_ = false;
  double duration_s_ = 0.0;
  double position_s_ = 0.0;
  double speed_ = 1.0;
  bool playing_ = false, loop_ = false, finished_ = false, empty_ = false;
  int64_t last_tick_ns_ = 0;
  uint64_t stepped_ = 0;
};

}  // namespace telehand::server::session
