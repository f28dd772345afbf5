// The server's malloc tuning (telehand/app/malloc_tuning.h): glibc's per-thread cache off,
// added to whatever GLIBC_TUNABLES holds, unless that already sets the cache's size.
#include <gtest/gtest.h>
#include <malloc.h>

#include <cstdlib>

#include "telehand/app/malloc_tuning.h"

namespace telehand::app {
namespace {

TEST(MallocTuning, TurnsTheThreadCacheOffBesideOtherTunables) {
  EXPECT_EQ(tunablesWithoutThreadCache(nullptr), "glibc.malloc.tcache_count=0");
  EXPECT_EQ(tunablesWithoutThreadCache(""), "glibc.malloc.tcache_count=0");
  EXPECT_EQ(tunablesWithoutThreadCache("glibc.malloc.arena_max=2"),
            "glibc.malloc.arena_max=2:glibc.malloc.tcache_count=0");
  // A tunable that only begins like it is another one.
  EXPECT_EQ(tunablesWithoutThreadCache("glibc.malloc.tcache_count_x=1"),
            "glibc.malloc.tcache_count_x=1:glibc.malloc.tcache_count=0");
}

TEST(MallocTuning, AnOperatorsOwnCacheSizeStands) {
  EXPECT_EQ(tunablesWithoutThreadCache("glibc.malloc.tcache_count=3"), std::nullopt);
  EXPECT_EQ(tunablesWithoutThreadCache("glibc.malloc.arena_max=2:glibc.malloc.tcache_count=7"),
            std::nullopt);
  // Already off (the program run again): not run a third time.
  EXPECT_EQ(tunablesWithoutThreadCache("glibc.malloc.tcache_count=0"), std::nullopt);
}

TEST(MallocTuning, TheMmapThresholdIsTheOperatorsWhenTheTunablesSetIt) {
  EXPECT_FALSE(tunablesSetMmapThreshold(nullptr));
  EXPECT_FALSE(tunablesSetMmapThreshold("glibc.malloc.tcache_count=0"));
  EXPECT_FALSE(tunablesSetMmapThreshold("glibc.malloc.mmap_threshold_x=1"));
  EXPECT_TRUE(tunablesSetMmapThreshold("glibc.malloc.mmap_threshold=65536"));
  EXPECT_TRUE(
      tunablesSetMmapThreshold("glibc.malloc.tcache_count=0:glibc.malloc.mmap_threshold=1"));
}

TEST(MallocTuning, HeldLargeBlocksAreMappedAfterALargerOneWasFreed) {
  // glibc's moving threshold: freeing a mapped 4 MiB block raises it to 4 MiB, and the next
  // 1 MiB block comes from the heap. Held, the 1 MiB block is mapped (one more mapped
  // block while it lives).
  if (tunablesSetMmapThreshold(std::getenv("GLIBC_TUNABLES"))) GTEST_SKIP() << "set outside";
  ASSERT_TRUE(holdMmapThreshold());
  void* big = std::malloc(4u << 20);
  ASSERT_NE(big, nullptr);
  std::free(big);
  const std::size_t before = mallinfo2().hblks;
  void* block = std::malloc(1u << 20);
  ASSERT_NE(block, nullptr);
  const std::size_t during = mallinfo2().hblks;
  std::free(block);
  EXPECT_EQ(during, before + 1);
  EXPECT_EQ(mallinfo2().hblks, before);
}

}  // namespace
}  // namespace telehand::app
