// The SQLite session store as a file: WAL, the schema marker and version in its header,
// migration of older files (schema 1: blobs), refusal of foreign ones, CSV columns. What every
// store does (sessions, samples, duplicates, events, lessons) is test_store_contract.cpp's,
// run on SQLite and PostgreSQL alike.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sqlite3.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "store_samples.h"
#include "telehand/core/error.h"
#include "telehand/server/store/sqlite_store.h"

namespace telehand::server::store {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using namespace store_test;

/// A fresh directory per test, removed afterwards.
class SqliteStoreTest : public ::testing::Test {
 protected:
  void SetUp() override {
    static std::atomic<int> counter{0};
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ =
        fs::temp_directory_path() / ("telehand-store-" + std::string(info->name()) + "-" +
                                     std::to_string(::getpid()) + "-" + std::to_string(counter++));
    fs::remove_all(dir_);
    ASSERT_TRUE(fs::create_directories(dir_));
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
    EXPECT_FALSE(fs::exists(dir_));
  }
  std::string dbPath() const { return (dir_ / "records" / "telehand.db").string(); }

  fs::path dir_;
};

TEST_F(SqliteStoreTest, CreatesTheFileAndItsDirectoryInWalMode) {
  {
    SqliteStore store(dbPath());
    EXPECT_EQ(store.location(), dbPath());
    store.createSession(info("alice"));
  }
  ASSERT_TRUE(fs::exists(dbPath()));
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open_v2(dbPath().c_str(), &db, SQLITE_OPEN_READONLY, nullptr), SQLITE_OK);
  sqlite3_stmt* st = nullptr;
  ASSERT_EQ(sqlite3_prepare_v2(db, "PRAGMA journal_mode", -1, &st, nullptr), SQLITE_OK);
  ASSERT_EQ(sqlite3_step(st), SQLITE_ROW);
  EXPECT_STREQ(reinterpret_cast<const char*>(sqlite3_column_text(st, 0)), "wal");
  sqlite3_finalize(st);
  sqlite3_close(db);
}

TEST_F(SqliteStoreTest, ReleasingMemoryEmptiesThePageCacheAndKeepsTheRecord) {
  // A server with no session left gives back the pages its connection cached meanwhile
  // (SessionManager, docs/security.md "Memory"); what was stored stays readable.
  SqliteStore store(dbPath());
  std::vector<uint64_t> ids;
  for (int k = 0; k < 8; ++k) {
    ids.push_back(store.createSession(info("s" + std::to_string(k))));
    const auto batch = samples(ids.back(), 1, 2001);
    const std::vector<uint8_t> valid(batch.size(), 1);
    ASSERT_EQ(store.appendSamples(ids.back(), batch, valid), batch.size());
  }
  const std::size_t before = store.cacheBytes();
  EXPECT_GT(before, 64u * 1024u) << "the writes cached pages";
  store.releaseMemory();
  EXPECT_LT(store.cacheBytes(), before / 4);
  for (const uint64_t id : ids) EXPECT_EQ(seqsOf(store, id).size(), 2000u);
}

TEST_F(SqliteStoreTest, ReadOnlyOpenOfAMissingFileNamesThePath) {
  const std::string missing = (dir_ / "nope" / "missing.db").string();
  try {
    SqliteStore store(missing, SqliteStore::Mode::kReadOnly);
    FAIL() << "opened a missing file";
  } catch (const StoreError& e) {
    EXPECT_THAT(e.what(), HasSubstr(missing));
  }
  EXPECT_FALSE(fs::exists(missing)) << "read-only open must not create it";
  EXPECT_FALSE(fs::exists(dir_ / "nope"));
}

TEST_F(SqliteStoreTest, ReadOnlyOpenOfAForeignFileNamesThePath) {
  const std::string text = (dir_ / "notes.db").string();
  std::ofstream(text) << "these are not the records you are looking for\n";
  try {
    SqliteStore store(text, SqliteStore::Mode::kReadOnly);
    FAIL() << "opened a text file as a record database";
  } catch (const StoreError& e) {
    EXPECT_THAT(e.what(), HasSubstr(text));
  }

  const std::string other = (dir_ / "other.db").string();
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(other.c_str(), &db), SQLITE_OK);
  ASSERT_EQ(sqlite3_exec(db, "CREATE TABLE t (x INTEGER);", nullptr, nullptr, nullptr), SQLITE_OK);
  sqlite3_close(db);
  try {
    SqliteStore store(other, SqliteStore::Mode::kReadOnly);
    FAIL() << "opened a database without a samples table";
  } catch (const StoreError& e) {
    EXPECT_THAT(e.what(), HasSubstr(other));
  }
}

