// telehand-watch: the supervisor's live view of one session. It may join at any time:
// SessionStatus, JointModel and SessionEvent are transient-local, so a late joiner learns
// which sessions exist, the model in force and the recent events at once; HandState
// (best-effort, volatile) then streams the live hand. The screen is redrawn at --refresh-hz
// (>= 5 Hz); --plain, automatic when stdout is not a terminal, prints one greppable
// key=value line per refresh instead.
#include <spdlog/fmt/fmt.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <climits>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <deque>
#include <iostream>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "telehand/core/clock.h"
#include "telehand/protocol/dds.h"
#include "telehand/core/error.h"
#include "telehand/core/log.h"
#include "telehand/protocol/wire.h"

namespace telehand::client::watch {
namespace {

std::atomic<bool> g_stop{false};
void onSignal(int) { g_stop.store(true); }

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
};

struct EventLine {
  uint64_t arrival = 0;  ///< order of receipt, to print each event once in --plain
  uint64_t session_id = 0;
  uint64_t seq = 0;     ///< the server's event counter: orders events stamped the same ns
  int64_t time_ns = 0;  ///< server wall clock
  telehand_msg_EventKind kind = telehand_msg_EVENT_INFO;
  std::string text;
};
bool before(const EventLine& a, const EventLine& b) {
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

/// Text from the network made safe to print: bounded, and control characters replaced so a
/// name or an event cannot move the cursor or recolour the supervisor's terminal.
std::string printable(const char* s, std::size_t max) {
  std::string out(s, strnlen(s, max));
  for (char& c : out) {
    if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) c = '?';
  }
  return out;
}
template <std::size_t N>
std::string printable(const char (&s)[N]) {
  return printable(s, N);
}

/// A value for a --plain key=value field: no spaces, never empty.
std::string token(std::string s) {
  std::replace(s.begin(), s.end(), ' ', '_');
  return s.empty() ? "-" : s;
}

std::string clockTime(int64_t wall_ns) {
  const time_t secs = static_cast<time_t>(wall_ns / kNsPerS);
  tm t{};
  localtime_r(&secs, &t);
  return fmt::format("{:02}:{:02}:{:02}.{:03}", t.tm_hour, t.tm_min, t.tm_sec,
                     (wall_ns % kNsPerS) / kNsPerMs);
}

double ms(int64_t ns) { return static_cast<double>(ns) / 1e6; }
/// Capped at ~30 years so that a huge --seconds or --wait cannot overflow a deadline.
int64_t secondsToNs(double s) { return static_cast<int64_t>(std::min(s, 1e9) * 1e9); }
double norm3(const double (&v)[3]) { return std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); }

enum class Band { kBelow, kIn, kAbove };
Band bandOf(double force_n, const Options& o) {
  if (force_n < o.band_min_n) return Band::kBelow;
  return force_n > o.band_max_n ? Band::kAbove : Band::kIn;
}
std::string_view bandName(Band b) {
  switch (b) {
    case Band::kBelow:
      return "below";
    case Band::kIn:
      return "in";
    case Band::kAbove:
      return "above";
  }
  return "-";
}

/// 0 .. 1.5 x band max, the band bracketed and dotted where not reached:
/// "|################[####..]          |"; '>' at the end when off the scale.
std::string bandBar(double force_n, const Options& o) {
  const double full = 1.5 * o.band_max_n;
  auto cell = [&](double f) { return static_cast<int>(std::floor(f / full * kBarCells)); };
  const int first = std::clamp(cell(o.band_min_n), 0, kBarCells - 1);
  const int last = std::clamp(static_cast<int>(std::ceil(o.band_max_n / full * kBarCells)) - 1,
                              first, kBarCells - 1);
  const int filled =
      std::clamp(static_cast<int>(std::lround(force_n / full * kBarCells)), 0, kBarCells);
  std::string bar = "|";
  for (int i = 0; i < kBarCells; ++i) {
    if (i == first) bar += '[';
    bar += i < filled ? '#' : (i >= first && i <= last ? '.' : ' ');
    if (i == last) bar += ']';
  }
  bar += force_n > full ? '>' : '|';
  return bar;
}

