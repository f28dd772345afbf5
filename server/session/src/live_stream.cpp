#include "telehand/server/session/live_stream.h"

#include "telehand/core/clock.h"

namespace telehand::server::session {

void LiveStream::accept(const Sample& d, bool coded) noexcept {
  deadband_coded_ = coded;
  if (!coded && have_ && d.seq > last_.seq + 1) lost_ += d.seq - last_.seq - 1;
  if (!have_ || d.seq > last_.seq) {
    if (d.flags & sample_flags::kLoopOverrun) ++overruns_;
    last_ = d;
  }
  have_ = true;
  ++count_;
}

void LiveStream::updateRate(int64_t now_ns) noexcept {
  if (now_ns - rate_window_ns_ < kNsPerS / 2) return;
  rate_hz_ = static_cast<float>(static_cast<double>(count_ - rate_window_count_) /
                                (static_cast<double>(now_ns - rate_window_ns_) * 1e-9));
  rate_window_ns_ = now_ns;
  rate_window_count_ = count_;
}

}  // namespace telehand::server::session
