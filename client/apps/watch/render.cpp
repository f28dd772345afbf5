#include "render.h"

#include <spdlog/fmt/fmt.h>

#include <algorithm>
#include <cmath>

namespace telehand::client::watch {

namespace {

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

}  // namespace

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
        " rate_hz={:.1f} device_lost={} device_overruns={} hand_hz={} hand_gaps={} source={}"
        " alpha_deg={:.2f} beta_deg={:.2f} gamma_deg={:.2f} torque_nm={}"
        " thumb_f_n={} thumb_n={:.2f} index_f_n={} index_n={:.2f} applied_ref_n={:.2f} band={}",
        hs.device_rate_hz, hs.device_lost, hs.device_overruns, num(h.rate_hz, 1), v.hand_gaps,
        token(std::string(sourceName(hs.source))), radToDeg(hs.mcp_angles_rad[0]),
        radToDeg(hs.mcp_angles_rad[1]), radToDeg(hs.mcp_angles_rad[2]), triple(hs.mcp_torque_nm, 4),
        triple(hs.fingertip_force_n[0], 2), norm3(hs.fingertip_force_n[0]),
        triple(hs.fingertip_force_n[1], 2), norm3(hs.fingertip_force_n[1]), applied,
        bandName(bandOf(applied, o)));
  } else {
    s += fmt::format(
        " rate_hz=- device_lost=- device_overruns=- hand_hz=- hand_gaps={} source=- alpha_deg=-"
        " beta_deg=-"
        " gamma_deg=- torque_nm=- thumb_f_n=- thumb_n=- index_f_n=- index_n=- applied_ref_n=-"
        " band=-",
        v.hand_gaps);
  }
  if (v.hand && v.hand->technique == telehand_msg_TECHNIQUE_MASSAGE) {
    // The massage: each pad's depth in the web and the web's force on it (reference scale).
    const auto& hs = *v.hand;
    double most = 0.0;
    for (const auto& row : hs.web_grid_m)
      for (double x : row) most = std::max(most, x);
    s += fmt::format(
        " web_thumb_depth_mm={:.2f} web_index_depth_mm={:.2f} web_thumb_f_n={} web_index_f_n={}"
        " web_surface_mm={:.2f}",
        hs.web_depth_m[0] * 1e3, hs.web_depth_m[1] * 1e3, triple(hs.web_force_n[0], 2),
        triple(hs.web_force_n[1], 2), most * 1e3);
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

std::vector<std::string> screenLines(const Options& o, uint64_t id, const SessionView& v,
                                     const Health& h, const std::vector<const EventLine*>& events) {
  std::vector<std::string> out;
  out.push_back(fmt::format("{} on domain {} partition {}   {}   {}",
                            styled("telehand-watch", kBold), o.dds.domain, o.dds.partition,
                            clockTime(wallNs()).substr(0, 8), styled("Ctrl-C quits", kDim)));
  out.emplace_back();
  if (v.status) {
    const auto& st = *v.status;
    const char* state_style =
        st.state == telehand_msg_SESSION_ACTIVE ? kGreen
        : st.state == telehand_msg_SESSION_CLOSING || st.state == telehand_msg_SESSION_SUSPENDED
            ? kYellow
            : kDim;
    out.push_back(fmt::format("session {}  user {}  case {}  mode {}  {}",
                              styled(std::to_string(id), kBold), printable(st.user),
                              printable(st.case_name), modeName(st.mode),
                              styled(stateName(st.state), state_style)));
  }
  if (v.hand) {
    const auto& hs = *v.hand;
    out.push_back(fmt::format(
        "device      {:7.1f} Hz sampled   {} lost on the way to the server   {} loop overruns",
        hs.device_rate_hz, hs.device_lost, hs.device_overruns));
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
    if (hs.technique == telehand_msg_TECHNIQUE_MASSAGE) {
      for (int k = 0; k < 2; ++k) {
        const auto& f = hs.web_force_n[k];
        out.push_back(fmt::format("web {:<7} {:5.2f} mm deep   web force {:5.2f} N ref",
                                  k == 0 ? "thumb" : "index", hs.web_depth_m[k] * 1e3, norm3(f)));
      }
      // The web's surface, pressed in (darker: deeper), thumb side.
      static constexpr const char* kShade[] = {" ", ".", ":", "o", "O", "@"};
      for (const auto& row : hs.web_grid_m) {
        std::string line = "web surface ";
        for (double x : row) line += kShade[std::clamp(static_cast<int>(x * 1e3 / 1.5), 0, 5)];
        out.push_back(line);
      }
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

}  // namespace telehand::client::watch