std::string_view sourceName(telehand_msg_HandSource s) {
  switch (s) {
    case telehand_msg_HAND_SOURCE_SHARED_JOINT_MODEL:
      return "shared joint model";
    case telehand_msg_HAND_SOURCE_BULLET:
      return "bullet";
  }
  return "unknown";
}

/// The DDS side: one reader per topic the supervisor needs, and what they have said so far,
/// for every session in the partition (the session to watch may be chosen later).
class Watcher {
 public:
  explicit Watcher(const dds::Options& options)
      : participant_(options),
        topics_(participant_),
        status_reader_(participant_, topics_.session_status, dds::qos::sessionStatus()),
        model_reader_(participant_, topics_.joint_model, dds::qos::jointModel()),
        hand_reader_(participant_, topics_.hand_state, dds::qos::handStateReader(kHandReaderDepth)),
        event_reader_(participant_, topics_.session_event, dds::qos::sessionEvent()),
        waitset_(participant_) {
    waitset_.attach(status_reader_.handle(), 1);
    waitset_.attach(model_reader_.handle(), 2);
    waitset_.attach(hand_reader_.handle(), 3);
    waitset_.attach(event_reader_.handle(), 4);
  }

  /// Sleeps until a reader has data or `timeout` passes.
  void wait(int64_t timeout_ns) {
    if (timeout_ns > 0) waitset_.wait(std::chrono::nanoseconds(timeout_ns));
  }

  /// Takes everything that arrived. `now_ns` is the steady clock.
  void poll(int64_t now_ns) {
    const int64_t wall_ns = wallNs();
    status_reader_.take([&](const telehand_msg_SessionStatus& s,
                            const dds_sample_info_t&) { sessions_[s.session_id].status = s; },
                        kTakeAll);
    model_reader_.take(
        [&](const telehand_msg_JointModel& m, const dds_sample_info_t&) {
          SessionView& v = sessions_[m.session_id];
          ++v.models;
          if (!v.model || m.version >= v.model->version) v.model = m;
        },
        kTakeAll);
    hand_reader_.take(
        [&](const telehand_msg_HandState& h, const dds_sample_info_t&) {
          onHand(sessions_[h.session_id], h, now_ns, wall_ns);
        },
        kTakeAll);
    event_reader_.take(
        [&](const telehand_msg_SessionEvent& e, const dds_sample_info_t&) { onEvent(e); },
        kTakeAll);
  }

  const SessionView* find(uint64_t id) const {
    const auto it = sessions_.find(id);
    return it == sessions_.end() || !it->second.status ? nullptr : &it->second;
  }

  /// The most recently started ACTIVE session; 0 when there is none.
  uint64_t mostRecentActive() const {
    uint64_t best = 0;
    int64_t best_started = INT64_MIN;
    for (const auto& [id, v] : sessions_) {
      if (!v.status || v.status->state != telehand_msg_SESSION_ACTIVE) continue;
      if (v.status->started_ns >= best_started) {
        best = id;
        best_started = v.status->started_ns;
      }
    }
    return best;
  }

  /// Sessions with a status, newest first: "7 active, 6 closed" or "none".
  std::string known() const {
    std::string out;
    int shown = 0;
    for (auto it = sessions_.rbegin(); it != sessions_.rend(); ++it) {
      if (!it->second.status) continue;
      if (shown++ == 10) return out + ", ...";
      out += fmt::format("{}{} {}", out.empty() ? "" : ", ", it->first,
                         stateName(it->second.status->state));
    }
    return out.empty() ? "none" : out;
  }

