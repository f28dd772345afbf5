#include "telehand/server/store/sqlite_store.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <type_traits>

#include "sample_fields.h"
#include "telehand/core/clock.h"
#include "telehand/core/error.h"

namespace telehand::server::store {

namespace {

using detail::fieldNames;
using detail::visitFields;

// ---- Schema ---------------------------------------------------------------------------------
//
// The file says what it is in its SQLite header: application_id is kApplicationId and
// user_version the schema number. Schema 1 (no marker in the header, user_version 0) kept each
// sample as a BLOB of the C struct's memory next to a few query columns; schema 2 keeps every
// field of the sample in a column of its own, named as in the CSV export (sampleColumns());
// schema 3 adds the session's owner (the DDS participant that opened it, docs/security.md);
// schema 4 adds lessons, lesson runs and their trials (docs/lessons.md); schema 5 whether a
// lesson lets a supervisor take over its demonstration (lessons.takeover); schema 6 the pool's
// tables (docs/pool.md); schema 7 the massage's web per sample (depth and force per finger).
constexpr int32_t kApplicationId = 0x54484E44;  // "THND"
constexpr int kSchemaVersion = 7;
constexpr int kPoolSchemaVersion = 6;
constexpr int kTakeoverSchemaVersion = 5;
constexpr int kLessonSchemaVersion = 4;
constexpr int kOwnerSchemaVersion = 3;
constexpr int kColumnSchemaVersion = 2;
constexpr int kBlobSchemaVersion = 1;

// Tables other than samples; the same in schemas 1 (session_files came late in it), 2 and 3
// but for sessions.owner (addOwnerColumn() brings an older sessions table up to date).
constexpr const char* kOtherTables = R"sql(
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS sessions (
  id INTEGER PRIMARY KEY,
  user TEXT NOT NULL, case_name TEXT NOT NULL, mode TEXT NOT NULL,
  state TEXT NOT NULL, started_ns INTEGER NOT NULL, ended_ns INTEGER NOT NULL DEFAULT 0,
  samples_expected INTEGER NOT NULL DEFAULT 0, owner TEXT NOT NULL DEFAULT '');
CREATE TABLE IF NOT EXISTS events (
  session_id INTEGER NOT NULL,
  time_ns INTEGER NOT NULL,
  kind TEXT NOT NULL,
  text TEXT NOT NULL);
CREATE INDEX IF NOT EXISTS events_by_session ON events(session_id, time_ns);
CREATE TABLE IF NOT EXISTS explorations (
  session_id INTEGER NOT NULL,
  phase TEXT NOT NULL,
  direction TEXT NOT NULL,
  angle_deg REAL NOT NULL,
  force_n REAL NOT NULL);
CREATE TABLE IF NOT EXISTS session_files (
  session_id INTEGER NOT NULL,
  name TEXT NOT NULL,
  content BLOB NOT NULL,
  PRIMARY KEY (session_id, name));
)sql";

// Schema 4's tables (addLessonTables() adds them to an older file).
constexpr const char* kLessonTables = R"sql(
CREATE TABLE IF NOT EXISTS lessons (
  id INTEGER PRIMARY KEY,
  name TEXT NOT NULL, demo_session INTEGER NOT NULL, case_name TEXT NOT NULL,
  technique TEXT NOT NULL, schedule TEXT NOT NULL, guided INTEGER NOT NULL,
  attempts INTEGER NOT NULL, trial_s REAL NOT NULL, assessment INTEGER NOT NULL,
  targets TEXT NOT NULL, created_ns INTEGER NOT NULL, takeover INTEGER NOT NULL DEFAULT 0);
CREATE TABLE IF NOT EXISTS lesson_runs (
  session_id INTEGER PRIMARY KEY, lesson_id INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS trials (
  session_id INTEGER NOT NULL, idx INTEGER NOT NULL, phase TEXT NOT NULL,
  authority REAL NOT NULL, first_seq INTEGER NOT NULL, last_seq INTEGER NOT NULL,
  overall REAL NOT NULL, figures TEXT NOT NULL,
  PRIMARY KEY (session_id, idx));
)sql";

// Schema 6's tables: a pool of servers on one record (addPoolTables() adds them to an older
// file). Times on the record's clock (for an SQLite file, the host's wall clock).
constexpr const char* kPoolTables = R"sql(
CREATE TABLE IF NOT EXISTS pool_servers (
  server TEXT PRIMARY KEY, lease_until_ns INTEGER NOT NULL, started_ns INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS session_owners (
  session_id INTEGER PRIMARY KEY, server TEXT NOT NULL, since_ns INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS pool_opens (
  open_key TEXT PRIMARY KEY, server TEXT NOT NULL, at_ns INTEGER NOT NULL,
  session_id INTEGER NOT NULL DEFAULT 0);
CREATE TABLE IF NOT EXISTS checkpoints (
  session_id INTEGER PRIMARY KEY, seq INTEGER NOT NULL, time_ns INTEGER NOT NULL,
  data BLOB NOT NULL);
)sql";

/// Integer fields are INTEGER NOT NULL; floating-point ones REAL, NULL standing for NaN
/// (SQLite keeps no NaN). ±inf are kept as they are.
std::string samplesTableSql() {
  std::string sql =
      "CREATE TABLE IF NOT EXISTS samples (\n"
      "  session_id INTEGER NOT NULL REFERENCES sessions(id)";
  Sample probe{};
  std::size_t i = 0;
  visitFields(probe, [&](auto& v) {
    using T = std::remove_reference_t<decltype(v)>;
    sql += ",\n  " + fieldNames()[i++] + (std::is_integral_v<T> ? " INTEGER NOT NULL" : " REAL");
  });
  sql += ",\n  valid INTEGER NOT NULL,\n  PRIMARY KEY (session_id, seq)) WITHOUT ROWID;\n";
  return sql;
}

std::string insertSampleSql() {
  std::string cols = "session_id";
  std::string marks = "?";
  for (const auto& n : fieldNames()) {
    cols += ", " + n;
    marks += ",?";
  }
  return "INSERT OR IGNORE INTO samples (" + cols + ", valid) VALUES (" + marks + ",?)";
}

/// SELECT of every field in visitFields() order, then valid. A record from before schema 7
/// has no web columns: they read as 0.
std::string selectSamplesSql(bool range, bool web_columns) {
  std::string cols;
  for (std::size_t i = 0; i < fieldNames().size(); ++i)
    cols += (web_columns || !detail::isWebField(i) ? fieldNames()[i] : "0") + ", ";
  return "SELECT " + cols + "valid FROM samples WHERE session_id = ?" +
         (range ? " AND seq >= ? AND seq <= ?" : "") + " ORDER BY seq";
}

/// Binds session_id, the fields and valid to an insert statement.
void bindSample(sqlite3_stmt* st, uint64_t session_id, const Sample& s, bool valid) {
  int col = 1;
  sqlite3_bind_int64(st, col++, static_cast<sqlite3_int64>(session_id));
  visitFields(s, [&](const auto& v) {
    using T = std::remove_cvref_t<decltype(v)>;
    if constexpr (std::is_integral_v<T>) {
      sqlite3_bind_int64(st, col++, static_cast<sqlite3_int64>(v));
    } else if (std::isnan(v)) {
      sqlite3_bind_null(st, col++);
    } else {
      sqlite3_bind_double(st, col++, static_cast<double>(v));
    }
  });
  sqlite3_bind_int(st, col, valid ? 1 : 0);
}

/// Reads the fields from a row of selectSamplesSql(); returns valid.
bool readSample(sqlite3_stmt* st, uint64_t session_id, Sample& s) {
  int col = 0;
  s.session_id = session_id;
  visitFields(s, [&](auto& v) {
    using T = std::remove_reference_t<decltype(v)>;
    if constexpr (std::is_integral_v<T>) {
      v = static_cast<T>(sqlite3_column_int64(st, col++));
    } else if (sqlite3_column_type(st, col) == SQLITE_NULL) {
      v = std::numeric_limits<T>::quiet_NaN();
      ++col;
    } else {
      v = static_cast<T>(sqlite3_column_double(st, col++));
    }
  });
  return sqlite3_column_int(st, col) != 0;
}

// ---- Schema 1: the sample as a BLOB ---------------------------------------------------------
//
// The bytes of the C struct as g++ laid it out on x86-64 (little-endian, natural alignment):
// session_id u64 @0, seq u64 @8, source_time_ns i64 @16, model_version u32 @24, flags u32 @28,
// fingers[2] @32 and @136, each 104 bytes (position_m f64[3] @0, orientation_q f64[4] @24,
// fsr_n f32[4] @56, tangential_n f32 @72, normal_n f32 @76, command_n f64[3] @80),
// mcp_angles_rad f64[3] @240, mcp_torque_nm f64[3] @264, passivity_energy_j f32 @288,
// passivity_damping f32 @292. Blob format 2 is those 296 bytes; blob format 1 the first 288
// (no passivity fields, read as zero).
constexpr int kBlobFormat1Bytes = 288;
constexpr int kBlobFormat2Bytes = 296;

class BlobReader {
 public:
  explicit BlobReader(const unsigned char* p) : p_(p) {}
  uint64_t u64(std::size_t at) const {
    uint64_t v = 0;
    for (int i = 7; i >= 0; --i) v = (v << 8) | p_[at + static_cast<std::size_t>(i)];
    return v;
  }
  uint32_t u32(std::size_t at) const {
    uint32_t v = 0;
    for (int i = 3; i >= 0; --i) v = (v << 8) | p_[at + static_cast<std::size_t>(i)];
    return v;
  }
  double f64(std::size_t at) const { return std::bit_cast<double>(u64(at)); }
  float f32(std::size_t at) const { return std::bit_cast<float>(u32(at)); }

 private:
  const unsigned char* p_;
};

/// Decodes a schema-1 sample blob; false when format and size do not match a known layout.
bool decodeBlob(int format, const void* data, int bytes, Sample& s) {
  const bool v1 = format == 1 && bytes == kBlobFormat1Bytes;
  const bool v2 = format == 2 && bytes == kBlobFormat2Bytes;
  if (!(v1 || v2) || data == nullptr) return false;
  const BlobReader b(static_cast<const unsigned char*>(data));
  s = Sample{};
  s.session_id = b.u64(0);
  s.seq = b.u64(8);
  s.source_time_ns = static_cast<int64_t>(b.u64(16));
  s.model_version = b.u32(24);
  s.flags = b.u32(28);
  for (std::size_t k = 0; k < 2; ++k) {
    const std::size_t f = 32 + 104 * k;
    auto& finger = s.fingers[k];
    for (std::size_t i = 0; i < 3; ++i) finger.position_m[i] = b.f64(f + 8 * i);
    for (std::size_t i = 0; i < 4; ++i) finger.orientation_q[i] = b.f64(f + 24 + 8 * i);
    for (std::size_t i = 0; i < 4; ++i) finger.fsr_n[i] = b.f32(f + 56 + 4 * i);
    finger.tangential_n = b.f32(f + 72);
    finger.normal_n = b.f32(f + 76);
    for (std::size_t i = 0; i < 3; ++i) finger.command_n[i] = b.f64(f + 80 + 8 * i);
  }
  for (std::size_t i = 0; i < 3; ++i) s.mcp_angles_rad[i] = b.f64(240 + 8 * i);
  for (std::size_t i = 0; i < 3; ++i) s.mcp_torque_nm[i] = b.f64(264 + 8 * i);
  if (v2) {
    s.passivity_energy_j = b.f32(288);
    s.passivity_damping = b.f32(292);
  }
  return true;
}

/// "SQLite on '<file>'" for an error message: which record it was.
std::string sqliteOn(sqlite3* db) {
  const char* file = sqlite3_db_filename(db, "main");
  return std::string("SQLite on '") + (file && *file ? file : ":memory:") + "'";
}

/// The statement's opening words for an error message (the whole of a short one).
std::string statementOf(const char* sql) {
  std::string s = sql ? sql : "?";
  if (s.size() > 72) s = s.substr(0, 69) + "...";
  return s;
}

class Statement {
 public:
  Statement(sqlite3* db, const char* sql) : db_(db) {
    if (sqlite3_prepare_v2(db, sql, -1, &s_, nullptr) != SQLITE_OK) {
      throw StoreError(sqliteOn(db) + ": cannot prepare '" + sql + "': " + sqlite3_errmsg(db));
    }
  }
  Statement(sqlite3* db, const std::string& sql) : Statement(db, sql.c_str()) {}
  ~Statement() { sqlite3_finalize(s_); }
  Statement(const Statement&) = delete;
  Statement& operator=(const Statement&) = delete;
  sqlite3_stmt* get() const { return s_; }
  bool step() {
    const int rc = sqlite3_step(s_);
    if (rc == SQLITE_ROW) return true;
    if (rc == SQLITE_DONE) return false;
    throw StoreError(sqliteOn(db_) + ": " + sqlite3_errmsg(db_) +
                     " (in: " + statementOf(sqlite3_sql(s_)) + ")");
  }
  std::string text(int col) const {
    const auto* t = sqlite3_column_text(s_, col);
    return t ? reinterpret_cast<const char*>(t) : "";
  }

 private:
  sqlite3* db_;
  sqlite3_stmt* s_ = nullptr;
};

int64_t queryInt(sqlite3* db, const char* sql) {
  Statement st(db, sql);
  return st.step() ? sqlite3_column_int64(st.get(), 0) : 0;
}

}  // namespace

/// What an opened file holds, read from its header and tables; refuses what is not ours.
SqliteStore::Layout SqliteStore::inspect() {
  int64_t app_id = 0, version = 0;
  std::vector<std::string> tables;
  try {  // a file that is not SQLite at all fails here, with a message lacking the path
    app_id = queryInt(db_, "PRAGMA application_id");
    version = queryInt(db_, "PRAGMA user_version");
    Statement st(db_, "SELECT name FROM sqlite_master WHERE type = 'table' ORDER BY name");
    while (st.step()) tables.push_back(st.text(0));
  } catch (const StoreError&) {
    throw StoreError("cannot read record database '" + path_ + "': " + sqlite3_errmsg(db_));
  }
  const auto has = [&](const char* t) {
    return std::find(tables.begin(), tables.end(), t) != tables.end();
  };
  if (app_id == kApplicationId) {
    if (version > kSchemaVersion) {
      throw StoreError("'" + path_ + "' was written by a newer telehand (schema " +
                       std::to_string(version) + ", this program knows up to " +
                       std::to_string(kSchemaVersion) + "); it was left untouched");
    }
    if (version == kColumnSchemaVersion && has("samples") && has("sessions")) {
      return Layout::kColumns;
    }
    if (version == kOwnerSchemaVersion && has("samples") && has("sessions")) {
      return Layout::kOwner;
    }
    if (version == kLessonSchemaVersion && has("samples") && has("sessions") && has("lessons")) {
      return Layout::kLessons;
    }
    if (version == kTakeoverSchemaVersion && has("samples") && has("lessons")) {
      return Layout::kTakeover;
    }
    if (version == kPoolSchemaVersion && has("samples") && has("pool_servers")) {
      return Layout::kPool;
    }
    if (version != kSchemaVersion || !has("samples")) {
      throw StoreError("'" + path_ + "' carries the telehand marker but schema " +
                       std::to_string(version) +
                       (has("samples") ? "" : " without a samples table") +
                       ", which this program does not know (it knows " +
                       std::to_string(kSchemaVersion) + "); it was left untouched");
    }
    return Layout::kCurrent;
  }
  if (app_id != 0) {
    char hex[16];
    std::snprintf(hex, sizeof hex, "0x%08x", static_cast<uint32_t>(app_id));
    throw StoreError("'" + path_ + "' is not a telehand record database (SQLite application_id " +
                     hex + ", telehand's is 0x54484e44); it was left untouched");
  }
  if (tables.empty() && version == 0) return Layout::kEmpty;
  if (version == 0 && has("samples") && has("sessions")) {
    bool format = false, data = false;
    Statement st(db_, "SELECT name FROM pragma_table_info('samples')");
    while (st.step()) {
      const std::string c = st.text(0);
      format = format || c == "format";
      data = data || c == "data";
    }
    if (format && data) return Layout::kBlob;
  }
  std::string list;
  for (const auto& t : tables) list += (list.empty() ? "" : ", ") + t;
  throw StoreError("'" + path_ + "' is not a telehand record database (user_version " +
                   std::to_string(version) + ", tables: " + (list.empty() ? "none" : list) +
                   "; no telehand marker); it was left untouched");
}

SqliteStore::SqliteStore(const std::string& path, Mode mode) : path_(path) {
  int flags = SQLITE_OPEN_FULLMUTEX;
  if (mode == Mode::kReadWrite) {
    const auto dir = std::filesystem::path(path).parent_path();
    std::error_code ec;
    if (!dir.empty()) std::filesystem::create_directories(dir, ec);
    if (ec)
      throw StoreError("cannot create the record directory '" + dir.string() +
                       "': " + ec.message());
    flags |= SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE;
  } else {
    if (!std::filesystem::exists(path))
      throw StoreError("record database '" + path + "' does not exist");
    flags |= SQLITE_OPEN_READONLY;
  }
  if (sqlite3_open_v2(path.c_str(), &db_, flags, nullptr) != SQLITE_OK) {
    const std::string why = db_ ? sqlite3_errmsg(db_) : "out of memory";
    sqlite3_close(db_);
    db_ = nullptr;
    throw StoreError("cannot open record database '" + path + "': " + why);
  }
  sqlite3_busy_timeout(db_, 5000);
  try {
    // Nothing is written before inspect() has said the file is ours (or empty).
    Layout layout = inspect();
    if (mode == Mode::kReadOnly) {
      if (layout == Layout::kEmpty) {
        throw StoreError("'" + path + "' is not a telehand record database (it is empty)");
      }
      web_columns_ = hasWebColumns();
      return;  // a schema-1 file is read as it is (forEachSample decodes its blobs)
    }
    if (layout != Layout::kCurrent) {
      exec("BEGIN IMMEDIATE");
      try {
        layout = inspect();  // another program may have got there first
        if (layout == Layout::kEmpty) {
          exec(kOtherTables);
          exec(kLessonTables);
          exec(kPoolTables);
          exec(samplesTableSql().c_str());
          exec(("PRAGMA application_id = " + std::to_string(kApplicationId) + ";").c_str());
          exec(("PRAGMA user_version = " + std::to_string(kSchemaVersion) + ";").c_str());
        } else if (layout == Layout::kBlob) {
          migrateFromBlobs();
          addOwnerColumn();
          addLessonTables();
          addTakeoverColumn();
          addPoolTables();
          addWebColumns();
        } else if (layout == Layout::kColumns) {
          addOwnerColumn();
          addLessonTables();
          addTakeoverColumn();
          addPoolTables();
          addWebColumns();
        } else if (layout == Layout::kOwner) {
          addLessonTables();
          addTakeoverColumn();
          addPoolTables();
          addWebColumns();
        } else if (layout == Layout::kLessons) {
          addTakeoverColumn();
          addPoolTables();
          addWebColumns();
        } else if (layout == Layout::kTakeover) {
          addPoolTables();
          addWebColumns();
        } else if (layout == Layout::kPool) {
          addWebColumns();
        }
        exec("COMMIT");
      } catch (...) {
        sqlite3_exec(db_, "ROLLBACK", nullptr, nullptr, nullptr);
        throw;
      }
    }
    exec("PRAGMA journal_mode=WAL;");
    // The page cache (SQLite's default 2 MB) grows with the records toward its size; a
    // server's writes append at the tables' ends, which 256 KiB holds.
    exec("PRAGMA cache_size=-256;");
    exec("PRAGMA synchronous=NORMAL;");
    if (!insert_sample_) insert_sample_ = prepare(insertSampleSql().c_str());
  } catch (...) {
    sqlite3_finalize(insert_sample_);
    sqlite3_close(db_);
    throw;
  }
}

bool SqliteStore::hasTable(const char* name) {
  Statement st(db_, "SELECT count(*) FROM sqlite_master WHERE type = 'table' AND name = ?");
  sqlite3_bind_text(st.get(), 1, name, -1, SQLITE_STATIC);
  return st.step() && sqlite3_column_int(st.get(), 0) > 0;
}

/// Schema 3 -> 4 inside the caller's transaction: the lesson tables, empty.
void SqliteStore::addLessonTables() {
  exec(kLessonTables);
  exec(("PRAGMA user_version = " + std::to_string(kLessonSchemaVersion) + ";").c_str());
  spdlog::info("record database '{}': schema {} -> {} (lessons and their trials)", path_,
               kOwnerSchemaVersion, kLessonSchemaVersion);
}

bool SqliteStore::hasTakeoverColumn() {
  Statement st(db_, "SELECT name FROM pragma_table_info('lessons') WHERE name = 'takeover'");
  return st.step();
}

/// Schema 4 -> 5 inside the caller's transaction: lessons say whether a supervisor may take
/// over their demonstration (no, for the lessons made before).
void SqliteStore::addTakeoverColumn() {
  if (!hasTakeoverColumn()) {
    exec("ALTER TABLE lessons ADD COLUMN takeover INTEGER NOT NULL DEFAULT 0;");
  }
  exec(("PRAGMA user_version = " + std::to_string(kTakeoverSchemaVersion) + ";").c_str());
  spdlog::info("record database '{}': schema {} -> {} (lessons may allow a take-over)", path_,
               kLessonSchemaVersion, kTakeoverSchemaVersion);
}

/// Schema 5 -> 6 inside the caller's transaction: the pool's tables, empty (the sessions
/// recorded before have no owner in them; a pool takes them on as it takes orphans).
void SqliteStore::addPoolTables() {
  exec(kPoolTables);
  exec(("PRAGMA user_version = " + std::to_string(kPoolSchemaVersion) + ";").c_str());
  spdlog::info("record database '{}': schema {} -> {} (a pool of servers on one record)", path_,
               kTakeoverSchemaVersion, kPoolSchemaVersion);
}

bool SqliteStore::hasWebColumns() {
  Statement st(db_, "SELECT count(*) FROM pragma_table_info('samples') WHERE name = ?");
  const std::string& last = fieldNames().back();
  sqlite3_bind_text(st.get(), 1, last.c_str(), -1, SQLITE_STATIC);
  return st.step() && sqlite3_column_int(st.get(), 0) > 0;
}

/// Schema 6 -> 7 inside the caller's transaction: samples gain the massage's web per finger
/// (0 for the samples recorded before).
void SqliteStore::addWebColumns() {
  for (std::size_t i = 0; i < fieldNames().size(); ++i) {
    if (!detail::isWebField(i)) continue;
    Statement st(db_, "SELECT count(*) FROM pragma_table_info('samples') WHERE name = ?");
    sqlite3_bind_text(st.get(), 1, fieldNames()[i].c_str(), -1, SQLITE_STATIC);
    if (st.step() && sqlite3_column_int(st.get(), 0) > 0) continue;
    exec(("ALTER TABLE samples ADD COLUMN " + fieldNames()[i] + " REAL DEFAULT 0;").c_str());
  }
  exec(("PRAGMA user_version = " + std::to_string(kSchemaVersion) + ";").c_str());
  spdlog::info("record database '{}': schema {} -> {} (samples keep the massage's web)", path_,
               kPoolSchemaVersion, kSchemaVersion);
}

bool SqliteStore::hasOwnerColumn() {
  Statement st(db_, "SELECT name FROM pragma_table_info('sessions') WHERE name = 'owner'");
  return st.step();
}

/// Schema 2 -> 3 inside the caller's transaction: sessions gain their owner ('' for the
/// sessions recorded before owners were).
void SqliteStore::addOwnerColumn() {
  if (!hasOwnerColumn()) exec("ALTER TABLE sessions ADD COLUMN owner TEXT NOT NULL DEFAULT '';");
  exec(("PRAGMA user_version = " + std::to_string(kOwnerSchemaVersion) + ";").c_str());
  spdlog::info("record database '{}': schema {} -> {} (sessions record their owner)", path_,
               kColumnSchemaVersion, kOwnerSchemaVersion);
}

/// Schema 1 -> 2 inside the caller's transaction: every blob decoded into the columns, the
/// old table dropped only when all its rows arrived.
void SqliteStore::migrateFromBlobs() {
  const int64_t old_rows = queryInt(db_, "SELECT count(*) FROM samples");
  exec("ALTER TABLE samples RENAME TO samples_schema1;");
  exec(kOtherTables);
  exec(samplesTableSql().c_str());
  insert_sample_ = prepare(insertSampleSql().c_str());
  Statement old(db_, "SELECT session_id, seq, valid, format, data FROM samples_schema1");
  int64_t copied = 0;
  while (old.step()) {
    const auto session_id = static_cast<uint64_t>(sqlite3_column_int64(old.get(), 0));
    const int format = sqlite3_column_int(old.get(), 3);
    const void* data = sqlite3_column_blob(old.get(), 4);
    const int bytes = sqlite3_column_bytes(old.get(), 4);
    Sample s{};
    if (!decodeBlob(format, data, bytes, s)) {
      throw StoreError("cannot migrate '" + path_ + "': sample " +
                       std::to_string(sqlite3_column_int64(old.get(), 1)) + " of session " +
                       std::to_string(session_id) + " has blob format " + std::to_string(format) +
                       " (" + std::to_string(bytes) + " bytes), known are 1 (" +
                       std::to_string(kBlobFormat1Bytes) + " bytes) and 2 (" +
                       std::to_string(kBlobFormat2Bytes) + " bytes); the file was left as it was");
    }
    s.seq = static_cast<uint64_t>(sqlite3_column_int64(old.get(), 1));  // the key as stored
    sqlite3_reset(insert_sample_);
    bindSample(insert_sample_, session_id, s, sqlite3_column_int(old.get(), 2) != 0);
    if (sqlite3_step(insert_sample_) != SQLITE_DONE) {
      throw StoreError("cannot migrate '" + path_ + "': " + sqlite3_errmsg(db_));
    }
    copied += sqlite3_changes(db_);
  }
  const int64_t new_rows = queryInt(db_, "SELECT count(*) FROM samples");
  if (copied != old_rows || new_rows != old_rows) {
    throw StoreError("cannot migrate '" + path_ + "': " + std::to_string(old_rows) +
                     " samples in the old table but " + std::to_string(new_rows) +
                     " in the new one; the file was left as it was");
  }
  exec("DROP TABLE samples_schema1;");
  exec("DELETE FROM meta WHERE key = 'sample_format';");
  exec(("PRAGMA application_id = " + std::to_string(kApplicationId) + ";").c_str());
  exec(("PRAGMA user_version = " + std::to_string(kSchemaVersion) + ";").c_str());
  spdlog::info(
      "record database '{}': migrated {} samples from schema {} (one blob per sample) "
      "to schema {} (one column per field)",
      path_, copied, kBlobSchemaVersion, kSchemaVersion);
}

SqliteStore::~SqliteStore() {
  sqlite3_finalize(insert_sample_);
  sqlite3_close(db_);
}

void SqliteStore::releaseMemory() { sqlite3_db_release_memory(db_); }

std::size_t SqliteStore::cacheBytes() const {
  int current = 0, highest = 0;
  if (sqlite3_db_status(db_, SQLITE_DBSTATUS_CACHE_USED, &current, &highest, 0) != SQLITE_OK) {
    return 0;
  }
  return static_cast<std::size_t>(std::max(current, 0));
}

void SqliteStore::exec(const char* sql) {
  char* err = nullptr;
  if (sqlite3_exec(db_, sql, nullptr, nullptr, &err) != SQLITE_OK) {
    std::string msg = err ? err : "unknown error";
    sqlite3_free(err);
    throw StoreError("SQLite on '" + path_ + "': " + msg);
  }
}

sqlite3_stmt* SqliteStore::prepare(const char* sql) {
  sqlite3_stmt* s = nullptr;
  if (sqlite3_prepare_v2(db_, sql, -1, &s, nullptr) != SQLITE_OK) {
    throw StoreError("SQLite on '" + path_ + "': cannot prepare '" + statementOf(sql) +
                     "': " + sqlite3_errmsg(db_));
  }
  return s;
}

uint64_t SqliteStore::createSession(const SessionInfo& info) {
  Statement st(db_,
               "INSERT INTO sessions (user, case_name, mode, state, started_ns, owner) "
               "VALUES (?,?,?,?,?,?)");
  sqlite3_bind_text(st.get(), 1, info.user.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_text(st.get(), 2, info.case_name.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_text(st.get(), 3, info.mode.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_text(st.get(), 4, "active", -1, SQLITE_STATIC);
  sqlite3_bind_int64(st.get(), 5, info.started_ns);
  sqlite3_bind_text(st.get(), 6, info.owner.c_str(), -1, SQLITE_TRANSIENT);
  st.step();
  return static_cast<uint64_t>(sqlite3_last_insert_rowid(db_));
}

uint64_t SqliteStore::appendSamples(uint64_t session_id, std::span<const Sample> samples,
                                    std::span<const uint8_t> valid) {
  if (samples.empty()) return 0;
  exec("BEGIN");
  uint64_t added = 0;
  try {
    for (std::size_t i = 0; i < samples.size(); ++i) {
      const auto& s = samples[i];
      const bool ok = i < valid.size() ? valid[i] != 0 : true;
      sqlite3_stmt* st = insert_sample_;
      sqlite3_reset(st);
      bindSample(st, session_id, s, ok);
      if (sqlite3_step(st) != SQLITE_DONE) {
        throw StoreError("SQLite on '" + path_ + "': cannot store sample " + std::to_string(s.seq) +
                         " of session " + std::to_string(session_id) + ": " + sqlite3_errmsg(db_));
      }
      added += static_cast<uint64_t>(sqlite3_changes(db_));
    }
    exec("COMMIT");
  } catch (...) {
    sqlite3_exec(db_, "ROLLBACK", nullptr, nullptr, nullptr);
    throw;
  }
  return added;
}

void SqliteStore::appendEvent(uint64_t session_id, const EventRecord& e) {
  Statement st(db_, "INSERT INTO events (session_id, time_ns, kind, text) VALUES (?,?,?,?)");
  sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(session_id));
  sqlite3_bind_int64(st.get(), 2, e.time_ns);
  sqlite3_bind_text(st.get(), 3, e.kind.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_text(st.get(), 4, e.text.c_str(), -1, SQLITE_TRANSIENT);
  st.step();
}

void SqliteStore::appendReach(uint64_t session_id, const Reach& r) {
  Statement st(db_,
               "INSERT INTO explorations (session_id, phase, direction, angle_deg, force_n) "
               "VALUES (?,?,?,?,?)");
  sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(session_id));
  sqlite3_bind_text(st.get(), 2, r.phase.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_text(st.get(), 3, r.direction.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_double(st.get(), 4, r.angle_deg);
  sqlite3_bind_double(st.get(), 5, r.force_n);
  st.step();
}

std::vector<SessionStore::Reach> SqliteStore::reaches(uint64_t session_id) {
  Statement st(db_,
               "SELECT phase, direction, angle_deg, force_n FROM explorations "
               "WHERE session_id = ? ORDER BY rowid");
  sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(session_id));
  std::vector<Reach> out;
  while (st.step()) {
    out.push_back({st.text(0), st.text(1), sqlite3_column_double(st.get(), 2),
                   sqlite3_column_double(st.get(), 3)});
  }
  return out;
}

void SqliteStore::closeSession(uint64_t session_id, int64_t ended_ns, uint64_t samples_expected,
                               const std::string& state) {
  Statement st(db_,
               "UPDATE sessions SET ended_ns = ?, samples_expected = ?, state = ? WHERE id = ?");
  sqlite3_bind_int64(st.get(), 1, ended_ns);
  sqlite3_bind_int64(st.get(), 2, static_cast<sqlite3_int64>(samples_expected));
  sqlite3_bind_text(st.get(), 3, state.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_int64(st.get(), 4, static_cast<sqlite3_int64>(session_id));
  st.step();
}

namespace {
/// Read-only files of schemas 1 and 2 have no owner column: they read as ''.
std::string sessionSelect(bool has_owner) {
  return std::string(
             "SELECT s.id, s.user, s.case_name, s.mode, s.state, s.started_ns, s.ended_ns, "
             "s.samples_expected, (SELECT count(*) FROM samples WHERE session_id = s.id), "
             "(SELECT count(*) FROM samples WHERE session_id = s.id AND valid = 0), ") +
         (has_owner ? "s.owner" : "''") +
         ", (SELECT count(*) FROM samples WHERE session_id = s.id AND seq < s.samples_expected)"
         " FROM sessions s ";
}

SessionInfo readSession(const Statement& st) {
  SessionInfo i;
  i.id = static_cast<uint64_t>(sqlite3_column_int64(st.get(), 0));
  i.user = st.text(1);
  i.case_name = st.text(2);
  i.mode = st.text(3);
  i.state = st.text(4);
  i.started_ns = sqlite3_column_int64(st.get(), 5);
  i.ended_ns = sqlite3_column_int64(st.get(), 6);
  i.samples_expected = static_cast<uint64_t>(sqlite3_column_int64(st.get(), 7));
  i.samples = static_cast<uint64_t>(sqlite3_column_int64(st.get(), 8));
  i.rejected = static_cast<uint64_t>(sqlite3_column_int64(st.get(), 9));
  i.owner = st.text(10);
  i.samples_below_expected = static_cast<uint64_t>(sqlite3_column_int64(st.get(), 11));
  return i;
}
}  // namespace

std::vector<SessionInfo> SqliteStore::listSessions() {
  Statement st(db_, (sessionSelect(hasOwnerColumn()) + "ORDER BY s.id").c_str());
  std::vector<SessionInfo> out;
  while (st.step()) out.push_back(readSession(st));
  return out;
}

std::optional<SessionInfo> SqliteStore::session(uint64_t session_id) {
  Statement st(db_, (sessionSelect(hasOwnerColumn()) + "WHERE s.id = ?").c_str());
  sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(session_id));
  if (!st.step()) return std::nullopt;
  return readSession(st);
}

void SqliteStore::forEachSample(uint64_t session_id,
                                const std::function<void(const Sample&, bool)>& fn) {
  if (queryInt(db_, "PRAGMA user_version") == 0) {
    // Schema 1, open read-only (a writer migrates it on opening).
    Statement st(db_,
                 "SELECT seq, valid, format, data FROM samples WHERE session_id = ? ORDER BY seq");
    sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(session_id));
    while (st.step()) {
      const int format = sqlite3_column_int(st.get(), 2);
      const int bytes = sqlite3_column_bytes(st.get(), 3);
      Sample s{};
      if (!decodeBlob(format, sqlite3_column_blob(st.get(), 3), bytes, s)) {
        throw StoreError("sample " + std::to_string(sqlite3_column_int64(st.get(), 0)) +
                         " of session " + std::to_string(session_id) + " in '" + path_ +
                         "' has blob format " + std::to_string(format) + " (" +
                         std::to_string(bytes) + " bytes); known are 1 and 2");
      }
      s.session_id = session_id;
      s.seq = static_cast<uint64_t>(sqlite3_column_int64(st.get(), 0));
      fn(s, sqlite3_column_int(st.get(), 1) != 0);
    }
    return;
  }
  Statement st(db_, selectSamplesSql(false, web_columns_).c_str());
  sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(session_id));
  Sample s{};
  while (st.step()) {
    const bool valid = readSample(st.get(), session_id, s);
    fn(s, valid);
  }
}

void SqliteStore::forEachSampleIn(uint64_t session_id, uint64_t first_seq, uint64_t last_seq,
                                  const std::function<void(const Sample&, bool)>& fn) {
  if (queryInt(db_, "PRAGMA user_version") == 0) {  // schema 1: its blobs, filtered
    forEachSample(session_id, [&](const Sample& s, bool valid) {
      if (s.seq >= first_seq && s.seq <= last_seq) fn(s, valid);
    });
    return;
  }
  // Sequence numbers are stored as SQLite's signed integers; the window is clamped to them.
  constexpr uint64_t kMax = static_cast<uint64_t>(std::numeric_limits<sqlite3_int64>::max());
  Statement st(db_, selectSamplesSql(true, web_columns_).c_str());
  sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(session_id));
  sqlite3_bind_int64(st.get(), 2, static_cast<sqlite3_int64>(std::min(first_seq, kMax)));
  sqlite3_bind_int64(st.get(), 3, static_cast<sqlite3_int64>(std::min(last_seq, kMax)));
  Sample s{};
  while (st.step()) {
    const bool valid = readSample(st.get(), session_id, s);
    fn(s, valid);
  }
}

uint64_t SqliteStore::countSamples(uint64_t session_id, uint64_t first_seq, uint64_t last_seq) {
  if (queryInt(db_, "PRAGMA user_version") == 0) {  // schema 1: its blobs, one by one
    uint64_t n = 0;
    forEachSampleIn(session_id, first_seq, last_seq, [&](const Sample&, bool) { ++n; });
    return n;
  }
  constexpr uint64_t kMax = static_cast<uint64_t>(std::numeric_limits<sqlite3_int64>::max());
  Statement st(db_, "SELECT count(*) FROM samples WHERE session_id = ? AND seq >= ? AND seq <= ?");
  sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(session_id));
  sqlite3_bind_int64(st.get(), 2, static_cast<sqlite3_int64>(std::min(first_seq, kMax)));
  sqlite3_bind_int64(st.get(), 3, static_cast<sqlite3_int64>(std::min(last_seq, kMax)));
  return st.step() ? static_cast<uint64_t>(sqlite3_column_int64(st.get(), 0)) : 0;
}