TEST_F(SqliteStoreTest, ErrorsAreTelehandErrors) {
  EXPECT_THROW(SqliteStore((dir_ / "missing.db").string(), SqliteStore::Mode::kReadOnly), Error);
}

// A statement the record refuses names the record's file and the statement, for the log of a
// server that keeps several.
TEST_F(SqliteStoreTest, AStatementsErrorNamesTheFileAndTheStatement) {
  { SqliteStore create(dbPath()); }
  SqliteStore reader(dbPath(), SqliteStore::Mode::kReadOnly);
  SessionInfo i;
  i.user = "u";
  i.case_name = "healthy";
  i.mode = "mobilization";
  i.state = "active";
  try {
    reader.createSession(i);
    FAIL() << "a read-only record took a session";
  } catch (const StoreError& e) {
    EXPECT_THAT(e.what(), HasSubstr(dbPath()));
    EXPECT_THAT(e.what(), HasSubstr("INSERT INTO sessions"));
  }
}

// ---- Columns, schema version, migration, refusal --------------------------------------------

/// Raw SQLite access to a record file, as another program would have it.
class RawDb {
 public:
  explicit RawDb(const std::string& path) {
    EXPECT_EQ(sqlite3_open(path.c_str(), &db_), SQLITE_OK) << path;
  }
  ~RawDb() { sqlite3_close(db_); }
  RawDb(const RawDb&) = delete;
  RawDb& operator=(const RawDb&) = delete;
  void exec(const std::string& sql) {
    char* err = nullptr;
    EXPECT_EQ(sqlite3_exec(db_, sql.c_str(), nullptr, nullptr, &err), SQLITE_OK)
        << sql << ": " << (err ? err : "");
    sqlite3_free(err);
  }
  int64_t integer(const std::string& sql) {
    sqlite3_stmt* st = nullptr;
    EXPECT_EQ(sqlite3_prepare_v2(db_, sql.c_str(), -1, &st, nullptr), SQLITE_OK) << sql;
    int64_t v = -1;
    if (sqlite3_step(st) == SQLITE_ROW) v = sqlite3_column_int64(st, 0);
    sqlite3_finalize(st);
    return v;
  }
  std::vector<std::string> strings(const std::string& sql) {
    sqlite3_stmt* st = nullptr;
    EXPECT_EQ(sqlite3_prepare_v2(db_, sql.c_str(), -1, &st, nullptr), SQLITE_OK) << sql;
    std::vector<std::string> out;
    while (sqlite3_step(st) == SQLITE_ROW) {
      out.emplace_back(reinterpret_cast<const char*>(sqlite3_column_text(st, 0)));
    }
    sqlite3_finalize(st);
    return out;
  }
  sqlite3* get() const { return db_; }

 private:
  sqlite3* db_ = nullptr;
};

std::string fileBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

std::vector<std::string> dirListing(const fs::path& dir) {
  std::vector<std::string> out;
  for (const auto& e : fs::directory_iterator(dir)) out.push_back(e.path().filename().string());
  std::sort(out.begin(), out.end());
  return out;
}

TEST_F(SqliteStoreTest, TableHasOneColumnPerCsvFieldAndTheHeaderMarksTheSchema) {
  { SqliteStore store(dbPath()); }
  RawDb raw(dbPath());
  std::vector<std::string> want = {"session_id"};
  for (const auto& c : sampleColumns()) want.push_back(c);
  EXPECT_EQ(raw.strings("SELECT name FROM pragma_table_info('samples') ORDER BY cid"), want);
  EXPECT_EQ(
      raw.strings("SELECT type FROM pragma_table_info('samples') WHERE name = 'thumb_fsr1_n'"),
      std::vector<std::string>{"REAL"});
  EXPECT_EQ(raw.strings("SELECT type FROM pragma_table_info('samples') WHERE name = 'flags'"),
            std::vector<std::string>{"INTEGER"});
  EXPECT_EQ(raw.integer("PRAGMA application_id"), 0x54484E44);
  EXPECT_EQ(raw.integer("PRAGMA user_version"), 7);
}

// ---- Schema 1: one blob per sample, the C struct's bytes (x86-64, little-endian) ----------

