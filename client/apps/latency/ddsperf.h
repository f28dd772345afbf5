#pragma once
// Cyclone's ddsperf ping-pong at the same size and rate: the baseline for telehand's figures.
#include <cstdint>
#include <string>
#include <vector>

#include "common.h"
#include "options.h"
#include "stats.h"

namespace telehand::latency {

struct DdsperfResult {
  std::string pong_cmd, ping_cmd;
  std::vector<Summary> seconds;
  std::size_t warmup_lines = 0;
  std::size_t foreign_lines = 0;  // from other ddsperf pongs in the domain
  uint64_t timeouts = 0;
  Summary aggregate;
  bool interrupted = false;
};

/// Adds a later round's per-second reports to `into` (--rounds) and recomputes the aggregate.
void merge(DdsperfResult& into, const DdsperfResult& round);

/// Runs ddsperf (`path`) pong and ping with `size`-byte samples and aggregates the ping's
/// per-second reports after the warm-up.
DdsperfResult runDdsperf(const Settings& s, const std::string& path, uint32_t size,
                         Progress& progress);

}  // namespace telehand::latency