std::optional<uint64_t> SqliteStore::nextStoredSeq(uint64_t session_id, uint64_t first_seq) {
  constexpr uint64_t kMax = static_cast<uint64_t>(std::numeric_limits<sqlite3_int64>::max());
  if (first_seq > kMax) return std::nullopt;
  if (queryInt(db_, "PRAGMA user_version") == 0) {  // schema 1: its blobs, one by one
    std::optional<uint64_t> out;
    forEachSampleIn(session_id, first_seq, kMax, [&](const Sample& s, bool) {
      if (!out || s.seq < *out) out = s.seq;
    });
    return out;
  }
  Statement st(db_, "SELECT min(seq) FROM samples WHERE session_id = ? AND seq >= ?");
  sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(session_id));
  sqlite3_bind_int64(st.get(), 2, static_cast<sqlite3_int64>(first_seq));
  if (!st.step() || sqlite3_column_type(st.get(), 0) == SQLITE_NULL) return std::nullopt;
  return static_cast<uint64_t>(sqlite3_column_int64(st.get(), 0));
}

std::optional<SessionStore::Extent> SqliteStore::extent(uint64_t session_id) {
  std::optional<Extent> out;
  if (queryInt(db_, "PRAGMA user_version") == 0) {  // schema 1: its blobs, one by one
    forEachSample(session_id, [&](const Sample& s, bool) {
      if (!out) out = Extent{s.seq, s.seq, s.source_time_ns, s.source_time_ns};
      out->last_seq = s.seq;
      out->last_time_ns = s.source_time_ns;
    });
    return out;
  }
  // The first and the last row by the (session_id, seq) key: two index look-ups.
  for (const char* order : {"ASC", "DESC"}) {
    Statement st(db_, std::string("SELECT seq, t_ns FROM samples WHERE session_id = ? ORDER BY "
                                  "seq ") +
                          order + " LIMIT 1");
    sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(session_id));
    if (!st.step()) return std::nullopt;
    const auto seq = static_cast<uint64_t>(sqlite3_column_int64(st.get(), 0));
    const int64_t t = sqlite3_column_int64(st.get(), 1);
    if (!out) {
      out = Extent{seq, seq, t, t};
    } else {
      out->last_seq = seq;
      out->last_time_ns = t;
    }
  }
  return out;
}

