#pragma once
// Child processes for integration tests: telehand::app::Process with stdout and stderr to a
// log file, stopped by PID (never by name), always reaped.
#include <fstream>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "telehand/app/process.h"

namespace telehand::test {

class Process : public app::Process {
 public:
  /// Starts argv[0] with stdout and stderr to `log_path`, its niceness raised by `nice`, in
  /// `env` (unset: this process's environment).
  Process(std::vector<std::string> argv, std::string log_path, int nice = 0,
          std::optional<std::vector<std::string>> env = std::nullopt)
      : app::Process(app::ProcessOptions{
            .argv = std::move(argv), .env = std::move(env), .out_path = log_path, .nice = nice}),
        log_(std::move(log_path)) {}

  std::string output() const {
    std::ifstream in(log_);
    std::ostringstream ss;
    ss << in.rdbuf();
    return ss.str();
  }

 private:
  std::string log_;
};

/// `bin args...` on loopback without DDS Security, in a partition of the test's own.
inline std::vector<std::string> insecureOnLoopback(std::string bin, std::vector<std::string> args,
                                                   const std::string& dds_config,
                                                   const std::string& partition) {
  std::vector<std::string> v{std::move(bin)};
  v.insert(v.end(), args.begin(), args.end());
  v.insert(v.end(), {"--dds-config", dds_config, "--insecure", "--partition", partition});
  return v;
}

}  // namespace telehand::test
