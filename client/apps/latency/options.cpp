#include "options.h"

#include "telehand/app/cli.h"
#include "telehand/app/dds_cli.h"

namespace telehand::latency {

std::optional<int> parseOptions(int argc, char** argv, Settings& s, bool& seconds_given) {
  CLI::App app{
      "telehand-latency: loopback latency probe. Sends DeviceState samples at --rate through an "
      "echo (a telehand-server's, or a child 'telehand-latency --echo-only' in a private "
      "partition) and prints one-way latency (RTT/2) percentiles; --compare-ddsperf then runs "
      "Cyclone's ddsperf ping-pong at the same size and rate and prints the ratio."};
  std::string echo_choice = "auto";
  auto* seconds_opt = app.add_option("--seconds", s.seconds,
                                     "measured seconds (with --echo-only: stop after this; "
                                     "default there: until SIGINT/SIGTERM)")
                          ->capture_default_str()
                          ->check(CLI::PositiveNumber);
  app.add_option("--rate", s.rate_hz, "pings per second, Hz")
      ->capture_default_str()
      ->check(CLI::Range(1.0, 20000.0));
  app.add_option("--warmup", s.warmup_s, "seconds sent first and discarded")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 3600.0));
  app.add_option("--echo", echo_choice,
                 "auto: a server echo if one matches within 2 s, else self; server; self")
      ->capture_default_str()
      ->check(CLI::IsMember({"auto", "server", "self"}));
  auto* rounds = app.add_option("--rounds", s.rounds,
                                "with --compare-ddsperf: alternate telehand and ddsperf this "
                                "many times, --seconds/rounds each (each with its warm-up), so "
                                "that a shared machine's changing load falls on both alike")
                     ->capture_default_str()
                     ->check(CLI::Range(1, 100));
  app.add_option("--take", s.take,
                 "how samples are taken, by the pong reader and a self or --echo-only echo: "
                 "listener (inside Cyclone's receive thread, as ddsperf does) or waitset (a "
                 "thread of ours, woken per sample, as the server's serve loop)")
      ->capture_default_str()
      ->check(CLI::IsMember({"listener", "waitset"}));
  auto* echo_only = app.add_flag("--echo-only", s.echo_only,
                                 "only echo pings (the other end of a probe) until "
                                 "SIGINT/SIGTERM or --seconds");
  app::addDdsOptions(app, s.dds, s.insecure, "engineer");
  auto* compare = app.add_flag("--compare-ddsperf", s.compare,
                               "afterwards run ddsperf ping-pong at the same size and rate");
  app.add_option("--ddsperf", s.ddsperf, "ddsperf program (package cyclonedds-tools)")
      ->capture_default_str();
  app.add_option("--json", s.json_path, "also write the results to this JSON file");
  app.add_flag("-q,--quiet", s.quiet, "no progress lines on stderr");
  echo_only->excludes(compare);
  rounds->needs(compare);
  app::requireFiniteNumbers(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // CLI11's own codes (105, 106...) would not tell a script "bad usage" the way 2 does.
    return app.exit(e) == 0 ? 0 : 2;
  }
  s.echo = echo_choice;
  s.dds_config = s.dds.config;
  seconds_given = seconds_opt->count() > 0;
  return std::nullopt;
}

}  // namespace telehand::latency