/// The schema-1 tables as that version created them.
constexpr const char* kSchema1 = R"sql(
PRAGMA journal_mode=WAL;
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE sessions (
  id INTEGER PRIMARY KEY,
  user TEXT NOT NULL, case_name TEXT NOT NULL, mode TEXT NOT NULL,
  state TEXT NOT NULL, started_ns INTEGER NOT NULL, ended_ns INTEGER NOT NULL DEFAULT 0,
  samples_expected INTEGER NOT NULL DEFAULT 0);
CREATE TABLE samples (
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
CREATE TABLE events (
  session_id INTEGER NOT NULL,
  time_ns INTEGER NOT NULL,
  kind TEXT NOT NULL,
  text TEXT NOT NULL);
CREATE INDEX events_by_session ON events(session_id, time_ns);
CREATE TABLE explorations (
  session_id INTEGER NOT NULL,
  phase TEXT NOT NULL,
  direction TEXT NOT NULL,
  angle_deg REAL NOT NULL,
  force_n REAL NOT NULL);
INSERT INTO meta VALUES ('sample_format', '2');
)sql";

/// A sample's schema-1 blob written field by field: format 2 is 296 bytes, format 1 the
/// first 288 (no passivity fields).
std::vector<unsigned char> blobOf(const Sample& s, int format) {
  std::vector<unsigned char> b(format == 1 ? 288 : 296, 0);
  auto put = [&](std::size_t at, uint64_t v, int bytes) {
    for (int i = 0; i < bytes; ++i)
      b[at + static_cast<std::size_t>(i)] = static_cast<unsigned char>(v >> (8 * i));
  };
  auto f64 = [&](std::size_t at, double v) { put(at, std::bit_cast<uint64_t>(v), 8); };
  auto f32 = [&](std::size_t at, float v) { put(at, std::bit_cast<uint32_t>(v), 4); };
  put(0, s.session_id, 8);
  put(8, s.seq, 8);
  put(16, static_cast<uint64_t>(s.source_time_ns), 8);
  put(24, s.model_version, 4);
  put(28, s.flags, 4);
  for (std::size_t k = 0; k < 2; ++k) {
    const std::size_t f = 32 + 104 * k;
    const auto& finger = s.fingers[k];
    for (std::size_t i = 0; i < 3; ++i) f64(f + 8 * i, finger.position_m[i]);
    for (std::size_t i = 0; i < 4; ++i) f64(f + 24 + 8 * i, finger.orientation_q[i]);
    for (std::size_t i = 0; i < 4; ++i) f32(f + 56 + 4 * i, finger.fsr_n[i]);
    f32(f + 72, finger.tangential_n);
    f32(f + 76, finger.normal_n);
    for (std::size_t i = 0; i < 3; ++i) f64(f + 80 + 8 * i, finger.command_n[i]);
  }
  for (std::size_t i = 0; i < 3; ++i) f64(240 + 8 * i, s.mcp_angles_rad[i]);
  for (std::size_t i = 0; i < 3; ++i) f64(264 + 8 * i, s.mcp_torque_nm[i]);
  if (format != 1) {
    f32(288, s.passivity_energy_j);
    f32(292, s.passivity_damping);
  }
  return b;
}

void insertSchema1Sample(RawDb& raw, uint64_t session_id, const Sample& s, bool valid, int format,
                         const std::vector<unsigned char>& blob) {
  sqlite3_stmt* st = nullptr;
  ASSERT_EQ(sqlite3_prepare_v2(raw.get(),
                               "INSERT INTO samples (session_id, seq, t_ns, valid, flags, "
                               "model_version, alpha_rad, beta_rad, gamma_rad, format, data) "
                               "VALUES (?,?,?,?,?,?,?,?,?,?,?)",
                               -1, &st, nullptr),
            SQLITE_OK);
  sqlite3_bind_int64(st, 1, static_cast<sqlite3_int64>(session_id));
  sqlite3_bind_int64(st, 2, static_cast<sqlite3_int64>(s.seq));
  sqlite3_bind_int64(st, 3, s.source_time_ns);
  sqlite3_bind_int(st, 4, valid ? 1 : 0);
  sqlite3_bind_int64(st, 5, s.flags);
  sqlite3_bind_int64(st, 6, s.model_version);
  for (int a = 0; a < 3; ++a) {
    if (std::isfinite(s.mcp_angles_rad[a])) {
      sqlite3_bind_double(st, 7 + a, s.mcp_angles_rad[a]);
    } else {
      sqlite3_bind_null(st, 7 + a);
    }
  }
  sqlite3_bind_int(st, 10, format);
  sqlite3_bind_blob(st, 11, blob.data(), static_cast<int>(blob.size()), SQLITE_TRANSIENT);
  EXPECT_EQ(sqlite3_step(st), SQLITE_DONE) << sqlite3_errmsg(raw.get());
  sqlite3_finalize(st);
}

