#pragma once
/// Child processes started with fork and exec, stopped by their PID only (never by name)
/// and always reaped. Everything the child needs is prepared before the fork: a process that
/// already runs DDS threads may only make async-signal-safe calls between fork and exec.
#include <sys/types.h>

#include <chrono>
#include <functional>
#include <optional>
#include <string>
#include <vector>

namespace telehand::app {

struct ProcessOptions {
  std::vector<std::string> argv{};  ///< argv[0] is the program
  /// The child's environment; unset: this process's own.
  std::optional<std::vector<std::string>> env{};
  bool search_path = false;      ///< look argv[0] up in PATH, as execvp does
  int out_fd = -1;               ///< stdout and stderr to this descriptor (-1: inherited)
  std::string out_path{};        ///< or to this file, truncated (when out_fd is -1)
  bool null_stdin = false;       ///< stdin from /dev/null instead of ours
  bool die_with_parent = false;  ///< SIGTERM when this process dies (PR_SET_PDEATHSIG)
  int nice = 0;                  ///< added to the child's niceness (0-19: yields the CPU)
};

class Process {
 public:
  /// Starts the child; throws std::runtime_error when it cannot be started or its program
  /// cannot be run ("cannot run PROGRAM: reason").
  explicit Process(const ProcessOptions& options);
  ~Process();
  Process(const Process&) = delete;
  Process& operator=(const Process&) = delete;

  pid_t pid() const noexcept { return pid_; }

  /// True while it runs; reaps it otherwise.
  bool alive();
  /// The exit code (128 + signal when killed) within `timeout`, or nullopt if still running.
  std::optional<int> wait(std::chrono::milliseconds timeout);
  /// Waits as long as it takes; returns the exit code.
  int wait();
  /// SIGTERM, then SIGKILL after `grace` (calling `on_kill` first). Returns the exit code.
  int stop(std::chrono::milliseconds grace = std::chrono::milliseconds(5000),
           const std::function<void()>& on_kill = {});

  /// Once it has ended: its wait status, exit code, and "exited with status N" or
  /// "killed by SIGNAL".
  int status() const noexcept { return status_; }
  int exitCode() const noexcept;
  bool exitedOk() const noexcept { return exitCode() == 0; }
  std::string describeExit() const;

 private:
  pid_t pid_ = -1;
  bool running_ = false;
  int status_ = 0;
};

/// Resolves a program name through PATH as execvp would.
std::optional<std::string> findProgram(const std::string& name);

}  // namespace telehand::app
