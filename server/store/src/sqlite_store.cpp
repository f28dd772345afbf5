#include "telehand/server/store/sqlite_store.h"

#include <cmath>
#include <cstddef>
#include <cstring>
#include <filesystem>
#include <sstream>

#include "telehand/core/error.h"

namespace telehand::server::store {

namespace {

// The sample is kept whole as its fixed-size wire struct (x86-64 layout) plus the columns a
// query needs; kSampleFormat changes whenever idl/telehand.idl's DeviceState does.
// Format 2 appended the passivity fields; format 1 samples (shorter) are read with them zero.
constexpr int kSampleFormat = 2;
constexpr int kSampleFormat1Bytes = static_cast<int>(offsetof(Sample, passivity_energy_j));

constexpr const char* kSchema = R"sql(
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS sessions (
  id INTEGER PRIMARY KEY,
  user TEXT NOT NULL, case_name TEXT NOT NULL, mode TEXT NOT NULL,
  state TEXT NOT NULL, started_ns INTEGER NOT NULL, ended_ns INTEGER NOT NULL DEFAULT 0,
  samples_expected INTEGER NOT NULL DEFAULT 0);
CREATE TABLE IF NOT EXISTS samples (
  session_id INTEGER NOT NULL REFERENCES sessions(id),
  seq INTEGER NOT NULL,
  t_ns INTEGER NOT NULL,
  valid INTEGER NOT NULL,
  flags INTEGER NOT NULL,
  model_version INTEGER NOT NULL,
  alpha_rad REAL, beta_rad REAL, gamma_rad REAL,
  format INTEGER NOT NULL,
  data BLOB NOT NULL,
  PRIMARY KEY (session_id, seq)) WITHOUT ROWID;
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

class Statement {
 public:
  Statement(sqlite3* db, const char* sql) : db_(db) {
    if (sqlite3_prepare_v2(db, sql, -1, &s_, nullptr) != SQLITE_OK) {
      throw StoreError(std::string("SQLite: cannot prepare '") + sql + "': " + sqlite3_errmsg(db));
    }
  }
  ~Statement() { sqlite3_finalize(s_); }
  Statement(const Statement&) = delete;
  Statement& operator=(const Statement&) = delete;
  sqlite3_stmt* get() const { return s_; }
  bool step() {
    const int rc = sqlite3_step(s_);
    if (rc == SQLITE_ROW) return true;
    if (rc == SQLITE_DONE) return false;
    throw StoreError(std::string("SQLite: ") + sqlite3_errmsg(db_));
  }
  std::string text(int col) const {
    const auto* t = sqlite3_column_text(s_, col);
    return t ? reinterpret_cast<const char*>(t) : "";
  }

 private:
  sqlite3* db_;
  sqlite3_stmt* s_ = nullptr;
};

double nullIfNan(double v) { return v; }

}  // namespace

SqliteStore::SqliteStore(const std::string& path, Mode mode) : path_(path) {
  int flags = SQLITE_OPEN_FULLMUTEX;
  if (mode == Mode::kReadWrite) {
    const auto dir = std::filesystem::path(path).parent_path();
    std::error_code ec;
    if (!dir.empty()) std::filesystem::create_directories(dir, ec);
    if (ec) throw StoreError("cannot create the record directory '" + dir.string() + "': " + ec.message());
    flags |= SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE;
  } else {
    if (!std::filesystem::exists(path)) throw StoreError("record database '" + path + "' does not exist");
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
    if (mode == Mode::kReadWrite) {
      exec("PRAGMA journal_mode=WAL;");
      exec("PRAGMA synchronous=NORMAL;");
      exec(kSchema);
      exec(("INSERT OR IGNORE INTO meta VALUES ('sample_format', '" + std::to_string(kSampleFormat) +
            "');").c_str());
      insert_sample_ = prepare(
          "INSERT OR IGNORE INTO samples (session_id, seq, t_ns, valid, flags, model_version, "
          "alpha_rad, beta_rad, gamma_rad, format, data) VALUES (?,?,?,?,?,?,?,?,?,?,?)");
    } else {
      bool has_samples = false;
      try {  // a file that is not SQLite at all fails here, with a message lacking the path
        Statement check(db_, "SELECT count(*) FROM sqlite_master WHERE name = 'samples'");
        has_samples = check.step() && sqlite3_column_int(check.get(), 0) == 1;
      } catch (const StoreError&) {
        throw StoreError("cannot read record database '" + path + "': " + sqlite3_errmsg(db_));
      }
      if (!has_samples) {
        throw StoreError("'" + path + "' is not a telehand record database (no samples table)");
      }
    }
  } catch (...) {
    sqlite3_finalize(insert_sample_);
    sqlite3_close(db_);
    throw;
  }
}

SqliteStore::~SqliteStore() {
  sqlite3_finalize(insert_sample_);
  sqlite3_close(db_);
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
    throw StoreError(std::string("SQLite: cannot prepare: ") + sqlite3_errmsg(db_));
  }
  return s;
}