/// A schema-1 file: session 1 with format-2 samples (one invalid, NaN angle), session 2 with
/// format-1 samples, an event. Returns the samples per session as they should read back.
std::vector<std::vector<std::pair<Sample, bool>>> writeSchema1File(const std::string& path) {
  fs::create_directories(fs::path(path).parent_path());
  RawDb raw(path);
  raw.exec(kSchema1);
  raw.exec(
      "INSERT INTO sessions (id, user, case_name, mode, state, started_ns, ended_ns, "
      "samples_expected) VALUES (1, 'alice', 'healthy', 'mobilization', 'closed', 10, 20, 6), "
      "(2, 'bob', 'stiff', 'exploration', 'active', 30, 0, 0);");
  raw.exec("INSERT INTO events VALUES (1, 15, 'mark', 'half way');");
  std::vector<std::vector<std::pair<Sample, bool>>> want(2);
  std::mt19937_64 rng(7);
  for (uint64_t session : {1u, 2u}) {
    const int format = session == 1 ? 2 : 1;
    for (uint64_t seq = 0; seq < 6; ++seq) {
      Sample s = randomSample(rng);
      s.session_id = session;
      s.seq = seq;
      const bool valid = !(session == 1 && seq == 4);
      if (!valid) s.mcp_angles_rad[0] = std::nan("");
      insertSchema1Sample(raw, session, s, valid, format, blobOf(s, format));
      if (format == 1) {  // format 1 had no passivity fields: they read as zero
        s.passivity_energy_j = 0.0f;
        s.passivity_damping = 0.0f;
      }
      want[session - 1].push_back({s, valid});
    }
  }
  return want;
}

void expectSessionsRead(SqliteStore& store,
                        const std::vector<std::vector<std::pair<Sample, bool>>>& want) {
  for (uint64_t session : {1u, 2u}) {
    SCOPED_TRACE("session " + std::to_string(session));
    const auto& w = want[session - 1];
    std::size_t n = 0;
    store.forEachSample(session, [&](const Sample& got, bool ok) {
      ASSERT_LT(n, w.size());
      expectSameSample(got, w[n].first);
      EXPECT_EQ(ok, w[n].second);
      ++n;
    });
    EXPECT_EQ(n, w.size());
  }
  const auto s1 = store.session(1);
  ASSERT_TRUE(s1);
  EXPECT_EQ(s1->user, "alice");
  EXPECT_EQ(s1->samples, 6u);
  EXPECT_EQ(s1->rejected, 1u);
  EXPECT_EQ(s1->samples_expected, 6u);
  EXPECT_EQ(store.session(2)->samples, 6u);
  ASSERT_EQ(store.events(1).size(), 1u);
  EXPECT_EQ(store.events(1)[0].text, "half way");
}

TEST_F(SqliteStoreTest, MigratesASchema1BlobFileInPlace) {
  const auto want = writeSchema1File(dbPath());
  {
    RawDb raw(dbPath());
    EXPECT_EQ(raw.integer("PRAGMA user_version"), 0);
    EXPECT_EQ(raw.integer("PRAGMA application_id"), 0);
  }
  const std::string before = fileBytes(dbPath());

  // A reader reads the blobs as they are and changes nothing.
  {
    SqliteStore reader(dbPath(), SqliteStore::Mode::kReadOnly);
    expectSessionsRead(reader, want);
  }
  EXPECT_EQ(fileBytes(dbPath()), before) << "a read-only open must not migrate";

  // The writer migrates on opening.
  {
    SqliteStore store(dbPath());
    expectSessionsRead(store, want);
    const uint64_t id = store.createSession(info("carol"));
    EXPECT_GT(id, 2u);
    EXPECT_EQ(store.appendSamples(id, samples(id, 0, 3), {}), 3u);
    EXPECT_EQ(store.appendSamples(1, {&want[0][0].first, 1}, {}), 0u) << "keys kept";
  }
  {
    RawDb raw(dbPath());
    EXPECT_EQ(raw.integer("PRAGMA user_version"), 7);
    EXPECT_EQ(raw.integer("PRAGMA application_id"), 0x54484E44);
    EXPECT_EQ(raw.integer("SELECT count(*) FROM sqlite_master WHERE name LIKE 'samples_%'"), 0)
        << "old table dropped";
    EXPECT_EQ(raw.integer("SELECT count(*) FROM pragma_table_info('samples') "
                          "WHERE name IN ('data', 'format')"),
              0);
    EXPECT_EQ(raw.integer("SELECT count(*) FROM samples"), 15);
    EXPECT_EQ(raw.integer("SELECT count(*) FROM meta WHERE key = 'sample_format'"), 0);
    EXPECT_EQ(raw.integer("SELECT count(*) FROM sqlite_master WHERE name = 'session_files'"), 1);
  }
  // Opening again finds schema 3: nothing more to do.
  SqliteStore again(dbPath());
  expectSessionsRead(again, want);
  EXPECT_EQ(again.session(3)->samples, 3u);
}

