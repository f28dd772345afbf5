#pragma once
/// Logging set-up shared by the programs (spdlog, to stderr). Never used on the RT thread.
#include <spdlog/spdlog.h>

#include <string>

namespace telehand {

/// Name the program in every line and set the level ("trace".."off").
void setupLogging(const std::string& program, const std::string& level = "info");

}  // namespace telehand
