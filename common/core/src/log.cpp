#include "telehand/core/log.h"

#include <spdlog/sinks/stdout_color_sinks.h>

#include "telehand/core/error.h"

namespace telehand {

void setupLogging(const std::string& program, const std::string& level) {
  auto logger = spdlog::stderr_color_mt(program);
  const auto lvl = spdlog::level::from_str(level);
  if (lvl == spdlog::level::off && level != "off") {
    throw ConfigError("log level '" + level +
                      "' is not one of trace, debug, info, warn, error, off");
  }
  logger->set_level(lvl);
  logger->set_pattern("%H:%M:%S.%e %n %^%l%$: %v");
  spdlog::set_default_logger(logger);
}

}  // namespace telehand
