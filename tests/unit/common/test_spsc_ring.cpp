// The fixed-size SPSC ring that carries every sample and model across the RT boundary.
#include <gtest/gtest.h>

#include <chrono>
#include <cstdint>
#include <memory>
#include <thread>

#include "telehand/core/rt/spsc_ring.h"

namespace telehand {
namespace {

TEST(SpscRing, StartsEmpty) {
  SpscRing<int, 4> ring;
  int v = -1;
  EXPECT_EQ(ring.size(), 0u);
  EXPECT_FALSE(ring.tryPop(v));
  EXPECT_EQ(v, -1) << "a failed pop leaves the output alone";
  EXPECT_EQ(ring.capacity(), 4u);
}

TEST(SpscRing, FifoOrder) {
  SpscRing<int, 8> ring;
  for (int i = 0; i < 5; ++i) ASSERT_TRUE(ring.tryPush(i * 10));
  EXPECT_EQ(ring.size(), 5u);
  for (int i = 0; i < 5; ++i) {
    int v = -1;
    ASSERT_TRUE(ring.tryPop(v));
    EXPECT_EQ(v, i * 10);
  }
  int v = -1;
  EXPECT_FALSE(ring.tryPop(v));
}

TEST(SpscRing, FullRejectsWithoutOverwriting) {
  SpscRing<int, 4> ring;
  for (int i = 0; i < 4; ++i) ASSERT_TRUE(ring.tryPush(i));
  EXPECT_EQ(ring.size(), 4u);
  EXPECT_FALSE(ring.tryPush(99));
  EXPECT_FALSE(ring.tryPush(100));
  int v = -1;
  ASSERT_TRUE(ring.tryPop(v));
  EXPECT_EQ(v, 0) << "the oldest element survives a rejected push";
  EXPECT_TRUE(ring.tryPush(4)) << "one slot free again";
  EXPECT_FALSE(ring.tryPush(5));
  for (int want = 1; want <= 4; ++want) {
    ASSERT_TRUE(ring.tryPop(v));
    EXPECT_EQ(v, want);
  }
  EXPECT_FALSE(ring.tryPop(v));
}

TEST(SpscRing, WrapsAroundManyTimes) {
  SpscRing<uint32_t, 4> ring;
  uint32_t next_in = 0;
  uint32_t next_out = 0;
  // Varying fill levels so that head and tail cross the slot boundary at every offset.
  for (int round = 0; round < 1000; ++round) {
    const int n = 1 + round % 4;
    for (int i = 0; i < n; ++i) ASSERT_TRUE(ring.tryPush(next_in++));
    EXPECT_EQ(ring.size(), static_cast<std::size_t>(n));
    for (int i = 0; i < n; ++i) {
      uint32_t v = 0;
      ASSERT_TRUE(ring.tryPop(v));
      ASSERT_EQ(v, next_out++);
    }
  }
  EXPECT_EQ(next_out, next_in);
  EXPECT_EQ(ring.size(), 0u);
}

TEST(SpscRing, CopiesWholeStructs) {
  struct Item {
    uint64_t a;
    double b[3];
  };
  SpscRing<Item, 2> ring;
  ASSERT_TRUE(ring.tryPush({7, {1.0, 2.0, 3.0}}));
  Item out{};
  ASSERT_TRUE(ring.tryPop(out));
  EXPECT_EQ(out.a, 7u);
  EXPECT_EQ(out.b[2], 3.0);
}

/// Payload whose fields must stay consistent: a torn copy would break the check word.
struct Tagged {
  uint64_t seq;
  uint64_t check;
  uint64_t pad[6];
};
constexpr uint64_t checkOf(uint64_t seq) { return seq * 0x9E3779B97F4A7C15ull ^ 0xA5A5A5A5ull; }

TEST(SpscRing, TwoThreadStressKeepsOrderAndLosesNothing) {
  constexpr uint64_t kItems = 1'000'000;
  using Ring = SpscRing<Tagged, 1024>;
  auto ring = std::make_unique<Ring>();
  // Bounded time: either side gives up after this, and the test fails instead of hanging.
  const auto give_up = std::chrono::steady_clock::now() + std::chrono::seconds(60);

  std::thread producer([&] {
    for (uint64_t i = 0; i < kItems;) {
      Tagged t{i, checkOf(i), {i, i, i, i, i, i}};
      if (ring->tryPush(t)) {
        ++i;
      } else {
        if (std::chrono::steady_clock::now() > give_up) return;
        std::this_thread::yield();
      }
    }
  });

  uint64_t received = 0;
  uint64_t out_of_order = 0;
  uint64_t torn = 0;
  while (received < kItems) {
    Tagged t{};
    if (ring->tryPop(t)) {
      if (t.seq != received) ++out_of_order;
      if (t.check != checkOf(t.seq) || t.pad[5] != t.seq) ++torn;
      ++received;
    } else {
      if (std::chrono::steady_clock::now() > give_up) break;
      std::this_thread::yield();
    }
  }
  producer.join();

  EXPECT_EQ(received, kItems) << "lost items (or timed out)";
  EXPECT_EQ(out_of_order, 0u);
  EXPECT_EQ(torn, 0u);
  Tagged extra{};
  EXPECT_FALSE(ring->tryPop(extra)) << "nothing beyond what was sent";
}

}  // namespace
}  // namespace telehand
