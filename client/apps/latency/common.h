#pragma once
// What the parts of telehand-latency share: the sample, the waits, the clock, the child
// processes' stop and the progress line.
#include <unistd.h>

#include <chrono>
#include <cstdint>
#include <iostream>
#include <string>

#include "telehand/app/process.h"
#include "telehand/core/clock.h"
#include "telehand/protocol/dds.h"

namespace telehand::latency {

using namespace std::chrono_literals;
using Sample = telehand_msg_DeviceState;

constexpr auto kAutoEchoWait = 2s;    // a server echo must answer within 2 s, or one is started
constexpr auto kServerEchoWait = 5s;  // --echo server was asked for: allow slower discovery
constexpr auto kSelfEchoWait = 10s;   // includes exec and the child's domain start-up
constexpr auto kDrain = 500ms;        // after the last ping: later pongs count as lost
constexpr auto kChildGrace = 2s;      // SIGTERM to SIGKILL
constexpr double kDdsperfInitWaitS = 10.0;
constexpr uint32_t kDdsperfMinSize = 12;  // KS topic: seq, key, octet-sequence length

inline int64_t monoNs() noexcept { return SteadyClock{}.nowNs(); }

/// SIGTERM, then SIGKILL after kChildGrace, saying so.
inline void stopChild(app::Process& child, const std::string& name) {
  child.stop(kChildGrace, [&] {
    std::cerr << "telehand-latency: " << name << " (pid " << child.pid()
              << ") ignored SIGTERM; sending SIGKILL\n";
  });
}

/// Prints a progress line to stderr at most once a second.
class Progress {
 public:
  explicit Progress(bool quiet) : quiet_(quiet), tty_(isatty(STDERR_FILENO) != 0) {}
  void line(const std::string& text) {
    if (quiet_) return;
    std::cerr << (tty_ ? "\r\033[K" : "") << text << (tty_ ? "" : "\n") << std::flush;
    dirty_ = tty_;
  }
  void done() {
    if (dirty_) std::cerr << "\n";
    dirty_ = false;
  }

 private:
  bool quiet_, tty_, dirty_ = false;
};

}  // namespace telehand::latency
