#include "stats.h"

#include <algorithm>

namespace telehand::latency {

namespace {
double tailUs(const std::vector<int64_t>& sorted_rtt, std::size_t k) {
  const std::size_t n = sorted_rtt.size();
  return static_cast<double>(sorted_rtt[n - (n + k - 1) / k]) / 2e3;
}

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const std::size_t m = v.size() / 2;
  return v.size() % 2 ? v[m] : (v[m - 1] + v[m]) / 2;
}

}  // namespace

Summary summarize(std::vector<int64_t>& rtt_ns) {
  Summary s;
  s.count = rtt_ns.size();
  if (rtt_ns.empty()) return s;
  std::sort(rtt_ns.begin(), rtt_ns.end());
  double sum = 0;
  for (int64_t r : rtt_ns) sum += static_cast<double>(r);
  s.p50_us = tailUs(rtt_ns, 2);
  s.p90_us = tailUs(rtt_ns, 10);
  s.p99_us = tailUs(rtt_ns, 100);
  s.p999_us = tailUs(rtt_ns, 1000);
  s.max_us = static_cast<double>(rtt_ns.back()) / 2e3;
  s.mean_us = sum / static_cast<double>(rtt_ns.size()) / 2e3;
  return s;
}
Summary aggregateSeconds(const std::vector<Summary>& secs) {
  Summary a;
  std::vector<double> p50, p90, p99, mean;
  for (const auto& s : secs) {
    p50.push_back(s.p50_us);
    p90.push_back(s.p90_us);
    p99.push_back(s.p99_us);
    mean.push_back(s.mean_us);
    a.max_us = std::max(a.max_us, s.max_us);
    a.count += s.count;
  }
  a.p50_us = median(p50);
  a.p90_us = median(p90);
  a.p99_us = median(p99);
  a.mean_us = median(mean);
  return a;
}

}  // namespace telehand::latency