  /// Events of `session` and the server's errors not tied to a session, oldest first.
  std::vector<const EventLine*> eventsFor(uint64_t session) const {
    std::vector<const EventLine*> out;
    if (const auto it = sessions_.find(session); it != sessions_.end()) {
      for (const auto& e : it->second.events) out.push_back(&e);
    }
    if (const auto it = sessions_.find(0); session != 0 && it != sessions_.end()) {
      for (const auto& e : it->second.events) {
        if (e.kind == telehand_msg_EVENT_ERROR) out.push_back(&e);
      }
    }
    std::sort(out.begin(), out.end(),
              [](const EventLine* a, const EventLine* b) { return before(*a, *b); });
    return out;
  }

  /// Whether a server (the HandState writer) is matched right now.
  bool serverMatched() const noexcept { return hand_reader_.matchedWriters() > 0; }

 private:
  static void onHand(SessionView& v, const telehand_msg_HandState& h, int64_t now_ns,
                     int64_t wall_ns) {
    ++v.hand_states;
    if (v.hand && h.seq <= v.hand->seq) {
      ++v.hand_reordered;
      return;
    }
    if (v.hand && h.seq > v.hand->seq + 1) v.hand_gaps += h.seq - v.hand->seq - 1;
    v.hand = h;
    v.hand_rx_ns = now_ns;
    if (v.first_hand_rx_ns == 0) v.first_hand_rx_ns = now_ns;
    v.hand_delay_ns = wall_ns - h.source_time_ns;
    // device_time_ns should be the client's wall clock (IDL), but a client stamping with its
    // monotonic clock yields nonsense: show a delay only when it is plausible at all.
    const int64_t device_delay_ns = wall_ns - h.device_time_ns;
    v.device_delay_ns = h.device_time_ns > 0 && std::llabs(device_delay_ns) < kPlausibleDelayNs
                            ? device_delay_ns
                            : 0;
    v.hand_rx.push_back(now_ns);
    while (v.hand_rx.front() < now_ns - kRateWindowNs) v.hand_rx.pop_front();
  }

  void onEvent(const telehand_msg_SessionEvent& e) {
    SessionView& v = sessions_[e.session_id];
    ++v.events_seen;
    EventLine line{++arrivals_, e.session_id, e.seq, e.source_time_ns, e.kind, printable(e.text)};
    // One writer's events arrive in order, but a restarted or second server in the partition
    // writes its own: keep the history sorted, so "the last few" are the latest.
    const auto pos = std::upper_bound(v.events.begin(), v.events.end(), line, before);
    v.events.insert(pos, std::move(line));
    if (v.events.size() > kEventsKept) v.events.pop_front();
  }

  dds::Participant participant_;
  dds::Topics topics_;
  dds::Reader<telehand_msg_SessionStatus> status_reader_;
  dds::Reader<telehand_msg_JointModel> model_reader_;
  dds::Reader<telehand_msg_HandState> hand_reader_;
  dds::Reader<telehand_msg_SessionEvent> event_reader_;
  dds::WaitSet waitset_;
  std::map<uint64_t, SessionView> sessions_;  // 0 holds events not tied to a session
  uint64_t arrivals_ = 0;
};

/// Link health of one session's HandState stream as the supervisor experiences it.
struct Health {
  std::string_view verdict;       ///< ok, STALE, waiting (none yet), ended, no-server
  std::optional<double> age_ms;   ///< since the last HandState arrived
  std::optional<double> rate_hz;  ///< HandStates received per second
};

Health healthOf(const SessionView& v, int64_t now_ns, bool server_matched) {
  Health h;
  if (v.hand) {
    h.age_ms = ms(now_ns - v.hand_rx_ns);
    // Rate over the last second, or over what there is of it just after joining.
    const int64_t window = std::min(kRateWindowNs, now_ns - v.first_hand_rx_ns);
    if (window >= 200 * kNsPerMs) {
      const auto n = std::count_if(v.hand_rx.begin(), v.hand_rx.end(),
                                   [&](int64_t t) { return t >= now_ns - window; });
      h.rate_hz = static_cast<double>(n) / (static_cast<double>(window) * 1e-9);
    }
  }
  const bool closed = v.status && v.status->state == telehand_msg_SESSION_CLOSED;
  const bool stale = !v.hand || now_ns - v.hand_rx_ns > kStaleNs;
  if (!stale) {
    h.verdict = "ok";
  } else if (closed) {
    h.verdict = "ended";  // a closed session publishes no more hand states: not a link fault
  } else if (!server_matched) {
    h.verdict = "no-server";
  } else {
    h.verdict = v.hand ? "STALE" : "waiting";
  }
  return h;
}