TEST_F(SqliteStoreTest, MigrationStopsUntouchedAtABlobItCannotRead) {
  auto want = writeSchema1File(dbPath());
  {
    RawDb raw(dbPath());
    Sample s = sample(2, 99);
    insertSchema1Sample(raw, 2, s, true, 3, std::vector<unsigned char>(300, 0));
  }
  const std::string before = fileBytes(dbPath());
  try {
    SqliteStore store(dbPath());
    FAIL() << "migrated a blob of an unknown format";
  } catch (const StoreError& e) {
    EXPECT_THAT(e.what(), HasSubstr(dbPath()));
    EXPECT_THAT(e.what(), HasSubstr("format 3 (300 bytes)"));
  }
  EXPECT_EQ(fileBytes(dbPath()), before);
  RawDb raw(dbPath());
  EXPECT_EQ(raw.integer("PRAGMA user_version"), 0);
  EXPECT_EQ(raw.integer("SELECT count(*) FROM samples"), 13);
}

TEST_F(SqliteStoreTest, RefusesANewerSchemaAndLeavesItUntouched) {
  {
    SqliteStore store(dbPath());
    const uint64_t id = store.createSession(info("alice"));
    store.appendSamples(id, samples(id, 0, 10), {});
  }
  {
    RawDb raw(dbPath());
    raw.exec("PRAGMA user_version = 8;");
  }
  const fs::path dir = fs::path(dbPath()).parent_path();
  const auto listing = dirListing(dir);
  const std::string before = fileBytes(dbPath());
  for (auto mode : {SqliteStore::Mode::kReadWrite, SqliteStore::Mode::kReadOnly}) {
    try {
      SqliteStore store(dbPath(), mode);
      FAIL() << "opened a newer schema";
    } catch (const StoreError& e) {
      EXPECT_THAT(e.what(), HasSubstr(dbPath()));
      EXPECT_THAT(
          e.what(),
          HasSubstr("was written by a newer telehand (schema 8, this program knows up to 7)"));
    }
    EXPECT_EQ(fileBytes(dbPath()), before);
    if (mode == SqliteStore::Mode::kReadWrite) {
      EXPECT_EQ(dirListing(dir), listing) << "no journal left behind";
    } else if (fs::exists(dbPath() + "-wal")) {
      // A read-only connection cannot remove the WAL files of a WAL database; it wrote none.
      EXPECT_EQ(fs::file_size(dbPath() + "-wal"), 0u);
    }
  }
}

TEST_F(SqliteStoreTest, RefusesAForeignSqliteFileAndLeavesItUntouched) {
  const std::string foreign = (dir_ / "foreign.db").string();
  {
    RawDb raw(foreign);
    raw.exec("CREATE TABLE foo (x INTEGER); INSERT INTO foo VALUES (42);");
  }
  const std::string marked = (dir_ / "marked.db").string();
  {
    RawDb raw(marked);
    raw.exec("PRAGMA application_id = 1234; CREATE TABLE samples (x INTEGER);");
  }
  for (const auto& path : {foreign, marked}) {
    const std::string before = fileBytes(path);
    const auto listing = dirListing(dir_);
    for (auto mode : {SqliteStore::Mode::kReadWrite, SqliteStore::Mode::kReadOnly}) {
      try {
        SqliteStore store(path, mode);
        FAIL() << "opened " << path;
      } catch (const StoreError& e) {
        EXPECT_THAT(e.what(), HasSubstr(path));
        EXPECT_THAT(e.what(), HasSubstr("is not a telehand record database"));
      }
    }
    EXPECT_EQ(fileBytes(path), before) << path;
    EXPECT_EQ(dirListing(dir_), listing) << path;
  }
  RawDb raw(foreign);
  EXPECT_EQ(raw.integer("SELECT x FROM foo"), 42);
  EXPECT_EQ(raw.integer("PRAGMA user_version"), 0);
}