uint64_t SqliteStore::createLesson(const LessonInfo& l) {
  Statement st(db_,
               "INSERT INTO lessons (name, demo_session, case_name, technique, schedule, guided, "
               "attempts, trial_s, assessment, targets, created_ns, takeover) "
               "VALUES (?,?,?,?,?,?,?,?,?,?,?,?)");
  sqlite3_bind_text(st.get(), 1, l.name.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_int64(st.get(), 2, static_cast<sqlite3_int64>(l.demo_session));
  sqlite3_bind_text(st.get(), 3, l.case_name.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_text(st.get(), 4, l.technique.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_text(st.get(), 5, l.schedule.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_int(st.get(), 6, l.guided);
  sqlite3_bind_int(st.get(), 7, l.attempts);
  sqlite3_bind_double(st.get(), 8, l.trial_s);
  sqlite3_bind_int(st.get(), 9, l.assessment ? 1 : 0);
  sqlite3_bind_text(st.get(), 10, l.targets.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_int64(st.get(), 11, l.created_ns);
  sqlite3_bind_int(st.get(), 12, l.takeover ? 1 : 0);
  st.step();
  return static_cast<uint64_t>(sqlite3_last_insert_rowid(db_));
}

namespace {
/// `takeover`: the file's lessons have the column (a read-only file of schema 4 has not).
std::string lessonSelect(bool takeover) {
  return std::string(
             "SELECT id, name, demo_session, case_name, technique, schedule, guided, attempts, "
             "trial_s, assessment, targets, created_ns, ") +
         (takeover ? "takeover" : "0") + " FROM lessons ";
}

LessonInfo readLesson(const Statement& st) {
  LessonInfo l;
  l.id = static_cast<uint64_t>(sqlite3_column_int64(st.get(), 0));
  l.name = st.text(1);
  l.demo_session = static_cast<uint64_t>(sqlite3_column_int64(st.get(), 2));
  l.case_name = st.text(3);
  l.technique = st.text(4);
  l.schedule = st.text(5);
  l.guided = sqlite3_column_int(st.get(), 6);
  l.attempts = sqlite3_column_int(st.get(), 7);
  l.trial_s = sqlite3_column_double(st.get(), 8);
  l.assessment = sqlite3_column_int(st.get(), 9) != 0;
  l.targets = st.text(10);
  l.created_ns = sqlite3_column_int64(st.get(), 11);
  l.takeover = sqlite3_column_int(st.get(), 12) != 0;
  return l;
}
}  // namespace

std::vector<LessonInfo> SqliteStore::listLessons() {
  std::vector<LessonInfo> out;
  if (!hasTable("lessons")) return out;  // a read-only file of an older schema
  Statement st(db_, (lessonSelect(hasTakeoverColumn()) + "ORDER BY id").c_str());
  while (st.step()) out.push_back(readLesson(st));
  return out;
}

std::optional<LessonInfo> SqliteStore::lesson(uint64_t lesson_id) {
  if (!hasTable("lessons")) return std::nullopt;
  Statement st(db_, (lessonSelect(hasTakeoverColumn()) + "WHERE id = ?").c_str());
  sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(lesson_id));
  if (!st.step()) return std::nullopt;
  return readLesson(st);
}

void SqliteStore::setSessionLesson(uint64_t session_id, uint64_t lesson_id) {
  Statement st(db_, "INSERT OR REPLACE INTO lesson_runs (session_id, lesson_id) VALUES (?,?)");
  sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(session_id));
  sqlite3_bind_int64(st.get(), 2, static_cast<sqlite3_int64>(lesson_id));
  st.step();
}

uint64_t SqliteStore::sessionLesson(uint64_t session_id) {
  if (!hasTable("lesson_runs")) return 0;
  Statement st(db_, "SELECT lesson_id FROM lesson_runs WHERE session_id = ?");
  sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(session_id));
  return st.step() ? static_cast<uint64_t>(sqlite3_column_int64(st.get(), 0)) : 0;
}

void SqliteStore::appendTrial(const TrialRecord& t) {
  Statement st(db_,
               "INSERT OR REPLACE INTO trials (session_id, idx, phase, authority, first_seq, "
               "last_seq, overall, figures) VALUES (?,?,?,?,?,?,?,?)");
  sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(t.session_id));
  sqlite3_bind_int(st.get(), 2, t.index);
  sqlite3_bind_text(st.get(), 3, t.phase.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_double(st.get(), 4, t.authority);
  sqlite3_bind_int64(st.get(), 5, static_cast<sqlite3_int64>(t.first_seq));
  sqlite3_bind_int64(st.get(), 6, static_cast<sqlite3_int64>(t.last_seq));
  sqlite3_bind_double(st.get(), 7, t.overall);
  sqlite3_bind_text(st.get(), 8, t.figures.c_str(), -1, SQLITE_TRANSIENT);
  st.step();
}

std::vector<TrialRecord> SqliteStore::trials(uint64_t session_id) {
  std::vector<TrialRecord> out;
  if (!hasTable("trials")) return out;
  Statement st(db_,
               "SELECT idx, phase, authority, first_seq, last_seq, overall, figures FROM trials "
               "WHERE session_id = ? ORDER BY idx");
  sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(session_id));
  while (st.step()) {
    TrialRecord t;
    t.session_id = session_id;
    t.index = sqlite3_column_int(st.get(), 0);
    t.phase = st.text(1);
    t.authority = sqlite3_column_double(st.get(), 2);
    t.first_seq = static_cast<uint64_t>(sqlite3_column_int64(st.get(), 3));
    t.last_seq = static_cast<uint64_t>(sqlite3_column_int64(st.get(), 4));
    t.overall = sqlite3_column_double(st.get(), 5);
    t.figures = st.text(6);
    out.push_back(std::move(t));
  }
  return out;
}

void SqliteStore::appendFile(uint64_t session_id, const SessionFile& f) {
  Statement st(db_,
               "INSERT OR REPLACE INTO session_files (session_id, name, content) VALUES (?,?,?)");
  sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(session_id));
  sqlite3_bind_text(st.get(), 2, f.name.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_blob(st.get(), 3, f.content.data(), static_cast<int>(f.content.size()),
                    SQLITE_TRANSIENT);
  st.step();
}

std::vector<SessionFile> SqliteStore::files(uint64_t session_id) {
  std::vector<SessionFile> out;
  // Records written before files were kept have no such table.
  Statement check(db_, "SELECT count(*) FROM sqlite_master WHERE name = 'session_files'");
  if (!check.step() || sqlite3_column_int(check.get(), 0) == 0) return out;
  Statement st(db_, "SELECT name, content FROM session_files WHERE session_id = ? ORDER BY name");
  sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(session_id));
  while (st.step()) {
    const auto* b = static_cast<const char*>(sqlite3_column_blob(st.get(), 1));
    out.push_back({st.text(0), std::string(b ? b : "", static_cast<std::size_t>(
                                                           sqlite3_column_bytes(st.get(), 1)))});
  }
  return out;
}

