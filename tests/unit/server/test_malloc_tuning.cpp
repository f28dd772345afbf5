// The server's malloc tuning (telehand/app/malloc_tuning.h): glibc's per-thread cache off,
// added to whatever GLIBC_TUNABLES holds, unless that already sets the cache's size.
#include <gtest/gtest.h>

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

}  // namespace
}  // namespace telehand::app
