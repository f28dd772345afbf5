#pragma once
// What telehand-watch knows: its options, the limits it works within, and each session as
// far as it has arrived.
#include <spdlog/fmt/fmt.h>

#include <algorithm>
#include <chrono>
#include <climits>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <ctime>
#include <deque>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "telehand/core/clock.h"
#include "telehand/core/printable.h"
#include "telehand/protocol/dds.h"
#include "telehand/protocol/wire.h"

namespace telehand::client::watch {

constexpr int64_t kStaleNs = 500 * kNsPerMs;  // older than this, a view is shown STALE
constexpr int64_t kRateWindowNs = kNsPerS;
// The transient-local histories arrive in bursts after discovery, one per writer and in no
// particular order across sessions: give them this long once a session is found before
// choosing, or an older session could win, and a session that already closed would be
// reported without its model and events.
constexpr int64_t kSettleNs = 300 * kNsPerMs;
// HandState is keep-last 1. A reader that shallow turns any hiccup of this process into
// "gaps" that never happened on the link; a short reader history keeps the count honest.
constexpr int32_t kHandReaderDepth = 16;
constexpr std::size_t kEventsKept = 64;  // per session, as deep as the writer's history
constexpr std::size_t kEventsShown = 5;
constexpr int kBarCells = 32;
constexpr std::size_t kTakeAll = SIZE_MAX;
constexpr int64_t kPlausibleDelayNs = 60 * kNsPerS;

struct Options {
  dds::Options dds;
  uint64_t session = 0;  ///< 0 = the most recently started ACTIVE session
  double refresh_hz = 10.0;
  double band_min_n = 12.0;  ///< reference band, N at reference scale (paper: 12-16 N)
  double band_max_n = 16.0;
  double seconds = 0.0;  ///< 0 = until Ctrl-C or the session closes
  double wait_s = 10.0;
  bool exit_on_close = false;
  bool plain = false;
  /// --replay: replay this recorded session (the server publishes it as a session of its
  /// own) and watch that, at `speed`, looping with `loop`.
  uint64_t replay = 0;
  double speed = 1.0;
  bool loop = false;
};

struct EventLine {
  uint64_t arrival = 0;  ///< order of receipt, to print each event once in --plain
  uint64_t session_id = 0;
  uint64_t seq = 0;     ///< the server's event counter: orders events stamped the same ns
  int64_t time_ns = 0;  ///< server wall clock
  telehand_msg_EventKind kind = telehand_msg_EVENT_INFO;
  std::string text;
};
inline bool before(const EventLine& a, const EventLine& b) {
  return a.time_ns != b.time_ns ? a.time_ns < b.time_ns : a.seq < b.seq;
}

/// What the watcher knows of one session from what has arrived so far.
struct SessionView {
  std::optional<telehand_msg_SessionStatus> status;
  std::optional<telehand_msg_JointModel> model;  ///< newest version
  uint64_t models = 0;                           ///< JointModel samples received
  std::optional<telehand_msg_HandState> hand;    ///< newest by seq
  uint64_t hand_states = 0;
  uint64_t hand_gaps = 0;       ///< seqs skipped (lost on the link or overwritten)
  uint64_t hand_reordered = 0;  ///< arrived after a newer one; not shown
  int64_t first_hand_rx_ns = 0;
  int64_t hand_rx_ns = 0;        ///< steady clock at receipt of `hand`
  int64_t hand_delay_ns = 0;     ///< server source time -> receipt, wall clocks
  int64_t device_delay_ns = 0;   ///< device sample time -> receipt, wall clocks; 0 = unknown
  std::deque<int64_t> hand_rx;   ///< receipt times within the last kRateWindowNs
  std::deque<EventLine> events;  ///< oldest first, at most kEventsKept
  uint64_t events_seen = 0;
};

/// A value for a --plain key=value field: no spaces, never empty.
inline std::string token(std::string s) {
  std::replace(s.begin(), s.end(), ' ', '_');
  return s.empty() ? "-" : s;
}

inline std::string clockTime(int64_t wall_ns) {
  const time_t secs = static_cast<time_t>(wall_ns / kNsPerS);
  tm t{};
  localtime_r(&secs, &t);
  return fmt::format("{:02}:{:02}:{:02}.{:03}", t.tm_hour, t.tm_min, t.tm_sec,
                     (wall_ns % kNsPerS) / kNsPerMs);
}

inline double ms(int64_t ns) { return static_cast<double>(ns) / 1e6; }
/// Capped at ~30 years so that a huge --seconds or --wait cannot overflow a deadline.
inline int64_t secondsToNs(double s) { return static_cast<int64_t>(std::min(s, 1e9) * 1e9); }
inline double norm3(const double (&v)[3]) {
  return std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}

}  // namespace telehand::client::watch
