#include "telehand/app/cli.h"

#include <string_view>

#include "telehand/core/parse.h"

namespace telehand::app {

FiniteNumberValidator::FiniteNumberValidator() : CLI::Validator("FINITE") {
  func_ = [](std::string& text) -> std::string {
    std::string_view number(text);
    if (!number.empty() && number.front() == '+') number.remove_prefix(1);
    double value = 0.0;
    if (parseFiniteNumber(number, value)) return {};
    return "'" + text + "' is not a finite number";
  };
  non_modifying();
}

const FiniteNumberValidator FiniteNumber;

void requireFiniteNumbers(CLI::App& app) {
  for (CLI::Option* option : app.get_options()) {
    // First, ahead of its range: a range's message about inf is no clearer than this one.
    if (option->get_type_name().starts_with("FLOAT")) option->transform(FiniteNumber);
  }
  for (CLI::App* sub : app.get_subcommands([](CLI::App*) { return true; })) {
    requireFiniteNumbers(*sub);
  }
}

}  // namespace telehand::app