std::string num(std::optional<double> v, int decimals) {
  return v ? fmt::format("{:.{}f}", *v, decimals) : "-";
}

std::string triple(const double (&v)[3], int decimals) {
  return fmt::format("{:.{}f},{:.{}f},{:.{}f}", v[0], decimals, v[1], decimals, v[2], decimals);
}

/// At most `max` bytes, cut on a UTF-8 character boundary, "~" marking a cut.
std::string clip(const std::string& s, std::size_t max) {
  if (s.size() <= max) return s;
  std::size_t n = max - 1;
  while (n > 0 && (static_cast<unsigned char>(s[n]) & 0xC0) == 0x80) --n;
  return s.substr(0, n) + "~";
}

/// One --plain line. Keys are stable (tests and scripts grep them); "-" = not known yet.
std::string plainLine(const Options& o, uint64_t id, const SessionView& v, const Health& h,
                      double t_s) {
  std::string s = fmt::format("watch t={:.1f} session={}", t_s, id);
  if (v.status) {
    const auto& st = *v.status;
    s += fmt::format(" user={} case={} mode={} state={}", token(printable(st.user)),
                     token(printable(st.case_name)), modeName(st.mode), stateName(st.state));
  } else {
    s += " user=- case=- mode=- state=-";
  }
  if (v.hand) {
    const auto& hs = *v.hand;
    const double applied = hs.applied_force_ref_n;
    s += fmt::format(
        " rate_hz={:.1f} device_lost={} hand_hz={} hand_gaps={} source={}"
        " alpha_deg={:.2f} beta_deg={:.2f} gamma_deg={:.2f} torque_nm={}"
        " thumb_f_n={} thumb_n={:.2f} index_f_n={} index_n={:.2f} applied_ref_n={:.2f} band={}",
        hs.device_rate_hz, hs.device_lost, num(h.rate_hz, 1), v.hand_gaps,
        token(std::string(sourceName(hs.source))), radToDeg(hs.mcp_angles_rad[0]),
        radToDeg(hs.mcp_angles_rad[1]), radToDeg(hs.mcp_angles_rad[2]), triple(hs.mcp_torque_nm, 4),
        triple(hs.fingertip_force_n[0], 2), norm3(hs.fingertip_force_n[0]),
        triple(hs.fingertip_force_n[1], 2), norm3(hs.fingertip_force_n[1]), applied,
        bandName(bandOf(applied, o)));
  } else {
    s += fmt::format(
        " rate_hz=- device_lost=- hand_hz=- hand_gaps={} source=- alpha_deg=- beta_deg=-"
        " gamma_deg=- torque_nm=- thumb_f_n=- thumb_n=- index_f_n=- index_n=- applied_ref_n=-"
        " band=-",
        v.hand_gaps);
  }
  s += fmt::format(" model_v={} hand_model_v={}", v.model ? std::to_string(v.model->version) : "-",
                   v.hand ? std::to_string(v.hand->model_version) : "-");
  s += fmt::format(" hand_age_ms={} delay_ms={} device_delay_ms={} link={}", num(h.age_ms, 0),
                   v.hand ? num(ms(v.hand_delay_ns), 1) : "-",
                   v.hand && v.device_delay_ns != 0 ? num(ms(v.device_delay_ns), 1) : "-",
                   h.verdict);
  return s;
}

std::string plainEvent(const EventLine& e) {
  return fmt::format("event session={} time={} kind={} text={}", e.session_id, clockTime(e.time_ns),
                     eventKindName(e.kind), e.text);
}

