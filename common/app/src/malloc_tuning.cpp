#include "telehand/app/malloc_tuning.h"

#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <string_view>

namespace telehand::app {

std::optional<std::string> tunablesWithoutThreadCache(const char* current) {
  const std::string_view now = current ? current : "";
  // GLIBC_TUNABLES is name=value pairs separated by colons.
  std::size_t at = 0;
  while (at <= now.size()) {
    const std::size_t end = std::min(now.find(':', at), now.size());
    if (now.substr(at, end - at).starts_with("glibc.malloc.tcache_count=")) return std::nullopt;
    at = end + 1;
  }
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