uint64_t SqliteStore::createSession(const SessionInfo& info) {
  Statement st(db_,
               "INSERT INTO sessions (user, case_name, mode, state, started_ns) VALUES (?,?,?,?,?)");
  sqlite3_bind_text(st.get(), 1, info.user.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_text(st.get(), 2, info.case_name.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_text(st.get(), 3, info.mode.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_text(st.get(), 4, "active", -1, SQLITE_STATIC);
  sqlite3_bind_int64(st.get(), 5, info.started_ns);
  st.step();
  return static_cast<uint64_t>(sqlite3_last_insert_rowid(db_));
}

uint64_t SqliteStore::appendSamples(uint64_t session_id,
                                    std::span<const Sample> samples,
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
      sqlite3_bind_int64(st, 1, static_cast<sqlite3_int64>(session_id));
      sqlite3_bind_int64(st, 2, static_cast<sqlite3_int64>(s.seq));
      sqlite3_bind_int64(st, 3, s.source_time_ns);
      sqlite3_bind_int(st, 4, ok ? 1 : 0);
      sqlite3_bind_int64(st, 5, s.flags);
      sqlite3_bind_int64(st, 6, s.model_version);
      for (int a = 0; a < 3; ++a) {
        if (std::isfinite(s.mcp_angles_rad[a])) {
          sqlite3_bind_double(st, 7 + a, nullIfNan(s.mcp_angles_rad[a]));
        } else {
          sqlite3_bind_null(st, 7 + a);
        }
      }
      sqlite3_bind_int(st, 10, kSampleFormat);
      sqlite3_bind_blob(st, 11, &s, sizeof(s), SQLITE_STATIC);
      if (sqlite3_step(st) != SQLITE_DONE) {
        throw StoreError("SQLite: cannot store sample " + std::to_string(s.seq) + " of session " +
                         std::to_string(session_id) + ": " + sqlite3_errmsg(db_));
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
  Statement st(db_, "INSERT INTO explorations (session_id, phase, direction, angle_deg, force_n) "
                    "VALUES (?,?,?,?,?)");
  sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(session_id));
  sqlite3_bind_text(st.get(), 2, r.phase.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_text(st.get(), 3, r.direction.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_double(st.get(), 4, r.angle_deg);
  sqlite3_bind_double(st.get(), 5, r.force_n);
  st.step();
}

std::vector<SessionStore::Reach> SqliteStore::reaches(uint64_t session_id) {
  Statement st(db_, "SELECT phase, direction, angle_deg, force_n FROM explorations "
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
  Statement st(db_, "UPDATE sessions SET ended_ns = ?, samples_expected = ?, state = ? WHERE id = ?");
  sqlite3_bind_int64(st.get(), 1, ended_ns);
  sqlite3_bind_int64(st.get(), 2, static_cast<sqlite3_int64>(samples_expected));
  sqlite3_bind_text(st.get(), 3, state.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_int64(st.get(), 4, static_cast<sqlite3_int64>(session_id));
  st.step();
}

namespace {
constexpr const char* kSessionSelect =
    "SELECT s.id, s.user, s.case_name, s.mode, s.state, s.started_ns, s.ended_ns, "
    "s.samples_expected, (SELECT count(*) FROM samples WHERE session_id = s.id), "
    "(SELECT count(*) FROM samples WHERE session_id = s.id AND valid = 0) FROM sessions s ";

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
  return i;
}
}  // namespace

std::vector<SessionInfo> SqliteStore::listSessions() {
  Statement st(db_, (std::string(kSessionSelect) + "ORDER BY s.id").c_str());
  std::vector<SessionInfo> out;
  while (st.step()) out.push_back(readSession(st));
  return out;
}

std::optional<SessionInfo> SqliteStore::session(uint64_t session_id) {
  Statement st(db_, (std::string(kSessionSelect) + "WHERE s.id = ?").c_str());
  sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(session_id));
  if (!st.step()) return std::nullopt;
  return readSession(st);
}

void SqliteStore::forEachSample(
    uint64_t session_id, const std::function<void(const Sample&, bool)>& fn) {
  Statement st(db_,
               "SELECT seq, valid, format, data FROM samples WHERE session_id = ? ORDER BY seq");
  sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(session_id));
  while (st.step()) {
    const int format = sqlite3_column_int(st.get(), 2);
    const int bytes = sqlite3_column_bytes(st.get(), 3);
    const bool current = format == kSampleFormat && bytes == static_cast<int>(sizeof(Sample));
    const bool older = format == 1 && bytes == kSampleFormat1Bytes;
    if (!current && !older) {
      throw StoreError("sample " + std::to_string(sqlite3_column_int64(st.get(), 0)) +
                       " of session " + std::to_string(session_id) + " in '" + path_ +
                       "' has format " + std::to_string(format) + " (" + std::to_string(bytes) +
                       " bytes); this build reads format " + std::to_string(kSampleFormat));
    }
    Sample s{};
    std::memcpy(&s, sqlite3_column_blob(st.get(), 3), static_cast<std::size_t>(bytes));
    fn(s, sqlite3_column_int(st.get(), 1) != 0);
  }
}

void SqliteStore::appendFile(uint64_t session_id, const SessionFile& f) {
  Statement st(db_, "INSERT OR REPLACE INTO session_files (session_id, name, content) VALUES (?,?,?)");
  sqlite3_bind_int64(st.get(), 1, static_cast<sqlite3_int64>(session_id));
  sqlite3_bind_text(st.get(), 2, f.name.c_str(), -1, SQLITE_TRANSIENT);
  sqlite3_bind_blob(st.get(), 3, f.content.data(), static_cast<int>(f.content.size()), SQLITE_TRANSIENT);
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
    out.push_back({st.text(0), std::string(b ? b : "", static_cast<std::size_t>(sqlite3_column_bytes(st.get(), 1)))});
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

namespace {
struct Column {
  std::string name;
  std::function<void(std::ostream&, const Sample&)> put;
};

const std::vector<Column>& columns() {
  static const std::vector<Column> cols = [] {
    std::vector<Column> c;
    c.push_back({"seq", [](std::ostream& o, const auto& s) { o << s.seq; }});
    c.push_back({"t_ns", [](std::ostream& o, const auto& s) { o << s.source_time_ns; }});
    c.push_back({"model_version", [](std::ostream& o, const auto& s) { o << s.model_version; }});
    c.push_back({"flags", [](std::ostream& o, const auto& s) { o << s.flags; }});
    const char* axes[3] = {"alpha", "beta", "gamma"};
    for (int a = 0; a < 3; ++a) {
      c.push_back({std::string(axes[a]) + "_rad",
                   [a](std::ostream& o, const auto& s) { o << s.mcp_angles_rad[a]; }});
    }
    for (int a = 0; a < 3; ++a) {
      c.push_back({"tau_" + std::string(axes[a]) + "_nm",
                   [a](std::ostream& o, const auto& s) { o << s.mcp_torque_nm[a]; }});
    }
    const char* fingers[2] = {"thumb", "index"};
    const char* xyz[3] = {"x", "y", "z"};
    const char* wxyz[4] = {"w", "x", "y", "z"};
    for (int k = 0; k < 2; ++k) {
      const std::string f = fingers[k];
      for (int i = 0; i < 3; ++i) {
        c.push_back({f + "_p" + xyz[i] + "_m",
                     [k, i](std::ostream& o, const auto& s) { o << s.fingers[k].position_m[i]; }});
      }
      for (int i = 0; i < 4; ++i) {
        c.push_back({f + "_q" + wxyz[i],
                     [k, i](std::ostream& o, const auto& s) { o << s.fingers[k].orientation_q[i]; }});
      }
      for (int i = 0; i < 4; ++i) {
        c.push_back({f + "_fsr" + std::to_string(i + 1) + "_n",
                     [k, i](std::ostream& o, const auto& s) { o << s.fingers[k].fsr_n[i]; }});
      }
      c.push_back({f + "_tangential_n",
                   [k](std::ostream& o, const auto& s) { o << s.fingers[k].tangential_n; }});
      c.push_back({f + "_normal_n",
                   [k](std::ostream& o, const auto& s) { o << s.fingers[k].normal_n; }});
      for (int i = 0; i < 3; ++i) {
        c.push_back({f + "_cmd" + xyz[i] + "_n",
                     [k, i](std::ostream& o, const auto& s) { o << s.fingers[k].command_n[i]; }});
      }
    }
    c.push_back({"passivity_energy_j", [](std::ostream& o, const auto& s) { o << s.passivity_energy_j; }});
    c.push_back({"passivity_damping_ns_per_m",
                 [](std::ostream& o, const auto& s) { o << s.passivity_damping; }});
    return c;
  }();
  return cols;
}
}  // namespace

const std::vector<std::string>& sampleColumns() {
  static const std::vector<std::string> names = [] {
    std::vector<std::string> n;
    for (const auto& c : columns()) n.push_back(c.name);
    n.push_back("valid");
    return n;
  }();
  return names;
}

std::string sampleCsvRow(const Sample& s, bool valid) {
  std::ostringstream o;
  o.precision(9);
  for (const auto& c : columns()) {
    c.put(o, s);
    o << ',';
  }
  o << (valid ? 1 : 0);
  return o.str();
}

}  // namespace telehand::server::store
