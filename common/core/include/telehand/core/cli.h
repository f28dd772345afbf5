#pragma once
/// Command-line parsing shared by the programs: --help exits 0, a bad option exits 2 (the
/// README's "bad input" code) with CLI11's message naming the option.
#include <CLI/CLI.hpp>

#define TELEHAND_CLI_PARSE(app, argc, argv)        \
  try {                                             \
    (app).parse((argc), (argv));                    \
  } catch (const CLI::ParseError& cli_error) {      \
    return (app).exit(cli_error) == 0 ? 0 : 2;      \
  }

#include <atomic>
#include <csignal>

namespace telehand {

/// Set by SIGINT or SIGTERM once installStopSignals() has run: programs finish their work
/// (close the session, flush the record) instead of dying mid-write.
inline std::atomic<bool> g_stop_requested{false};
inline void installStopSignals() {
  auto handler = [](int) { g_stop_requested.store(true); };
  std::signal(SIGINT, handler);
  std::signal(SIGTERM, handler);
}

}  // namespace telehand
