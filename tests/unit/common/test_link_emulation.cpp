// The emulated link: Gilbert-Elliott loss rates and bursts, bounded jitter, order, profiles.
#include <gtest/gtest.h>

#include <filesystem>

#include "telehand/core/clock.h"
#include "telehand/core/error.h"
#include "telehand/netem/link_emulation.h"

namespace telehand {
namespace {

TEST(GilbertElliott, StationaryLossAndMeanBurstAsConfigured) {
  GilbertElliott ge(0.10, 8.0);
  std::mt19937_64 rng(7);
  int lost = 0, bursts = 0;
  bool prev = false;
  constexpr int kN = 1'000'000;
  for (int i = 0; i < kN; ++i) {
    const bool l = ge.lose(rng);
    lost += l;
    bursts += l && !prev;
    prev = l;
  }
  EXPECT_NEAR(static_cast<double>(lost) / kN, 0.10, 0.005);
  EXPECT_NEAR(static_cast<double>(lost) / bursts, 8.0, 0.4);
}

TEST(LinkDirection, DelayStaysInTheJitterBandAndOrderIsKept) {
  LinkProfile p;
  p.rtt_ms = 300;
  p.jitter_ms = 20;
  p.loss_pct = 2;
  p.loss_burst = 4;
  LinkDirection d(p, 3);
  int64_t last = INT64_MIN;
  int delivered = 0;
  for (int i = 0; i < 20000; ++i) {
    const int64_t send = i * kNsPerMs;
    const auto at = d.schedule(send);
    if (!at) continue;
    ++delivered;
    const double delay_ms = static_cast<double>(*at - send) * 1e-6;
    EXPECT_GE(delay_ms, 150.0 - 20.0 - 1e-6);
    EXPECT_LE(delay_ms, 150.0 + 20.0 + 1.0);  // FIFO may hold a packet behind its predecessor
    EXPECT_GE(*at, last);
    last = *at;
  }
  EXPECT_EQ(d.stats().reordered, 0u);
  EXPECT_NEAR(1.0 - delivered / 20000.0, 0.02, 0.01);
  EXPECT_GT(d.stats().delay_max_ms - 150.0, 10.0) << "the jitter is used";
}

TEST(LinkDirection, ReorderedPacketsOvertake) {
  LinkProfile p;
  p.rtt_ms = 1000;
  p.jitter_ms = 250;
  p.reorder_pct = 5;
  LinkDirection d(p, 5);
  for (int i = 0; i < 5000; ++i) d.schedule(i * kNsPerMs);
  EXPECT_GT(d.stats().reordered, 50u);
}

TEST(DelayLine, DeliversInArrivalOrderAtTheRightTime) {
  LinkProfile p;
  p.rtt_ms = 20;
  DelayLine<int> line(p, 1);
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(line.send(i, i * kNsPerMs));
  std::vector<int> got;
  EXPECT_EQ(line.deliver(9 * kNsPerMs, [&](int v) { got.push_back(v); }), 0u);
  EXPECT_EQ(line.nextArrivalNs(), 10 * kNsPerMs);
  line.deliver(12 * kNsPerMs, [&](int v) { got.push_back(v); });
  EXPECT_EQ(got, (std::vector<int>{0, 1, 2}));
  line.deliver(100 * kNsPerMs, [&](int v) { got.push_back(v); });
  EXPECT_EQ(got.size(), 5u);
  EXPECT_EQ(line.inFlight(), 0u);
}

TEST(LinkProfile, DeployedProfilesParse) {
  const std::filesystem::path dir = std::filesystem::path(TELEHAND_DEPLOY_DIR) / "links";
  const LinkProfile sa = loadLinkProfile((dir / "spain-australia.toml").string());
  EXPECT_EQ(sa.name, "spain-australia");
  EXPECT_DOUBLE_EQ(sa.rtt_ms, 300.0);
  EXPECT_DOUBLE_EQ(sa.jitter_ms, 20.0);
  EXPECT_DOUBLE_EQ(sa.loss_pct, 2.0);
  const LinkProfile ex = loadLinkProfile((dir / "extreme.toml").string());
  EXPECT_DOUBLE_EQ(ex.rtt_ms, 1000.0);
  EXPECT_DOUBLE_EQ(ex.jitter_ms, 250.0);
  EXPECT_DOUBLE_EQ(ex.loss_pct, 10.0);
  EXPECT_NO_THROW(loadLinkProfile((dir / "lan.toml").string()));
  EXPECT_NO_THROW(loadLinkProfile((dir / "loopback.toml").string()));
}

TEST(LinkProfile, BadInputIsNamed) {
  auto message = [](const std::string& text) {
    try {
      parseLinkProfile(text, "x.toml");
    } catch (const ConfigError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(
      message("[link]\nrtt_ms = 'far'\n").find("x.toml: line 2: 'link.rtt_ms' must be a number"),
      std::string::npos);
  EXPECT_NE(message("[link]\nloss_pct = 95.0\n").find("'link.loss_pct'"), std::string::npos);
  EXPECT_NE(message("[link]\nlatency = 3\n").find("unknown key 'link.latency'"), std::string::npos);
  EXPECT_NE(message("[net]\n").find("unknown table 'net'"), std::string::npos);
  EXPECT_NE(message("").find("missing table [link]"), std::string::npos);
  EXPECT_NE(message("[link]\nrtt_ms = 10.0\njitter_ms = 6.0\n").find("exceeds the one-way delay"),
            std::string::npos);
  EXPECT_NE(message("[link\n").find("x.toml: line 1"), std::string::npos);
}

}  // namespace
}  // namespace telehand