// ANSI styling for the terminal view only.
constexpr const char* kBold = "\x1b[1m";
constexpr const char* kDim = "\x1b[2m";
constexpr const char* kRed = "\x1b[31m";
constexpr const char* kGreen = "\x1b[32m";
constexpr const char* kYellow = "\x1b[33m";
constexpr const char* kReset = "\x1b[0m";

std::string styled(std::string_view text, const char* style) {
  return fmt::format("{}{}{}", style, text, kReset);
}

/// The terminal view, one string per line, kept under 80 columns.
std::vector<std::string> screenLines(const Options& o, uint64_t id, const SessionView& v,
                                     const Health& h, const std::vector<const EventLine*>& events) {
  std::vector<std::string> out;
  out.push_back(fmt::format("{} on domain {} partition {}   {}   {}",
                            styled("telehand-watch", kBold), o.dds.domain, o.dds.partition,
                            clockTime(wallNs()).substr(0, 8), styled("Ctrl-C quits", kDim)));
  out.emplace_back();
  if (v.status) {
    const auto& st = *v.status;
    const char* state_style = st.state == telehand_msg_SESSION_ACTIVE    ? kGreen
                              : st.state == telehand_msg_SESSION_CLOSING ? kYellow
                                                                         : kDim;
    out.push_back(fmt::format("session {}  user {}  case {}  mode {}  {}",
                              styled(std::to_string(id), kBold), printable(st.user),
                              printable(st.case_name), modeName(st.mode),
                              styled(stateName(st.state), state_style)));
  }
  if (v.hand) {
    const auto& hs = *v.hand;
    out.push_back(fmt::format("device      {:7.1f} Hz sampled   {} lost on the way to the server",
                              hs.device_rate_hz, hs.device_lost));
    out.push_back(fmt::format("hand state  {:>7} Hz received  {} gaps   from {}", num(h.rate_hz, 1),
                              v.hand_gaps, sourceName(hs.source)));
    const auto& a = hs.mcp_angles_rad;
    out.push_back(fmt::format("MCP angles  α {:+7.1f}°   β {:+7.1f}°   γ {:+7.1f}°", radToDeg(a[0]),
                              radToDeg(a[1]), radToDeg(a[2])));
    const auto& t = hs.mcp_torque_nm;
    out.push_back(fmt::format("torque      α {:+7.3f}    β {:+7.3f}    γ {:+7.3f}  N·m (passive)",
                              t[0], t[1], t[2]));
    for (int k = 0; k < 2; ++k) {
      const auto& f = hs.fingertip_force_n[k];
      out.push_back(fmt::format("{:<11} ({:+6.2f} {:+6.2f} {:+6.2f}) N   |F| {:5.2f} N",
                                k == 0 ? "thumb" : "index", f[0], f[1], f[2], norm3(f)));
    }
    const double applied = hs.applied_force_ref_n;
    const Band band = bandOf(applied, o);
    out.push_back(
        fmt::format("applied     {:5.1f} N ref {} {} {:g}-{:g} N", applied, bandBar(applied, o),
                    styled(band == Band::kIn ? "in band" : fmt::format("{} band", bandName(band)),
                           band == Band::kIn ? kGreen : kYellow),
                    o.band_min_n, o.band_max_n));
  } else {
    out.push_back("hand state  none received yet");
  }
  std::string model = "model       ";
  if (v.model) {
    model += fmt::format("v{}  case {}  force scale {:g}", v.model->version,
                         printable(v.model->case_name), v.model->force_scale);
  } else {
    model += "no JointModel received";
  }
  if (v.hand && (!v.model || v.hand->model_version != v.model->version)) {
    model += styled(fmt::format("  (hand state reflects v{})", v.hand->model_version), kYellow);
  }
  out.push_back(model);
  const char* verdict_style = h.verdict == "ok" ? kGreen : h.verdict == "ended" ? kDim : kRed;
  std::string link = "link        " + styled(h.verdict, verdict_style);
  if (v.hand) {
    link += fmt::format("  last {} ms ago  server→watch {:.1f} ms", num(h.age_ms, 0),
                        ms(v.hand_delay_ns));
    if (v.device_delay_ns != 0)
      link += fmt::format("  device→watch {:.1f} ms", ms(v.device_delay_ns));
  }
  out.push_back(link);
  if (v.status && v.status->state == telehand_msg_SESSION_CLOSED) {
    out.push_back(fmt::format("record      {} samples recorded, {} missing",
                              v.status->samples_recorded, v.status->samples_missing));
  }
  out.emplace_back();
  out.push_back(styled("events", kBold));
  const std::size_t from = events.size() > kEventsShown ? events.size() - kEventsShown : 0;
  for (std::size_t i = from; i < events.size(); ++i) {
    const EventLine& e = *events[i];
    const std::string line =
        fmt::format("  {} {:<8} {}", clockTime(e.time_ns), eventKindName(e.kind), clip(e.text, 52));
    out.push_back(e.kind == telehand_msg_EVENT_ERROR ? styled(line, kRed) : line);
  }
  if (events.empty()) out.push_back("  none");
  return out;
}