std::vector<EventRecord> SqliteStore::events(uint64_t session_id) {
  Statement st(db_, "SELECT time_ns, kind, text FROM events WHERE session_id = ? ORDER BY rowid");
  sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(session_id));
  std::vector<EventRecord> out;
  while (st.step()) out.push_back({sqlite3_column_int64(st.get(), 0), st.text(1), st.text(2)});
  return out;
}

// ---- Pool (docs/pool.md) --------------------------------------------------------------------
// The record's clock for an SQLite file is the host's wall clock: the servers sharing one file
// run on one machine.

template <class F>
auto SqliteStore::transaction(F&& fn) {
  exec("BEGIN IMMEDIATE");
  try {
    if constexpr (std::is_void_v<decltype(fn())>) {
      fn();
      exec("COMMIT");
    } else {
      auto r = fn();
      exec("COMMIT");
      return r;
    }
  } catch (...) {
    sqlite3_exec(db_, "ROLLBACK", nullptr, nullptr, nullptr);
    throw;
  }
}

namespace {
void bindText(sqlite3_stmt* st, int i, const std::string& v) {
  sqlite3_bind_text(st, i, v.c_str(), -1, SQLITE_TRANSIENT);
}
void bindInt(sqlite3_stmt* st, int i, int64_t v) { sqlite3_bind_int64(st, i, v); }

/// Orphans: sessions still open whose owner's lease ran out, or which have had no owner for
/// 5 s (a session is created a moment before its creator claims it).
constexpr const char* kOrphansSql =
    "SELECT s.id FROM sessions s LEFT JOIN session_owners o ON o.session_id = s.id "
    "LEFT JOIN pool_servers p ON p.server = o.server "
    "WHERE s.state IN ('active', 'suspended') AND "
    "((o.server IS NULL AND s.started_ns < ?1 - 5000000000) OR "
    "(o.server IS NOT NULL AND (p.lease_until_ns IS NULL OR p.lease_until_ns < ?1))) "
    "ORDER BY s.id";
/// Members whose lease runs, least loaded first.
constexpr const char* kMembersSql =
    "SELECT p.server, p.lease_until_ns, "
    "(SELECT count(*) FROM session_owners o JOIN sessions s ON s.id = o.session_id "
    " WHERE o.server = p.server AND s.state IN ('active', 'suspended')) + "
    "(SELECT count(*) FROM pool_opens q WHERE q.server = p.server AND q.session_id = 0 "
    " AND q.at_ns > ?1 - 60000000000) AS load "
    "FROM pool_servers p WHERE p.lease_until_ns >= ?1 ORDER BY load, p.server";
}  // namespace

