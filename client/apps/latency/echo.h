#pragma once
// The two ends of telehand's own round trip: the echo (--echo-only, or the child a probe
// starts for itself) and the pinger that measures through it.
#include <string>
#include <vector>

#include "common.h"
#include "options.h"
#include "stats.h"

namespace telehand::latency {

/// --echo-only: answer every ping with the same sample on the pong topic.
int runEcho(const Settings& s, bool seconds_given);

struct PingResult {
  double load_at_start = 0;  // 1-minute load average: context for the figures
  std::string echo_desc;
  std::string partition;
  uint64_t warmup_pings = 0;
  uint64_t planned = 0;  // measured pings planned
  uint64_t sent = 0;     // measured pings sent
  uint64_t received = 0;
  uint64_t late = 0;  // RTT longer than one period
  uint64_t duplicates = 0;
  uint64_t foreign = 0;  // pongs of another run or outside the sequence range
  uint64_t write_errors = 0;
  uint64_t overruns = 0;  // pinger woke more than one period late
  double wake_p99_us = 0, wake_max_us = 0;
  double measured_s = 0;
  bool interrupted = false;
  Summary pooled;
  Summary per_second;  // aggregated like ddsperf's output, for the comparison
  std::size_t seconds_count = 0;
  std::vector<int64_t> rtt_ns;        // answered pings' RTTs, in send order
  std::vector<Summary> seconds;       // per second of sending
  std::vector<int64_t> wake_late_ns;  // per ping sent, warm-up included
};

/// Recomputes the figures (received, pooled, per_second, wake_*) from the raw vectors.
void finish(PingResult& r);

/// Adds a later round's pings to `into` (--rounds): counters add up, the raw vectors are
/// joined and the figures recomputed; the echo and partition are the round's.
void merge(PingResult& into, const PingResult& round);

/// Pings through a server's echo or one of its own; then the figures.
PingResult runPinger(const Settings& s, Progress& progress);

/// The environment for a child, with CYCLONEDDS_URI replaced when a config was given, so that
/// ddsperf joins the same network set-up as telehand did.
std::vector<std::string> childEnv(const std::string& dds_uri);

}  // namespace telehand::latency
