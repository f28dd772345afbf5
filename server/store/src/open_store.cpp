#include "telehand/server/store/open_store.h"

#include "telehand/server/store/pg_store.h"
#include "telehand/server/store/sqlite_store.h"

namespace telehand::server::store {

bool isPostgresUri(const std::string& spec) {
  return spec.starts_with("postgresql://") || spec.starts_with("postgres://");
}

std::unique_ptr<SessionStore> openStore(const std::string& spec, SessionStore::Mode mode) {
  if (isPostgresUri(spec)) return std::make_unique<PgStore>(spec, mode);
  return std::make_unique<SqliteStore>(spec, mode);
}

std::string describeStore(const std::string& spec) {
  return isPostgresUri(spec) ? redactUri(spec) : spec;
}

}  // namespace telehand::server::store