/// Full-screen redraws on a terminal: the alternate screen (the supervisor's scrollback is
/// left alone), no cursor, no line wrap (a narrow window truncates instead of scrolling).
/// The destructor puts the terminal back on every way out: Ctrl-C, close, errors.
class Screen {
 public:
  Screen() { write("\x1b[?1049h\x1b[?25l\x1b[?7l"); }
  ~Screen() { write("\x1b[?7h\x1b[?25h\x1b[?1049l"); }
  Screen(const Screen&) = delete;
  Screen& operator=(const Screen&) = delete;

  void draw(const std::vector<std::string>& lines) {
    std::string out = "\x1b[H";  // home, then overwrite in place: no flicker
    for (const auto& l : lines) out += l + "\x1b[K\n";
    out += "\x1b[J";
    write(out);
  }

 private:
  static void write(std::string_view s) {
    std::fwrite(s.data(), 1, s.size(), stdout);
    std::fflush(stdout);
  }
};

enum class End { kSignal, kTime, kClosed };

void printSummary(uint64_t id, const SessionView* v, End end, double seconds) {
  if (v && v->status && v->status->state == telehand_msg_SESSION_CLOSED) {
    std::printf("session %llu closed: %llu samples recorded, %llu missing; record %s\n",
                static_cast<unsigned long long>(id),
                static_cast<unsigned long long>(v->status->samples_recorded),
                static_cast<unsigned long long>(v->status->samples_missing),
                printable(v->status->record).c_str());
  }
  std::string s = fmt::format("watch summary: session={}", id == 0 ? "-" : std::to_string(id));
  if (v) {
    s += fmt::format(" hand_states={} hand_gaps={} hand_reordered={} events={} models={} state={}",
                     v->hand_states, v->hand_gaps, v->hand_reordered, v->events_seen, v->models,
                     v->status ? stateName(v->status->state) : "-");
    if (v->status && v->status->state == telehand_msg_SESSION_CLOSED) {
      s += fmt::format(" samples_recorded={} samples_missing={}", v->status->samples_recorded,
                       v->status->samples_missing);
    }
  } else {
    s += " hand_states=0 hand_gaps=0 hand_reordered=0 events=0 models=0 state=-";
  }
  const char* why = end == End::kSignal ? "signal" : end == End::kTime ? "time" : "closed";
  s += fmt::format(" seconds={:.1f} end={}", seconds, why);
  std::printf("%s\n", s.c_str());
  std::fflush(stdout);
}