TEST_F(SqliteStoreTest, SessionsKeepTheirOwnerAndSchemaTwoFilesGainTheColumn) {
  {
    SqliteStore store(dbPath());
    SessionInfo a = info("alice");
    a.owner = "0110ab12cd34ef56:0000001c:00000001 (device)";
    EXPECT_EQ(store.createSession(a), 1u);
    EXPECT_EQ(store.session(1)->owner, a.owner);
    store.createSession(info("bob"));
    EXPECT_EQ(store.session(2)->owner, "");
  }
  {
    // What schema 2 wrote: no owner column.
    RawDb raw(dbPath());
    raw.exec("ALTER TABLE sessions DROP COLUMN owner; PRAGMA user_version = 2;");
  }
  {
    SqliteStore reader(dbPath(), SqliteStore::Mode::kReadOnly);  // reads it as it is
    EXPECT_EQ(reader.session(1)->user, "alice");
    EXPECT_EQ(reader.session(1)->owner, "");
    RawDb raw(dbPath());
    EXPECT_EQ(raw.integer("PRAGMA user_version"), 2) << "a reader changes nothing";
  }
  {
    SqliteStore writer(dbPath());  // migrates
    EXPECT_EQ(writer.listSessions().size(), 2u);
    SessionInfo c = info("carol");
    c.owner = "carol's participant";
    EXPECT_EQ(writer.session(writer.createSession(c))->owner, "carol's participant");
  }
  RawDb raw(dbPath());
  EXPECT_EQ(raw.integer("PRAGMA user_version"), 7);
  EXPECT_EQ(raw.integer("SELECT count(*) FROM sessions WHERE owner = ''"), 2);
}

TEST_F(SqliteStoreTest, SchemaThreeFilesGainLessonsAndKeepThem) {
  {
    SqliteStore store(dbPath());
    store.createSession(info("alice"));
  }
  {
    // Back to schema 3 as an older telehand left it: no lesson tables.
    RawDb raw(dbPath());
    raw.exec("DROP TABLE lessons; DROP TABLE lesson_runs; DROP TABLE trials;");
    raw.exec("PRAGMA user_version = 3;");
  }
  {
    SqliteStore reader(dbPath(), SqliteStore::Mode::kReadOnly);
    EXPECT_TRUE(reader.listLessons().empty()) << "a reader of a schema-3 file sees no lessons";
    EXPECT_TRUE(reader.trials(1).empty());
    EXPECT_EQ(reader.sessionLesson(1), 0u);
  }
  SqliteStore store(dbPath());  // migrates 3 -> 4
  LessonInfo l;
  l.name = "demo";
  l.demo_session = 1;
  l.case_name = "stiff";
  l.schedule = "faded";
  l.guided = 3;
  l.attempts = 4;
  l.trial_s = 6.5;
  l.assessment = false;
  l.targets = "band_min_n=12;";
  const uint64_t id = store.createLesson(l);
  const auto back = store.lesson(id);
  ASSERT_TRUE(back.has_value());
  EXPECT_EQ(back->schedule, "faded");
  EXPECT_EQ(back->guided, 3);
  EXPECT_DOUBLE_EQ(back->trial_s, 6.5);
  EXPECT_FALSE(back->assessment);
  EXPECT_EQ(back->targets, "band_min_n=12;");
  EXPECT_FALSE(store.lesson(id + 1).has_value());
  const uint64_t run = store.createSession(info("bob"));
  store.setSessionLesson(run, id);
  EXPECT_EQ(store.sessionLesson(run), id);
  TrialRecord t;
  t.session_id = run;
  t.index = 2;
  t.phase = "attempt";
  t.first_seq = 100;
  t.last_seq = 4099;
  t.overall = 71.5;
  t.figures = "missing=0;";
  store.appendTrial(t);
  t.index = 1;
  t.phase = "guided";
  t.authority = 1.0;
  store.appendTrial(t);
  const auto trials = store.trials(run);
  ASSERT_EQ(trials.size(), 2u);
  EXPECT_EQ(trials[0].phase, "guided") << "in the order they ran";
  EXPECT_DOUBLE_EQ(trials[0].authority, 1.0);
  EXPECT_EQ(trials[1].last_seq, 4099u);
  // Samples by range, in order.
  store.appendSamples(run, samples(run, 0, 50), {});
  std::vector<uint64_t> seqs;
  store.forEachSampleIn(run, 10, 14, [&](const Sample& s, bool) { seqs.push_back(s.seq); });
  EXPECT_EQ(seqs, (std::vector<uint64_t>{10, 11, 12, 13, 14}));
  EXPECT_EQ(store.countSamples(run, 10, 14), 5u);
  EXPECT_EQ(store.countSamples(run, 40, UINT64_MAX), 10u);
  const auto ext = store.extent(run);
  ASSERT_TRUE(ext.has_value());
  EXPECT_EQ(ext->first_seq, 0u);
  EXPECT_EQ(ext->last_seq, 49u);
  EXPECT_EQ(ext->last_time_ns - ext->first_time_ns,
            samples(run, 49, 50)[0].source_time_ns - samples(run, 0, 1)[0].source_time_ns);
  EXPECT_FALSE(store.extent(run + 100).has_value());
  RawDb raw(dbPath());
  EXPECT_EQ(raw.integer("PRAGMA user_version"), 7);
}

