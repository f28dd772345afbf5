#include "telehand/app/malloc_tuning.h"

#include <malloc.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <string_view>

namespace telehand::app {

namespace {
/// Whether GLIBC_TUNABLES (name=value pairs separated by colons) sets `name`.
bool sets(std::string_view tunables, std::string_view name) {
  std::size_t at = 0;
  while (at <= tunables.size()) {
    const std::size_t end = std::min(tunables.find(':', at), tunables.size());
    const std::string_view pair = tunables.substr(at, end - at);
    if (pair.size() > name.size() && pair.starts_with(name) && pair[name.size()] == '=') {
      return true;
    }
    at = end + 1;
  }
  return false;
}
}  // namespace

bool tunablesSetMmapThreshold(const char* current) {
  return sets(current ? current : "", "glibc.malloc.mmap_threshold");
}

bool holdMmapThreshold() {
  if (tunablesSetMmapThreshold(getenv("GLIBC_TUNABLES"))) return false;
  return mallopt(M_MMAP_THRESHOLD, static_cast<int>(kMmapThresholdBytes)) == 1;
}

std::optional<std::string> tunablesWithoutThreadCache(const char* current) {
  const std::string_view now = current ? current : "";
  if (sets(now, "glibc.malloc.tcache_count")) return std::nullopt;
  if (now.empty()) return std::string(kNoThreadCacheTunable);
  return std::string(now) + ":" + kNoThreadCacheTunable;
}

void runWithoutMallocThreadCache(char** argv) {
  const std::optional<std::string> tunables = tunablesWithoutThreadCache(getenv("GLIBC_TUNABLES"));
  if (!tunables) return;
  if (setenv("GLIBC_TUNABLES", tunables->c_str(), 1) != 0) return;
  execv("/proc/self/exe", argv);
  // Still here: running on with the cache is better than not running.
  std::cerr << "warning: cannot run again with glibc's thread cache off (" << std::strerror(errno)
            << "); memory freed by a burst of sessions may stay resident\n";
}

}  // namespace telehand::app
