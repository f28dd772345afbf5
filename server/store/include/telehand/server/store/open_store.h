#pragma once
/// The record store a program's `--db` names: a postgresql:// or postgres:// URI is a
/// PostgreSQL database (PgStore), anything else the path of an SQLite file (SqliteStore, the
/// default).
#include <memory>
#include <string>

#include "telehand/server/store/store.h"

namespace telehand::server::store {

/// True when `spec` is a PostgreSQL connection URI.
bool isPostgresUri(const std::string& spec);

/// Opens the store `spec` names; StoreError naming it (a URI without its password) when it
/// cannot be opened or is refused.
std::unique_ptr<SessionStore> openStore(const std::string& spec,
                                        SessionStore::Mode mode = SessionStore::Mode::kReadWrite);

/// What may be shown of `spec` in messages and logs: a path as it is, a URI without its
/// password.
std::string describeStore(const std::string& spec);

}  // namespace telehand::server::store
