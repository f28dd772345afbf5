#pragma once
/// telehand-records' reading commands: list, show, export.
#include <cstdint>
#include <string>

#include "telehand/server/store/sqlite_store.h"

namespace telehand::records {

/// Every session in the store, one line each.
int runList(server::store::SqliteStore& store, const std::string& db);
/// One session: summary, events and exploration reaches.
int runShow(server::store::SqliteStore& store, const server::store::SessionInfo& info);
/// One session's samples as CSV, to `out_path` or stdout.
int runExport(server::store::SqliteStore& store, uint64_t session_id, const std::string& out_path);

}  // namespace telehand::records
