// The SQLite session store: sessions, samples (duplicates ignored), events, CSV columns.
#include "telehand/server/store/sqlite_store.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sqlite3.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "telehand/core/error.h"

namespace telehand::server::store {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

/// A fresh directory per test, removed afterwards.
class SqliteStoreTest : public ::testing::Test {
 protected:
  void SetUp() override {
    static std::atomic<int> counter{0};
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::temp_directory_path() /
           ("telehand-store-" + std::string(info->name()) + "-" + std::to_string(::getpid()) +
            "-" + std::to_string(counter++));
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

Sample sample(uint64_t session, uint64_t seq) {
  Sample s{};
  s.session_id = session;
  s.seq = seq;
  s.source_time_ns = 1'000'000'000 + static_cast<int64_t>(seq) * 1'000'000;
  s.model_version = 1;
  s.flags = static_cast<uint32_t>(seq % 4);
  for (int a = 0; a < 3; ++a) {
    s.mcp_angles_rad[a] = 0.1 * a + 0.001 * static_cast<double>(seq);
    s.mcp_torque_nm[a] = -0.01 * a;
  }
  for (int k = 0; k < 2; ++k) {
    for (int i = 0; i < 3; ++i) {
      s.fingers[k].position_m[i] = 0.01 * (k + 1) + 0.001 * i;
      s.fingers[k].command_n[i] = 0.5 * i - k;
    }
    s.fingers[k].orientation_q[0] = 1.0;
    for (int i = 0; i < 4; ++i) s.fingers[k].fsr_n[i] = static_cast<float>(seq % 7) + 0.25f * static_cast<float>(i);
    s.fingers[k].tangential_n = 0.5f;
    s.fingers[k].normal_n = 2.0f;
  }
  return s;
}

std::vector<Sample> samples(uint64_t session, uint64_t from, uint64_t to) {
  std::vector<Sample> v;
  for (uint64_t i = from; i < to; ++i) v.push_back(sample(session, i));
  return v;
}

SessionInfo info(const std::string& user) {
  SessionInfo i;
  i.user = user;
  i.case_name = "healthy";
  i.mode = "mobilization";
  i.started_ns = 1'700'000'000'000'000'000;
  return i;
}

std::vector<uint64_t> seqsOf(SqliteStore& store, uint64_t id) {
  std::vector<uint64_t> out;
  store.forEachSample(id, [&](const Sample& s, bool) { out.push_back(s.seq); });
  return out;
}

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

TEST_F(SqliteStoreTest, SessionIdsIncreaseAcrossReopen) {
  uint64_t a = 0, b = 0, c = 0;
  {
    SqliteStore store(dbPath());
    a = store.createSession(info("alice"));
    b = store.createSession(info("bob"));
  }
  SqliteStore store(dbPath());
  c = store.createSession(info("carol"));
  EXPECT_GT(a, 0u);
  EXPECT_GT(b, a);
  EXPECT_GT(c, b);
}

TEST_F(SqliteStoreTest, NewSessionIsActiveWithItsFields) {
  SqliteStore store(dbPath());
  const uint64_t id = store.createSession(info("alice"));
  const auto s = store.session(id);
  ASSERT_TRUE(s.has_value());
  EXPECT_EQ(s->id, id);
  EXPECT_EQ(s->user, "alice");
  EXPECT_EQ(s->case_name, "healthy");
  EXPECT_EQ(s->mode, "mobilization");
  EXPECT_EQ(s->state, "active");
  EXPECT_EQ(s->started_ns, 1'700'000'000'000'000'000);
  EXPECT_EQ(s->samples, 0u);
  EXPECT_FALSE(store.session(id + 100).has_value());
}

TEST_F(SqliteStoreTest, AppendCountsNewSamplesAndIgnoresDuplicates) {
  SqliteStore store(dbPath());
  const uint64_t id = store.createSession(info("alice"));
  const auto first = samples(id, 0, 10);
  EXPECT_EQ(store.appendSamples(id, first, {}), 10u);
  // Overlapping resend (store-and-forward after an outage): only 10..14 are new.
  const auto again = samples(id, 5, 15);
  EXPECT_EQ(store.appendSamples(id, again, {}), 5u);
  EXPECT_EQ(store.appendSamples(id, first, {}), 0u);
  EXPECT_EQ(store.appendSamples(id, {}, {}), 0u);
  EXPECT_EQ(store.session(id)->samples, 15u);
}

TEST_F(SqliteStoreTest, DuplicateKeepsTheFirstCopy) {
  SqliteStore store(dbPath());
  const uint64_t id = store.createSession(info("alice"));
  auto s = sample(id, 3);
  store.appendSamples(id, {&s, 1}, {});
  auto changed = s;
  changed.fingers[0].fsr_n[0] = 99.0f;
  store.appendSamples(id, {&changed, 1}, {});
  store.forEachSample(id, [&](const Sample& got, bool) {
    EXPECT_EQ(got.fingers[0].fsr_n[0], s.fingers[0].fsr_n[0]);
  });
}

TEST_F(SqliteStoreTest, SamplesComeBackWholeInSequenceOrder) {
  SqliteStore store(dbPath());
  const uint64_t id = store.createSession(info("alice"));
  std::vector<Sample> shuffled = {sample(id, 20), sample(id, 3), sample(id, 11),
                                                    sample(id, 0), sample(id, 7)};
  store.appendSamples(id, shuffled, {});
  EXPECT_EQ(seqsOf(store, id), (std::vector<uint64_t>{0, 3, 7, 11, 20}));
  store.forEachSample(id, [&](const Sample& got, bool valid) {
    const Sample want = sample(id, got.seq);
    EXPECT_TRUE(valid);
    EXPECT_EQ(got.source_time_ns, want.source_time_ns);
    EXPECT_EQ(got.flags, want.flags);
    EXPECT_EQ(got.mcp_angles_rad[2], want.mcp_angles_rad[2]);
    EXPECT_EQ(got.fingers[1].position_m[2], want.fingers[1].position_m[2]);
    EXPECT_EQ(got.fingers[1].fsr_n[3], want.fingers[1].fsr_n[3]);
    EXPECT_EQ(got.fingers[0].command_n[1], want.fingers[0].command_n[1]);
  });
}

TEST_F(SqliteStoreTest, SessionsDoNotMix) {
  SqliteStore store(dbPath());
  const uint64_t a = store.createSession(info("alice"));
  const uint64_t b = store.createSession(info("bob"));
  store.appendSamples(a, samples(a, 0, 4), {});
  store.appendSamples(b, samples(b, 0, 6), {});  // same seqs, another session: all new
  EXPECT_EQ(store.session(a)->samples, 4u);
  EXPECT_EQ(store.session(b)->samples, 6u);
  EXPECT_EQ(seqsOf(store, a).size(), 4u);
}

TEST_F(SqliteStoreTest, InvalidSamplesAreKeptAndCounted) {
  SqliteStore store(dbPath());
  const uint64_t id = store.createSession(info("alice"));
  auto batch = samples(id, 0, 4);
  batch[2].mcp_angles_rad[0] = std::nan("");
  const std::vector<uint8_t> valid = {1, 1, 0, 1};
  EXPECT_EQ(store.appendSamples(id, batch, valid), 4u);
  EXPECT_EQ(store.session(id)->rejected, 1u);
  std::vector<bool> flags;
  store.forEachSample(id, [&](const Sample& s, bool ok) {
    flags.push_back(ok);
    if (s.seq == 2) {
      EXPECT_TRUE(std::isnan(s.mcp_angles_rad[0]));
    }
  });
  EXPECT_EQ(flags, (std::vector<bool>{true, true, false, true}));
}

TEST_F(SqliteStoreTest, EventsInInsertionOrder) {
  SqliteStore store(dbPath());
  const uint64_t id = store.createSession(info("alice"));
  store.appendEvent(id, {200, "mark", "second, but earlier id"});
  store.appendEvent(id, {100, "feedback", "more force"});
  store.appendEvent(id + 1, {150, "mark", "other session"});
  const auto ev = store.events(id);
  ASSERT_EQ(ev.size(), 2u);
  EXPECT_EQ(ev[0].time_ns, 200);
  EXPECT_EQ(ev[0].kind, "mark");
  EXPECT_EQ(ev[1].text, "more force");
}

TEST_F(SqliteStoreTest, CloseRecordsEndExpectedAndState) {
  SqliteStore store(dbPath());
  const uint64_t id = store.createSession(info("alice"));
  store.appendSamples(id, samples(id, 0, 8), {});
  store.closeSession(id, 1'700'000'100'000'000'000, 10, "closed");
  const auto s = store.session(id);
  ASSERT_TRUE(s);
  EXPECT_EQ(s->state, "closed");
  EXPECT_EQ(s->ended_ns, 1'700'000'100'000'000'000);
  EXPECT_EQ(s->samples_expected, 10u);
  EXPECT_EQ(s->samples, 8u) << "two samples never arrived";
}

TEST_F(SqliteStoreTest, ListIsOrderedById) {
  SqliteStore store(dbPath());
  const uint64_t a = store.createSession(info("alice"));
  const uint64_t b = store.createSession(info("bob"));
  store.appendSamples(b, samples(b, 0, 3), {});
  store.closeSession(a, 5, 0, "abandoned");
  const auto list = store.listSessions();
  ASSERT_EQ(list.size(), 2u);
  EXPECT_EQ(list[0].id, a);
  EXPECT_EQ(list[0].user, "alice");
  EXPECT_EQ(list[0].state, "abandoned");
  EXPECT_EQ(list[1].id, b);
  EXPECT_EQ(list[1].samples, 3u);
  EXPECT_EQ(list[1].state, "active");
}

TEST_F(SqliteStoreTest, ReaderSeesWhatTheWriterStoredWhileItIsOpen) {
  SqliteStore writer(dbPath());
  const uint64_t id = writer.createSession(info("alice"));
  writer.appendSamples(id, samples(id, 0, 5), {});
  SqliteStore reader(dbPath(), SqliteStore::Mode::kReadOnly);
  EXPECT_EQ(reader.session(id)->samples, 5u);
  writer.appendSamples(id, samples(id, 5, 9), {});
  EXPECT_EQ(reader.session(id)->samples, 9u);
  EXPECT_EQ(seqsOf(reader, id).back(), 8u);
  EXPECT_THROW(reader.createSession(info("mallory")), StoreError) << "read-only";
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
  // + 2 passivity + valid.
  EXPECT_EQ(cols.size(), 4u + 3u + 3u + 2u * 16u + 2u + 1u);
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
}  // namespace telehand::server::session
