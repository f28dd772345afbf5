#pragma once
// Percentiles of one-way latency, computed the way ddsperf computes them.
#include <cstddef>
#include <cstdint>
#include <vector>

namespace telehand::latency {

/// Percentiles of one-way latency in µs. Ranks follow ddsperf (the value at n - ceil(n/k)
/// in ascending order for the 1/k tail) so that both tools' numbers mean the same thing.
struct Summary {
  std::size_t count = 0;
  double p50_us = 0, p90_us = 0, p99_us = 0, p999_us = 0, max_us = 0, mean_us = 0;
};

/// Sorts `rtt_ns` and summarizes it as one-way latency (RTT/2).
Summary summarize(std::vector<int64_t>& rtt_ns);

/// Aggregates per-second summaries as this tool does for ddsperf: median over seconds of
/// p50/p90/p99/mean, maximum of max, total count.
Summary aggregateSeconds(const std::vector<Summary>& secs);

}  // namespace telehand::latency