TEST_F(SqliteStoreTest, SchemaFourFilesLearnWhichLessonsAllowATakeOver) {
  LessonInfo l;
  l.name = "before";
  l.demo_session = 1;
  l.case_name = "healthy";
  l.targets = "band_min_n=12;";
  uint64_t old_id = 0;
  {
    SqliteStore store(dbPath());
    store.createSession(info("alice"));
    old_id = store.createLesson(l);
  }
  {
    // Back to schema 4 as an older telehand left it: lessons without the column.
    RawDb raw(dbPath());
    raw.exec("ALTER TABLE lessons DROP COLUMN takeover; PRAGMA user_version = 4;");
  }
  {
    SqliteStore reader(dbPath(), SqliteStore::Mode::kReadOnly);
    ASSERT_TRUE(reader.lesson(old_id).has_value()) << "a reader of a schema-4 file reads it";
    EXPECT_FALSE(reader.lesson(old_id)->takeover);
    EXPECT_EQ(reader.listLessons().size(), 1u);
    RawDb raw(dbPath());
    EXPECT_EQ(raw.integer("PRAGMA user_version"), 4) << "a reader changes nothing";
  }
  SqliteStore store(dbPath());  // migrates 4 -> 6
  EXPECT_FALSE(store.lesson(old_id)->takeover) << "a lesson made before allows none";
  l.name = "after";
  l.takeover = true;
  const uint64_t id = store.createLesson(l);
  EXPECT_TRUE(store.lesson(id)->takeover);
  EXPECT_EQ(store.listLessons().back().name, "after");
  RawDb raw(dbPath());
  EXPECT_EQ(raw.integer("PRAGMA user_version"), 7);
}

// Schema 6 (before the massage's web columns): a reader reads its samples with the web at 0,
// a writer adds the columns and keeps what was there.
TEST_F(SqliteStoreTest, ASchemaSixRecordGainsTheWebColumns) {
  uint64_t id = 0;
  {
    SqliteStore store(dbPath());
    id = store.createSession(info("alice"));
    store.appendSamples(id, samples(id, 0, 5), {});
  }
  {
    RawDb raw(dbPath());
    std::string drop;
    for (const std::string f : {"thumb", "index"}) {
      drop += "ALTER TABLE samples DROP COLUMN " + f + "_depth_m;";
      for (const char* c : {"x", "y", "z"})
        drop += "ALTER TABLE samples DROP COLUMN " + f + "_tissue" + c + "_n;";
    }
    raw.exec(drop + "PRAGMA user_version = 6;");
  }
  const auto depths = [&](SqliteStore& s) {
    std::vector<double> d;
    s.forEachSample(id, [&](const Sample& x, bool) { d.push_back(x.fingers[1].contact_depth_m); });
    return d;
  };
  {
    SqliteStore reader(dbPath(), SqliteStore::Mode::kReadOnly);
    EXPECT_EQ(depths(reader), std::vector<double>(5, 0.0)) << "a reader of schema 6 reads it";
    RawDb raw(dbPath());
    EXPECT_EQ(raw.integer("PRAGMA user_version"), 6) << "a reader changes nothing";
  }
  SqliteStore store(dbPath());  // migrates 6 -> 7
  auto more = samples(id, 5, 7);
  for (auto& x : more) {
    x.fingers[1].contact_depth_m = 0.006;
    x.fingers[0].tissue_force_n[2] = 10.5;
  }
  store.appendSamples(id, more, {});
  EXPECT_EQ(depths(store), (std::vector<double>{0, 0, 0, 0, 0, 0.006, 0.006}));
  double fz = 0.0;
  store.forEachSample(id, [&](const Sample& x, bool) { fz += x.fingers[0].tissue_force_n[2]; });
  EXPECT_DOUBLE_EQ(fz, 21.0);
  RawDb raw(dbPath());
  EXPECT_EQ(raw.integer("PRAGMA user_version"), 7);
}