std::vector<uint64_t> SqliteStore::poolHeartbeat(const std::string& server, uint64_t sessions,
                                                 int64_t lease_ns) {
  (void)sessions;  // the load is counted from the owners, not taken on a server's word
  return transaction([&] {
    const int64_t now = wallNs();
    {
      Statement st(db_,
                   "INSERT INTO pool_servers (server, lease_until_ns, started_ns) VALUES (?,?,?) "
                   "ON CONFLICT(server) DO UPDATE SET lease_until_ns = excluded.lease_until_ns");
      bindText(st.get(), 1, server);
      bindInt(st.get(), 2, now + lease_ns);
      bindInt(st.get(), 3, now);
      st.step();
    }
    Statement st(db_,
                 "SELECT o.session_id FROM session_owners o JOIN sessions s ON s.id = "
                 "o.session_id WHERE o.server = ? AND s.state IN ('active', 'suspended') "
                 "ORDER BY o.session_id");
    bindText(st.get(), 1, server);
    std::vector<uint64_t> out;
    while (st.step()) out.push_back(static_cast<uint64_t>(sqlite3_column_int64(st.get(), 0)));
    return out;
  });
}

void SqliteStore::poolLeave(const std::string& server) {
  Statement st(db_, "DELETE FROM pool_servers WHERE server = ?");
  bindText(st.get(), 1, server);
  st.step();
}

