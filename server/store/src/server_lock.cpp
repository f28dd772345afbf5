#include "telehand/server/store/server_lock.h"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "telehand/core/error.h"

namespace telehand::server::store {

ServerLock::ServerLock(const std::string& db_path, bool pool) {
  fd_ = ::open(db_path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd_ < 0) {
    throw StoreError("cannot lock the record " + db_path + ": " + std::strerror(errno));
  }
  if (::flock(fd_, (pool ? LOCK_SH : LOCK_EX) | LOCK_NB) != 0) {
    const int err = errno;
    ::close(fd_);
    fd_ = -1;
    if (err == EWOULDBLOCK) {
      throw StoreError(
          "the record " + db_path +
          (pool ? " is served by a telehand-server that is not of a pool; servers share an "
                  "SQLite file only as a pool (--pool, each of them): stop it, or give this one "
                  "another --db"
                : " is already served by another telehand-server; one server per SQLite file "
                  "(a second one would take on the same sessions), or several as a pool "
                  "(--pool, each of them): stop it, or give this one another --db"));
    }
    throw StoreError("cannot lock the record " + db_path + ": " + std::strerror(err));
  }
}

ServerLock::~ServerLock() {
  if (fd_ >= 0) ::close(fd_);
}

}  // namespace telehand::server::store
