#pragma once
/// One server per SQLite record (docs/recovery.md): a server recovers the sessions its record
/// holds open, so a second server on the same file would take on, write and close the same
/// sessions. The server holds an exclusive lock on the file while it runs (flock, which
/// SQLite's own locks do not see, so readers such as telehand-records are not affected); a
/// second one is refused with a message naming the file. The lock goes with the process,
/// however it ends. Servers of a pool (docs/pool.md) share the file: they hold the lock
/// shared, which keeps out a server that is not of the pool, and are kept out by one.
#include <string>

namespace telehand::server::store {

class ServerLock {
 public:
  /// Locks `db_path` (an existing file); StoreError naming it when another process holds it
  /// or it cannot be opened.
  /// `pool`: a shared lock, held beside the other servers of the pool.
  explicit ServerLock(const std::string& db_path, bool pool = false);
  ~ServerLock();
  ServerLock(const ServerLock&) = delete;
  ServerLock& operator=(const ServerLock&) = delete;

 private:
  int fd_ = -1;
};

}  // namespace telehand::server::store
