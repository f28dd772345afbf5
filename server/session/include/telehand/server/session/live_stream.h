#pragma once
/// A session's live DeviceState intake: the newest sample, link health (samples lost on the
/// way, the rate received) and when data last arrived.
#include <cstdint>

#include "telehand/core/sample.h"

namespace telehand::server::session {

class LiveStream {
 public:
  explicit LiveStream(int64_t now_ns) noexcept : last_data_ns_(now_ns), rate_window_ns_(now_ns) {}

  /// Data of any kind (live or record) arrived: the session is not idle.
  void touch(int64_t now_ns) noexcept { last_data_ns_ = now_ns; }
  int64_t idleNs(int64_t now_ns) const noexcept { return now_ns - last_data_ns_; }

  /// Newer than every sample taken so far (or the first).
  bool isNew(const Sample& d) const noexcept { return !have_ || d.seq > last_.seq; }
  /// Device ticks from the newest sample to `d` (1 for the first).
  uint64_t ticksTo(const Sample& d) const noexcept { return have_ ? d.seq - last_.seq : 1; }
  /// Take a finite live sample; `coded`: the client withholds samples inside its deadband
  /// (a gap is then not a loss).
  void accept(const Sample& d, bool coded) noexcept;
  /// Refresh the received rate every half second.
  void updateRate(int64_t now_ns) noexcept;

  bool have() const noexcept { return have_; }
  const Sample& last() const noexcept { return last_; }
  uint64_t count() const noexcept { return count_; }
  uint64_t lost() const noexcept { return lost_; }
  /// Samples flagged sample_flags::kLoopOverrun: the client's loop ran late before them. The
  /// flag always goes out live (docs/teleoperation.md "Deadband"); a sample lost on the way
  /// is not counted (the record has every one).
  uint64_t overruns() const noexcept { return overruns_; }
  float rateHz() const noexcept { return rate_hz_; }
  bool deadbandCoded() const noexcept { return deadband_coded_; }
  /// The samples the client has sent by the newest one received, or `none` without any.
  uint64_t sentOr(uint64_t none) const noexcept { return have_ ? last_.seq + 1 : none; }

 private:
  bool have_ = false;
  Sample last_{};
  uint64_t count_ = 0;
  uint64_t lost_ = 0;
  uint64_t overruns_ = 0;
  bool deadband_coded_ = false;
  int64_t last_data_ns_ = 0;
  int64_t rate_window_ns_ = 0;
  uint64_t rate_window_count_ = 0;
  float rate_hz_ = 0.0f;
};

}  // namespace telehand::server::session
