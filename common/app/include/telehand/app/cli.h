#pragma once
/// Command-line parsing shared by the programs: --help exits 0, a bad option exits 2 (the
/// README's "bad input" code) with CLI11's message naming the option.
#include <CLI/CLI.hpp>

#include "telehand/app/signals.h"

#define TELEHAND_CLI_PARSE(app, argc, argv)    \
  try {                                        \
    (app).parse((argc), (argv));               \
  } catch (const CLI::ParseError& cli_error) { \
    return (app).exit(cli_error) == 0 ? 0 : 2; \
  }
