#include "session.h"

#include <cstdio>
#include <iostream>
#include <memory>

#include "render.h"
#include "telehand/app/signals.h"
#include "watcher.h"

namespace telehand::client::watch {

namespace {

/// returns nullopt when none appears in time.
std::optional<uint64_t> chooseSession(Watcher& w, const Options& o, const Clock& clock) {
  const int64_t start = clock.nowNs();
  const int64_t deadline = start + secondsToNs(o.wait_s);
  int64_t found_ns = 0;
  bool told = false;
  while (!g_stop_requested.load()) {
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
    if (g_stop_requested.load()) {
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

}  // namespace

int run(const Options& given) {
  SteadyClock clock;
  const int64_t t0 = clock.nowNs();
  Watcher w(given.dds);
  Options o = given;
  if (o.replay != 0) {
    std::string why;
    const uint64_t replay = w.openReplay(o.replay, secondsToNs(o.wait_s), why);
    if (replay == 0) {
      std::cerr << "telehand-watch: cannot replay session " << o.replay << ": " << why << "\n";
      return 2;
    }
    if (o.speed != 1.0) w.control(replay, telehand_msg_CMD_PHASE, "speed", o.speed);
    if (o.loop) w.control(replay, telehand_msg_CMD_PHASE, "loop", 1.0);
    std::fprintf(stderr, "telehand-watch: replaying session %llu as session %llu at %.2gx%s\n",
                 static_cast<unsigned long long>(o.replay), static_cast<unsigned long long>(replay),
                 o.speed, o.loop ? ", looping" : "");
    o.session = replay;
  }
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
  if (o.replay != 0) w.control(*id, telehand_msg_CMD_CLOSE, "", 0.0);  // the replay ends with us
  printSummary(*id, w.find(*id), end, static_cast<double>(elapsed_ns) * 1e-9);
  return 0;
}

}  // namespace telehand::client::watch
