#pragma once
// How telehand-watch shows a session: the link health verdict, the --plain key=value lines,
// the terminal view and the closing summary.
#include <cstdio>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "model.h"

namespace telehand::client::watch {

/// Link health of one session's HandState stream as the supervisor experiences it.
struct Health {
  std::string_view verdict;       ///< ok, STALE, waiting (none yet), ended, no-server
  std::optional<double> age_ms;   ///< since the last HandState arrived
  std::optional<double> rate_hz;  ///< HandStates received per second
};

Health healthOf(const SessionView& v, int64_t now_ns, bool server_matched);

/// One --plain line. Keys are stable (tests and scripts grep them); "-" = not known yet.
std::string plainLine(const Options& o, uint64_t id, const SessionView& v, const Health& h,
                      double t_s);
std::string plainEvent(const EventLine& e);

/// The terminal view, one string per line, kept under 80 columns.
std::vector<std::string> screenLines(const Options& o, uint64_t id, const SessionView& v,
                                     const Health& h, const std::vector<const EventLine*>& events);

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

/// The closing lines: the record counts of a closed session, then one greppable summary.
void printSummary(uint64_t id, const SessionView* v, End end, double seconds);

}  // namespace telehand::client::watch