/// Waits for the session to watch. Returns its id, 0 on Ctrl-C; throws nothing, prints and
/// returns nullopt when none appears in time.
std::optional<uint64_t> chooseSession(Watcher& w, const Options& o, const Clock& clock) {
  const int64_t start = clock.nowNs();
  const int64_t deadline = start + secondsToNs(o.wait_s);
  int64_t found_ns = 0;
  bool told = false;
  while (!g_stop.load()) {
    w.wait(50 * kNsPerMs);
    const int64_t now = clock.nowNs();
    w.poll(now);
    const uint64_t candidate =
        o.session != 0 ? (w.find(o.session) ? o.session : 0) : w.mostRecentActive();
    if (candidate != 0) {
      if (found_ns == 0) found_ns = now;
      if (now - found_ns >= kSettleNs) return o.session != 0 ? o.session : w.mostRecentActive();
    }
    if (now >= deadline) {
      const auto& d = o.dds;
      if (o.session != 0) {
        std::cerr << fmt::format(
            "telehand-watch: no session {} known on domain {} partition {} "
            "(known: {})\n",
            o.session, d.domain, d.partition, w.known());
      } else {
        std::cerr << fmt::format(
            "telehand-watch: no active session on domain {} partition {} within {:g} s "
            "(known: {}){}\n",
            d.domain, d.partition, o.wait_s, w.known(),
            w.serverMatched() ? ""
                              : "; no telehand-server seen: is one running with the same "
                                "--domain, --partition and --dds-config?");
      }
      return std::nullopt;
    }
    if (!told && now - start > kNsPerS) {  // say so only when the wait is noticeable
      told = true;
      std::cerr << fmt::format(
          "telehand-watch: waiting up to {:g} s for {} on domain {} "
          "partition {}\n",
          o.wait_s,
          o.session ? "session " + std::to_string(o.session) : std::string("an active session"),
          o.dds.domain, o.dds.partition);
    }
  }
  return 0;
}

/// Shows session `id` until Ctrl-C, --seconds, or (with --exit-on-close or no --seconds) the
/// session closing. Returns how it ended.
End watchSession(Watcher& w, const Options& o, uint64_t id, const Clock& clock,
                 int64_t& elapsed_ns) {
  const int64_t period = static_cast<int64_t>(1e9 / o.refresh_hz);
  const int64_t start = clock.nowNs();
  const int64_t end = o.seconds > 0.0 ? start + secondsToNs(o.seconds) : INT64_MAX;
  const bool stop_on_close = o.exit_on_close || o.seconds == 0.0;
  std::optional<Screen> screen;
  if (!o.plain) screen.emplace();
  std::vector<std::string> last_frame;
  uint64_t printed_arrival = 0;
  bool first_frame = true;
  int64_t next_frame = start;
  for (;;) {
    w.wait(std::min(next_frame, end) - clock.nowNs());
    const int64_t now = clock.nowNs();
    w.poll(now);
    const SessionView& v = *w.find(id);  // known: chooseSession saw its status
    const bool closed = v.status->state == telehand_msg_SESSION_CLOSED;
    std::optional<End> done;
    if (g_stop.load()) {
      done = End::kSignal;
    } else if (closed && stop_on_close) {
      done = End::kClosed;
    } else if (now >= end) {
      done = End::kTime;
    }
    if (now >= next_frame || done) {
      const Health h = healthOf(v, now, w.serverMatched());
      const auto events = w.eventsFor(id);
      if (o.plain) {
        // Events once each; on joining, only the last few of the history.
        const std::size_t from =
            first_frame && events.size() > kEventsShown ? events.size() - kEventsShown : 0;
        for (std::size_t i = from; i < events.size(); ++i) {
          if (events[i]->arrival > printed_arrival)
            std::printf("%s\n", plainEvent(*events[i]).c_str());
        }
        for (const auto* e : events) printed_arrival = std::max(printed_arrival, e->arrival);
        std::printf("%s\n",
                    plainLine(o, id, v, h, static_cast<double>(now - start) * 1e-9).c_str());
        std::fflush(stdout);
      } else {
        last_frame = screenLines(o, id, v, h, events);
        screen->draw(last_frame);
      }
      first_frame = false;
      next_frame += period;
      if (next_frame <= now) next_frame = now + period;  // fell behind: do not burst
    }
    if (done) {
      elapsed_ns = now - start;
      screen.reset();  // back to the normal screen, then leave the last view there
      for (const auto& l : last_frame) std::printf("%s\n", l.c_str());
      return *done;
    }
  }
}

