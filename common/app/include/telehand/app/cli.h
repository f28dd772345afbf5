#pragma once
/// Command-line parsing shared by the programs: --help exits 0, a bad option exits 2 (the
/// README's "bad input" code) with CLI11's message naming the option.
#include <CLI/CLI.hpp>
#include <string>

#include "telehand/app/signals.h"

namespace telehand::app {

/// A floating-point option's value must be a finite number. CLI11 2.1.2's Range,
/// PositiveNumber and NonNegativeNumber pass NaN (`val < min || val > max` is false for it),
/// and an option without a range takes inf as well.
class FiniteNumberValidator : public CLI::Validator {
 public:
  FiniteNumberValidator();
};
extern const FiniteNumberValidator FiniteNumber;

/// Adds FiniteNumber to every floating-point option (CLI11's type FLOAT) of `app` and its
/// subcommands that is there now: call it once every option was added, before parsing.
void requireFiniteNumbers(CLI::App& app);

}  // namespace telehand::app

/// Parses the command line of `app`, every floating-point option held to a finite number
/// (requireFiniteNumbers); returns from the caller with 0 after --help, 2 on a bad option.
#define TELEHAND_CLI_PARSE(app, argc, argv)     \
  try {                                         \
    ::telehand::app::requireFiniteNumbers(app); \
    (app).parse((argc), (argv));                \
  } catch (const CLI::ParseError& cli_error) {  \
    return (app).exit(cli_error) == 0 ? 0 : 2;  \
  }
