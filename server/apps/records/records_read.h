#pragma once
/// telehand-records' reading commands: list, show, export.
#include <cstdint>
#include <string>

#include "telehand/server/store/store.h"

namespace telehand::records {

/// Every session in the store, one line each.
int runList(server::store::SessionStore& store);
/// One session: summary, events and exploration reaches.
int runShow(server::store::SessionStore& store, const server::store::SessionInfo& info,
            bool digest = false);
/// One session's samples as CSV, to `out_path` or stdout.
int runExport(server::store::SessionStore& store, uint64_t session_id, const std::string& out_path);

}  // namespace telehand::records