int run(const Options& o) {
  SteadyClock clock;
  const int64_t t0 = clock.nowNs();
  Watcher w(o.dds);
  const std::optional<uint64_t> id = chooseSession(w, o, clock);
  if (!id) return 2;
  if (*id == 0) {  // Ctrl-C while waiting
    printSummary(0, nullptr, End::kSignal, static_cast<double>(clock.nowNs() - t0) * 1e-9);
    return 0;
  }
  if (o.plain) {
    const auto& st = *w.find(*id)->status;
    std::printf("watching session %llu (%s, case %s, %s, %s) on domain %u partition %s\n",
                static_cast<unsigned long long>(*id), printable(st.user).c_str(),
                printable(st.case_name).c_str(), std::string(modeName(st.mode)).c_str(),
                std::string(stateName(st.state)).c_str(), o.dds.domain, o.dds.partition.c_str());
  }
  int64_t elapsed_ns = 0;
  const End end = watchSession(w, o, *id, clock, elapsed_ns);
  printSummary(*id, w.find(*id), end, static_cast<double>(elapsed_ns) * 1e-9);
  return 0;
}

}  // namespace
}  // namespace telehand::client::watch

int main(int argc, char** argv) {
  using namespace telehand;
  using namespace telehand::client::watch;
  CLI::App app{
      "telehand-watch: the supervisor's live view of a session, joining at any time: "
      "session and mode, sample rates, MCP angles, fingertip forces against the "
      "reference band, model version, link health and recent events. Ctrl-C quits."};
  Options o;
  std::string log_level = "warn";
  app.add_option("--session", o.session,
                 "session id (default: the most recently started active session)")
      ->check(CLI::PositiveNumber);
  app.add_option("--refresh-hz", o.refresh_hz, "screen refreshes per second")
      ->check(CLI::Range(5.0, 100.0))
      ->capture_default_str();
  app.add_option("--band-min", o.band_min_n, "reference force band low end, N")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--band-max", o.band_max_n, "reference force band high end, N")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--seconds", o.seconds,
                 "watch this long once the session is found (0 = until Ctrl-C or it closes)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_flag("--exit-on-close", o.exit_on_close,
               "exit 0 when the session closes, printing its final record counts");
  app.add_option("--wait", o.wait_s, "seconds to wait for the session to appear")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_flag("--plain", o.plain,
               "one key=value line per refresh, no ANSI (automatic when stdout is not a terminal)");
  app.add_option("--domain", o.dds.domain, "DDS domain id")->check(CLI::Range(0, 230));
  app.add_option("--partition", o.dds.partition, "DDS partition")->capture_default_str();
  app.add_option("--dds-config", o.dds.config, "Cyclone DDS XML config file");
  app.add_option("--log-level", log_level, "trace, debug, info, warn, error, off")
      ->capture_default_str();
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : 2;  // README: 2 = bad input
  }

  try {
    setupLogging("telehand-watch", log_level);
    if (!(o.band_min_n < o.band_max_n)) {
      throw ConfigError(fmt::format("--band-min ({:g} N) must be below --band-max ({:g} N)",
                                    o.band_min_n, o.band_max_n));
    }
    const char* term = std::getenv("TERM");
    o.plain = o.plain || isatty(STDOUT_FILENO) == 0 || (term && std::strcmp(term, "dumb") == 0);
    std::signal(SIGINT, onSignal);
    std::signal(SIGTERM, onSignal);
    return run(o);
  } catch (const telehand::Error& e) {
    std::cerr << "telehand-watch: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {  // caught so that the terminal is restored on the way
    std::cerr << "telehand-watch: unexpected error: " << e.what() << "\n";
    return 1;
  }
}