std::vector<PoolMember> SqliteStore::poolMembers() {
  std::vector<PoolMember> out;
  if (!hasTable("pool_servers")) return out;  // a read-only file of an older schema
  Statement st(db_, kMembersSql);
  bindInt(st.get(), 1, wallNs());
  while (st.step()) {
    out.push_back({st.text(0), static_cast<uint64_t>(sqlite3_column_int64(st.get(), 2)),
                   sqlite3_column_int64(st.get(), 1)});
  }
  return out;
}

std::string SqliteStore::poolAssign(const std::string& open_key) {
  return transaction([&] {
    const auto members = poolMembers();
    {
      // Assigned before: that answer, unless its server's lease ran out before it made the
      // session (then the OPEN, asked again, goes to a live one).
      Statement st(db_, "SELECT server, session_id FROM pool_opens WHERE open_key = ?");
      bindText(st.get(), 1, open_key);
      if (st.step()) {
        const std::string had = st.text(0);
        const bool alive = std::any_of(members.begin(), members.end(),
                                       [&](const PoolMember& m) { return m.server == had; });
        if (alive || sqlite3_column_int64(st.get(), 1) != 0) return had;
      }
    }
    if (members.empty()) {
      throw StoreError("no server of the pool on " + path_ + " holds a lease");
    }
    const int64_t now = wallNs();
    Statement st(
        db_,
        "INSERT INTO pool_opens (open_key, server, at_ns) VALUES (?,?,?) ON "
        "CONFLICT(open_key) DO UPDATE SET server = excluded.server, at_ns = excluded.at_ns");
    bindText(st.get(), 1, open_key);
    bindText(st.get(), 2, members.front().server);
    bindInt(st.get(), 3, now);
    st.step();
    Statement prune(db_, "DELETE FROM pool_opens WHERE at_ns < ?");  // OPENs of an hour ago
    bindInt(prune.get(), 1, now - int64_t{3600} * 1'000'000'000);
    prune.step();
    return members.front().server;
  });
}

PoolClaim SqliteStore::poolClaim(uint64_t session_id, const std::string& server,
                                 const std::string& open_key) {
  return transaction([&] {
    PoolClaim c;
    c.now_ns = wallNs();
    bool owned = false;
    {
      Statement st(db_,
                   "SELECT o.server, p.lease_until_ns FROM session_owners o LEFT JOIN "
                   "pool_servers p ON p.server = o.server WHERE o.session_id = ?");
      bindInt(st.get(), 1, static_cast<int64_t>(session_id));
      if (st.step()) {
        owned = true;
        c.previous = st.text(0);
        c.previous_lease_until_ns = sqlite3_column_int64(st.get(), 1);
      }
    }
    if (owned && c.previous != server && c.previous_lease_until_ns >= c.now_ns) return c;
    if (!owned || c.previous != server) {
      Statement st(db_,
                   "INSERT INTO session_owners (session_id, server, since_ns) VALUES (?,?,?) "
                   "ON CONFLICT(session_id) DO UPDATE SET server = excluded.server, "
                   "since_ns = excluded.since_ns");
      bindInt(st.get(), 1, static_cast<int64_t>(session_id));
      bindText(st.get(), 2, server);
      bindInt(st.get(), 3, c.now_ns);
      st.step();
    }
    if (!open_key.empty()) {
      Statement st(db_, "UPDATE pool_opens SET session_id = ? WHERE open_key = ?");
      bindInt(st.get(), 1, static_cast<int64_t>(session_id));
      bindText(st.get(), 2, open_key);
      st.step();
    }
    c.won = true;
    return c;
  });
}

std::vector<uint64_t> SqliteStore::poolOrphans() {
  Statement st(db_, kOrphansSql);
  bindInt(st.get(), 1, wallNs());
  std::vector<uint64_t> out;
  while (st.step()) out.push_back(static_cast<uint64_t>(sqlite3_column_int64(st.get(), 0)));
  return out;
}

std::string SqliteStore::poolOwner(uint64_t session_id) {
  if (!hasTable("session_owners")) return {};
  Statement st(db_, "SELECT server FROM session_owners WHERE session_id = ?");
  bindInt(st.get(), 1, static_cast<int64_t>(session_id));
  return st.step() ? st.text(0) : std::string();
}

void SqliteStore::putCheckpoint(uint64_t session_id, const Checkpoint& c) {
  Statement st(db_,
               "INSERT INTO checkpoints (session_id, seq, time_ns, data) VALUES (?,?,?,?) "
               "ON CONFLICT(session_id) DO UPDATE SET seq = excluded.seq, "
               "time_ns = excluded.time_ns, data = excluded.data");
  bindInt(st.get(), 1, static_cast<int64_t>(session_id));
  bindInt(st.get(), 2, static_cast<int64_t>(c.seq));
  bindInt(st.get(), 3, c.time_ns);
  sqlite3_bind_blob(st.get(), 4, c.data.data(), static_cast<int>(c.data.size()), SQLITE_TRANSIENT);
  st.step();
}

std::optional<Checkpoint> SqliteStore::checkpoint(uint64_t session_id) {
  if (!hasTable("checkpoints")) return std::nullopt;
  Statement st(db_, "SELECT seq, time_ns, data FROM checkpoints WHERE session_id = ?");
  bindInt(st.get(), 1, static_cast<int64_t>(session_id));
  if (!st.step()) return std::nullopt;
  Checkpoint c;
  c.seq = static_cast<uint64_t>(sqlite3_column_int64(st.get(), 0));
  c.time_ns = sqlite3_column_int64(st.get(), 1);
  const auto* b = static_cast<const char*>(sqlite3_column_blob(st.get(), 2));
  c.data.assign(b ? b : "", static_cast<std::size_t>(sqlite3_column_bytes(st.get(), 2)));
  return c;
}

}  // namespace telehand::server::store
