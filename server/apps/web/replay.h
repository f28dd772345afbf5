#pragma once
/// Replay frames: a recorded session read from the store (read-only, an SQLite file or a
/// PostgreSQL URI, opened as telehand-records opens it), decimated evenly to at most `max_points`
/// samples.
#include <cstdint>
#include <optional>
#include <string>

namespace telehand::web {

/// {"type":"replay",...} for `session`, or nullopt when the store does not hold it. Throws
/// StoreError when the store cannot be read.
std::optional<std::string> replayFrame(const std::string& db, uint64_t session,
                                       std::size_t max_points);
/// {"type":"records","sessions":[...],"total":N}: the newest kMaxRecordsListed sessions the
/// store holds (in id order), and how many it holds.
inline constexpr std::size_t kMaxRecordsListed = 1000;
std::string recordsFrame(const std::string& db);

}  // namespace telehand::web
