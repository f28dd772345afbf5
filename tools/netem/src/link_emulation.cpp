#include "telehand/netem/link_emulation.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

#include "telehand/config/toml_reader.h"
#include "telehand/core/error.h"

namespace telehand {

LinkProfile parseLinkProfile(const std::string& text, const std::string& origin) {
  const toml::table root = config::parseToml(text, origin);
  config::rejectUnknownTables(root, {"link"}, origin);
  config::TomlTable t(root, "link", origin, /*required=*/true);
  LinkProfile p;
  p.name = t.text("name", p.name);
  p.description = t.text("description", p.description);
  p.rtt_ms = t.number("rtt_ms", p.rtt_ms, 0.0, 10000.0);
  p.jitter_ms = t.number("jitter_ms", p.jitter_ms, 0.0, 5000.0);
  p.jitter_corr_ms = t.number("jitter_corr_ms", p.jitter_corr_ms, 0.0, 60000.0);
  p.loss_pct = t.number("loss_pct", p.loss_pct, 0.0, 90.0);
  p.loss_burst = t.number("loss_burst", p.loss_burst, 1.0, 1000.0);
  p.reorder_pct = t.number("reorder_pct", p.reorder_pct, 0.0, 100.0);
  t.rejectUnknown();
  if (p.jitter_ms > p.rtt_ms * 0.5) {
    config::fail(origin,
                 "'link.jitter_ms' = " + std::to_string(p.jitter_ms) +
                     " exceeds the one-way delay (rtt_ms / 2 = " + std::to_string(p.rtt_ms * 0.5) +
                     "): a packet would arrive before it was sent");
  }
  return p;
}

LinkProfile loadLinkProfile(const std::string& path) {
  return parseLinkProfile(config::readTextFile(path, "link profile"), path);
}

GilbertElliott::GilbertElliott(double loss_fraction, double mean_burst_packets) {
  const double loss = std::clamp(loss_fraction, 0.0, 0.99);
  r_ = 1.0 / std::max(mean_burst_packets, 1.0);
  // Stationary P(bad) = p / (p + r) = loss.
  p_ = loss <= 0.0 ? 0.0 : loss * r_ / (1.0 - loss);
}

bool GilbertElliott::lose(std::mt19937_64& rng) noexcept {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  bad_ = bad_ ? u(rng) >= r_ : u(rng) < p_;
  return bad_;
}

LinkDirection::LinkDirection(const LinkProfile& profile, uint64_t seed)
    : profile_(profile), rng_(seed), loss_(profile.loss_pct / 100.0, profile.loss_burst) {}

double LinkDirection::jitterNs(int64_t send_ns) {
  if (profile_.jitter_ms <= 0.0) return 0.0;
  // Ornstein–Uhlenbeck excursion (stationary sigma 0.5), clamped to ±1: the delay wanders
  // within ± jitter_ms and stays put over jitter_corr_ms, as queueing delay does.
  if (jitter_ns_ == INT64_MIN) {
    jitter_state_ = 0.5 * normal_(rng_);
  } else if (send_ns > jitter_ns_) {
    const double dt_ms = static_cast<double>(send_ns - jitter_ns_) * 1e-6;
    const double a =
        profile_.jitter_corr_ms > 0.0 ? std::exp(-dt_ms / profile_.jitter_corr_ms) : 0.0;
    jitter_state_ = a * jitter_state_ + std::sqrt(1.0 - a * a) * 0.5 * normal_(rng_);
  }
  jitter_ns_ = send_ns;
  return std::clamp(jitter_state_, -1.0, 1.0) * profile_.jitter_ms * 1e6;
}

std::optional<int64_t> LinkDirection::schedule(int64_t send_ns) {
  ++stats_.sent;
  const double jitter = jitterNs(send_ns);
  if (loss_.lose(rng_)) {
    ++stats_.lost;
    return std::nullopt;
  }
  const double base = profile_.oneWayDelayNs();
  int64_t at;
  if (profile_.reorder_pct > 0.0 && uniform_(rng_) * 100.0 < profile_.reorder_pct) {
    // A reordered packet takes its own delay anywhere in the jitter band.
    const double own = (2.0 * uniform_(rng_) - 1.0) * profile_.jitter_ms * 1e6;
    at = send_ns + static_cast<int64_t>(std::llround(base + own));
    if (at < last_arrival_ns_) ++stats_.reordered;
  } else {
    at = std::max(send_ns + static_cast<int64_t>(std::llround(base + jitter)), last_arrival_ns_);
  }
  last_arrival_ns_ = std::max(last_arrival_ns_, at);
  const double delay_ms = static_cast<double>(at - send_ns) * 1e-6;
  stats_.delay_sum_ms += delay_ms;
  stats_.delay_max_ms = std::max(stats_.delay_max_ms, delay_ms);
  return at;
}

}  // namespace telehand
