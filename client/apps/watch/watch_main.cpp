// telehand-watch: the supervisor's live view of one session. It may join at any time:
// SessionStatus, JointModel and SessionEvent are transient-local, so a late joiner learns
// which sessions exist, the model in force and the recent events at once; HandState
// (best-effort, volatile) then streams the live hand. The screen is redrawn at --refresh-hz
// (>= 5 Hz); --plain, automatic when stdout is not a terminal, prints one greppable
// key=value line per refresh instead.
//
// model: the options and the sessions as they arrive; watcher: the readers; render: the
// views; session: choosing the session and watching it.
#include <spdlog/fmt/fmt.h>
#include <unistd.h>

#include <cstdlib>
#include <cstring>
#include <iostream>

#include "session.h"
#include "telehand/app/cli.h"
#include "telehand/app/dds_cli.h"
#include "telehand/core/error.h"
#include "telehand/core/log.h"

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
  app.add_option("--replay", o.replay,
                 "replay this recorded session (a lesson's demonstration, any record) at real "
                 "time, as the server publishes it, and watch it")
      ->check(CLI::PositiveNumber);
  app.add_option("--speed", o.speed, "replay speed")
      ->check(CLI::Range(0.25, 2.0))
      ->capture_default_str();
  app.add_flag("--loop", o.loop, "replay: start again at the end");
  app.add_flag("--plain", o.plain,
               "one key=value line per refresh, no ANSI (automatic when stdout is not a terminal)");
  bool insecure = false;
  app::addDdsOptions(app, o.dds, insecure, "supervisor");
  app.add_option("--log-level", log_level, "trace, debug, info, warn, error, off")
      ->capture_default_str();
  app::requireFiniteNumbers(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : 2;  // README: 2 = bad input
  }

  try {
    setupLogging("telehand-watch", log_level);
    app::resolveDdsSecurity(o.dds, insecure, "supervisor", "telehand-watch");
    if (!(o.band_min_n < o.band_max_n)) {
      throw ConfigError(fmt::format("--band-min ({:g} N) must be below --band-max ({:g} N)",
                                    o.band_min_n, o.band_max_n));
    }
    const char* term = std::getenv("TERM");
    o.plain = o.plain || isatty(STDOUT_FILENO) == 0 || (term && std::strcmp(term, "dumb") == 0);
    installStopSignals();
    return run(o);
  } catch (const telehand::Error& e) {
    std::cerr << "telehand-watch: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {  // caught so that the terminal is restored on the way
    std::cerr << "telehand-watch: unexpected error: " << e.what() << "\n";
    return 1;
  }
}