TEST_F(SqliteStoreTest, AnEmptySqliteFileGetsTheSchema) {
  fs::create_directories(fs::path(dbPath()).parent_path());
  std::ofstream(dbPath()).close();  // zero bytes
  {
    SqliteStore store(dbPath());
    const uint64_t id = store.createSession(info("alice"));
    EXPECT_EQ(store.appendSamples(id, samples(id, 0, 2), {}), 2u);
  }
  RawDb raw(dbPath());
  EXPECT_EQ(raw.integer("PRAGMA user_version"), 7);
}

// ---- CSV ----------------------------------------------------------------------------------

std::vector<std::string> split(const std::string& row) {
  std::vector<std::string> out;
  std::string field;
  for (char c : row) {
    if (c == ',') {
      out.push_back(field);
      field.clear();
    } else {
      field += c;
    }
  }
  out.push_back(field);
  return out;
}

TEST(SampleCsv, HeaderNamesEveryColumnOnce) {
  const auto& cols = sampleColumns();
  // 4 ids + 3 angles + 3 torques + 2 fingers x (3 pos + 4 quat + 4 fsr + 2 eq. 1-2 + 3 cmd)
  // + 2 passivity + 2 fingers x (web depth + 3 web force) + valid.
  EXPECT_EQ(cols.size(), 4u + 3u + 3u + 2u * 16u + 2u + 2u * 4u + 1u);
  EXPECT_EQ(cols.front(), "seq");
  EXPECT_EQ(cols.back(), "valid");
  std::vector<std::string> sorted = cols;
  std::sort(sorted.begin(), sorted.end());
  EXPECT_EQ(std::adjacent_find(sorted.begin(), sorted.end()), sorted.end()) << "duplicate name";
  for (const char* want : {"t_ns", "alpha_rad", "tau_gamma_nm", "thumb_fsr1_n", "index_fsr4_n",
                           "index_tangential_n", "thumb_normal_n", "index_cmdz_n", "thumb_qw",
                           "passivity_energy_j", "passivity_damping_ns_per_m"}) {
    EXPECT_NE(std::find(cols.begin(), cols.end(), want), cols.end()) << want;
  }
}

TEST(SampleCsv, RowHasOneFieldPerColumnInOrder) {
  const Sample s = sample(1, 1234);
  const auto& cols = sampleColumns();
  const auto fields = split(sampleCsvRow(s, true));
  ASSERT_EQ(fields.size(), cols.size());
  auto field = [&](const std::string& name) {
    return fields[static_cast<std::size_t>(std::find(cols.begin(), cols.end(), name) -
                                           cols.begin())];
  };
  EXPECT_EQ(field("seq"), "1234");
  EXPECT_EQ(field("t_ns"), std::to_string(s.source_time_ns));
  EXPECT_EQ(field("valid"), "1");
  EXPECT_DOUBLE_EQ(std::stod(field("index_fsr4_n")), s.fingers[1].fsr_n[3]);
  EXPECT_DOUBLE_EQ(std::stod(field("thumb_normal_n")), 2.0);
  EXPECT_NEAR(std::stod(field("beta_rad")), s.mcp_angles_rad[1], 1e-8);
  EXPECT_EQ(split(sampleCsvRow(s, false)).back(), "0");
  // Non-finite values keep the column count.
  Sample bad = s;
  bad.mcp_angles_rad[0] = std::nan("");
  EXPECT_EQ(split(sampleCsvRow(bad, false)).size(), cols.size());
}

}  // namespace
}  // namespace telehand::server::store
