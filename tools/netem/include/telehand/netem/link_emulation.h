#pragma once
/// A network link as the impairments a packet meets on it: one-way delay, bounded jitter,
/// bursty loss (Gilbert–Elliott) and reordering. One model serves the in-process emulated
/// link of the teleoperation benchmark (simulated time) and the user-space TUN delay line
/// between network namespaces (tools/linkem), so both see the same link.
///
/// Profiles live in deploy/links/*.toml:
///   [link]
///   name = "spain-australia"
///   rtt_ms = 300.0          # round trip: each direction is delayed by rtt_ms / 2
///   jitter_ms = 20.0        # each one-way delay varies within ± this
///   jitter_corr_ms = 50.0   # how long a delay excursion lasts (time constant)
///   loss_pct = 2.0          # mean loss per direction
///   loss_burst = 4.0        # mean run of consecutive losses (1 = independent losses)
///   reorder_pct = 0.0       # packets whose own delay may overtake earlier packets
#include <cstdint>
#include <optional>
#include <queue>
#include <random>
#include <string>
#include <vector>

namespace telehand {

struct LinkProfile {
  std::string name = "loopback";
  std::string description;
  double rtt_ms = 0.0;
  double jitter_ms = 0.0;
  double jitter_corr_ms = 50.0;
  double loss_pct = 0.0;
  double loss_burst = 1.0;
  double reorder_pct = 0.0;

  double oneWayDelayNs() const noexcept { return rtt_ms * 0.5e6; }
};

/// Parse a profile; ConfigError naming `origin`, the line and the key on bad input.
LinkProfile parseLinkProfile(const std::string& text, const std::string& origin);
LinkProfile loadLinkProfile(const std::string& path);

/// Two-state bursty loss: in Good nothing is lost, in Bad everything; the mean burst is
/// 1 / r packets and the stationary loss p / (p + r).
class GilbertElliott {
 public:
  GilbertElliott() = default;
  GilbertElliott(double loss_fraction, double mean_burst_packets);
  /// Advance one packet: true when this packet is lost.
  bool lose(std::mt19937_64& rng) noexcept;

 private:
  double p_ = 0.0;
  double r_ = 1.0;
  bool bad_ = false;
};

struct LinkDirectionStats {
  uint64_t sent = 0;
  uint64_t lost = 0;
  uint64_t reordered = 0;  ///< delivered before a packet sent earlier
  double delay_sum_ms = 0.0;
  double delay_max_ms = 0.0;
};

/// One direction of a link: decides, per packet, whether it is lost and when it arrives.
/// Delivery keeps send order unless the packet is one of the reordered ones.
class LinkDirection {
 public:
  LinkDirection(const LinkProfile& profile, uint64_t seed);
  /// Arrival time for a packet sent at `send_ns`, or nullopt when the link loses it.
  /// Calls must come in non-decreasing send time.
  std::optional<int64_t> schedule(int64_t send_ns);
  const LinkDirectionStats& stats() const noexcept { return stats_; }

 private:
  double jitterNs(int64_t send_ns);

  LinkProfile profile_;
  std::mt19937_64 rng_;
  GilbertElliott loss_;
  std::normal_distribution<double> normal_{0.0, 1.0};
  std::uniform_real_distribution<double> uniform_{0.0, 1.0};
  double jitter_state_ = 0.0;  // Ornstein–Uhlenbeck excursion, in units of jitter_ms
  int64_t jitter_ns_ = INT64_MIN;
  int64_t last_arrival_ns_ = INT64_MIN;
  LinkDirectionStats stats_;
};

/// Packets in flight on one direction, delivered in arrival order (ties: send order).
template <typename T>
class DelayLine {
 public:
  DelayLine(const LinkProfile& profile, uint64_t seed) : dir_(profile, seed) {}

  /// Hand a packet to the link at `now_ns`; false when the link loses it.
  bool send(T packet, int64_t now_ns) {
    const auto at = dir_.schedule(now_ns);
    if (!at) return false;
    queue_.push(Entry{*at, order_++, std::move(packet)});
    return true;
  }
  /// Calls fn(packet) for every packet that has arrived by `now_ns`, in arrival order.
  template <typename Fn>
  std::size_t deliver(int64_t now_ns, Fn&& fn) {
    std::size_t n = 0;
    while (!queue_.empty() && queue_.top().at_ns <= now_ns) {
      Entry e = queue_.top();
      queue_.pop();
      fn(e.packet);
      ++n;
    }
    return n;
  }
  std::size_t inFlight() const noexcept { return queue_.size(); }
  /// Arrival time of the next packet, or INT64_MAX when none is in flight.
  int64_t nextArrivalNs() const noexcept { return queue_.empty() ? INT64_MAX : queue_.top().at_ns; }
  const LinkDirectionStats& stats() const noexcept { return dir_.stats(); }

 private:
  struct Entry {
    int64_t at_ns;
    uint64_t order;
    T packet;
    bool operator>(const Entry& o) const noexcept {
      return at_ns != o.at_ns ? at_ns > o.at_ns : order > o.order;
    }
  };
  LinkDirection dir_;
  uint64_t order_ = 0;
  std::priority_queue<Entry, std::vector<Entry>, std::greater<Entry>> queue_;
};

}  // namespace telehand
