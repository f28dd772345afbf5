// What every record store does, run on each: SQLite (a file in a fresh directory) and
// PostgreSQL (a fresh schema in a throw-away cluster, one per test process, tests/support/
// pg_cluster.h). Stores are opened through openStore(), as the programs open them. Sessions,
// samples (duplicates ignored, the first copy kept, invalid ones kept flagged), every field
// through the columns, events, files, reaches, lessons and trials, readers beside a writer,
// the schema version and foreign tables refused.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sqlite3.h>
#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <limits>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "../../support/pg_cluster.h"
#include "store_samples.h"
#include "telehand/core/error.h"
#include "telehand/server/store/open_store.h"

namespace telehand::server::store {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;
using namespace store_test;
using Mode = SessionStore::Mode;

/// Where a test's record lives, and what the tests do to it behind the store's back.
class Backend {
 public:
  virtual ~Backend() = default;
  /// What --db would say.
  virtual std::string spec() const = 0;
  /// Says the record was written by telehand's schema `version`.
  virtual void setSchemaVersion(int version) = 0;
  /// Puts a table of another program where the record would be.
  virtual void addForeignTable() = 0;
};

/// An SQLite file in a directory of its own (its parent made on opening).
class SqliteBackend final : public Backend {
 public:
  SqliteBackend() {
    static std::atomic<int> counter{0};
    dir_ = fs::temp_directory_path() /
           ("telehand-contract-" + std::to_string(::getpid()) + "-" + std::to_string(counter++));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  ~SqliteBackend() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  std::string spec() const override { return (dir_ / "records" / "telehand.db").string(); }
  void setSchemaVersion(int version) override {
    sql("PRAGMA user_version = " + std::to_string(version));
  }
  void addForeignTable() override {
    fs::create_directories(fs::path(spec()).parent_path());
    sql("CREATE TABLE inventory (item TEXT, count INTEGER); INSERT INTO inventory VALUES ('x', 1)");
  }

 private:
  void sql(const std::string& s) {
    sqlite3* db = nullptr;
    ASSERT_EQ(sqlite3_open(spec().c_str(), &db), SQLITE_OK);
    EXPECT_EQ(sqlite3_exec(db, s.c_str(), nullptr, nullptr, nullptr), SQLITE_OK) << s;
    sqlite3_close(db);
  }
  fs::path dir_;
};

/// A schema of its own in the test process's PostgreSQL cluster, dropped afterwards.
class PostgresBackend final : public Backend {
 public:
  PostgresBackend() {
    static std::atomic<int> counter{0};
    schema_ = "contract_" + std::to_string(::getpid()) + "_" + std::to_string(counter++);
    cluster().exec("CREATE SCHEMA " + schema_, "telehand");
  }
  ~PostgresBackend() override {
    try {
      cluster().exec("DROP SCHEMA " + schema_ + " CASCADE", "telehand");
    } catch (const std::exception& e) {
      ADD_FAILURE() << e.what();
    }
  }
  std::string spec() const override { return cluster().uri("telehand", schema_); }
  void setSchemaVersion(int version) override {
    cluster().exec(
        "UPDATE " + schema_ + ".telehand_schema SET version = " + std::to_string(version),
        "telehand");
  }
  void addForeignTable() override {
    cluster().exec("CREATE TABLE " + schema_ +
                       ".inventory (item TEXT, count INTEGER); INSERT INTO " + schema_ +
                       ".inventory VALUES ('x', 1)",
                   "telehand");
  }

 private:
  static test::PgCluster& cluster() { return *test::sharedPgCluster().cluster; }
  std::string schema_;
};

enum class Kind { kSqlite, kPostgres };

class SessionStoreTest : public ::testing::TestWithParam<Kind> {
 protected:
  void SetUp() override {
    if (GetParam() == Kind::kSqlite) {
      backend_ = std::make_unique<SqliteBackend>();
      return;
    }
    const auto shared = test::sharedPgCluster();
    if (!shared.skip.empty()) GTEST_SKIP() << shared.skip;
    if (!shared.error.empty()) FAIL() << shared.error;
    backend_ = std::make_unique<PostgresBackend>();
  }
  std::unique_ptr<SessionStore> open(Mode mode = Mode::kReadWrite) {
    return openStore(backend_->spec(), mode);
  }
  std::string spec() const { return backend_->spec(); }
  std::unique_ptr<Backend> backend_;
};

// A pool of servers on one record (docs/pool.md): leases, the least-loaded assignment of
// OPENs, one owner per session, orphans, checkpoints.
TEST_P(SessionStoreTest, APoolAssignsOpensToTheLeastLoadedAndGivesEachSessionOneOwner) {
  auto store = this->open();
  constexpr int64_t kMinute = 60'000'000'000;
  EXPECT_TRUE(store->poolHeartbeat("a", 0, kMinute).empty());
  EXPECT_TRUE(store->poolHeartbeat("b", 0, kMinute).empty());
  ASSERT_EQ(store->poolMembers().size(), 2u);
  EXPECT_EQ(store->poolAssign("open-1"), "a");  // a tie goes by name
  EXPECT_EQ(store->poolAssign("open-1"), "a") << "an OPEN is assigned once";
  EXPECT_EQ(store->poolAssign("open-2"), "b") << "a has an OPEN pending";
  const uint64_t s1 = store->createSession(info("alice"));
  const PoolClaim first = store->poolClaim(s1, "a", "open-1");
  EXPECT_TRUE(first.won);
  EXPECT_EQ(first.previous, "");
  EXPECT_EQ(store->poolOwner(s1), "a");
  EXPECT_FALSE(store->poolClaim(s1, "b").won) << "a's lease runs";
  EXPECT_EQ(store->poolOwner(s1), "a");
  EXPECT_EQ(store->poolHeartbeat("a", 1, kMinute), std::vector<uint64_t>{s1});
  const auto members = store->poolMembers();
  ASSERT_EQ(members.size(), 2u);
  EXPECT_EQ(members[0].sessions + members[1].sessions, 2u) << "s1 and open-2";
  // A session nobody owns (created long ago, e.g. by a server before the pool): an orphan.
  const uint64_t s2 = store->createSession(info("bob"));
  EXPECT_EQ(store->poolOrphans(), std::vector<uint64_t>{s2});
  // a stops renewing: its lease runs out and its session becomes an orphan b may take.
  store->poolHeartbeat("a", 1, -1'000'000);
  const auto orphans = store->poolOrphans();
  EXPECT_EQ(orphans, (std::vector<uint64_t>{s1, s2}));
  const PoolClaim taken = store->poolClaim(s1, "b");
  EXPECT_TRUE(taken.won);
  EXPECT_EQ(taken.previous, "a");
  EXPECT_LT(taken.previous_lease_until_ns, taken.now_ns);
  EXPECT_FALSE(store->poolClaim(s1, "a").won) << "b's lease runs now";
  EXPECT_TRUE(store->poolHeartbeat("a", 1, kMinute).empty()) << "a learns it lost s1";
  EXPECT_EQ(store->poolHeartbeat("b", 1, kMinute), std::vector<uint64_t>{s1});
  EXPECT_EQ(store->poolAssign("open-3"), "a") << "now the least loaded";
  store->closeSession(s1, 1, 0, "closed");
  EXPECT_TRUE(store->poolHeartbeat("b", 0, kMinute).empty()) << "a closed session is owned no more";
  EXPECT_EQ(store->poolOrphans(), std::vector<uint64_t>{s2});
  store->poolLeave("b");
  ASSERT_EQ(store->poolMembers().size(), 1u);
  EXPECT_EQ(store->poolMembers()[0].server, "a");
  store->poolLeave("a");
  EXPECT_THROW(store->poolAssign("open-4"), StoreError) << "no server holds a lease";

  EXPECT_FALSE(store->checkpoint(s2).has_value());
  std::string blob(3000, '\0');
  for (std::size_t i = 0; i < blob.size(); ++i) blob[i] = static_cast<char>(i * 7);
  store->putCheckpoint(s2, {41, 123, blob});
  store->putCheckpoint(s2, {42, 456, blob + "x"});
  const auto cp = store->checkpoint(s2);
  ASSERT_TRUE(cp.has_value());
  EXPECT_EQ(cp->seq, 42u);
  EXPECT_EQ(cp->time_ns, 456);
  EXPECT_EQ(cp->data, blob + "x");
}

INSTANTIATE_TEST_SUITE_P(Store, SessionStoreTest, ::testing::Values(Kind::kSqlite, Kind::kPostgres),
                         [](const ::testing::TestParamInfo<Kind>& p) {
                           return p.param == Kind::kSqlite ? "Sqlite" : "Postgres";
                         });

TEST_P(SessionStoreTest, OpensWhatTheSpecNamesAndSaysWhere) {
  auto store = this->open();
  EXPECT_EQ(store->location(), describeStore(this->spec()));
  EXPECT_EQ(isPostgresUri(this->spec()), GetParam() == Kind::kPostgres);
}

TEST_P(SessionStoreTest, SessionIdsIncreaseAcrossReopen) {
  uint64_t a = 0, b = 0, c = 0;
  {
    auto store = this->open();
    a = store->createSession(info("alice"));
    b = store->createSession(info("bob"));
  }
  auto store = this->open();
  c = store->createSession(info("carol"));
  EXPECT_GT(a, 0u);
  EXPECT_GT(b, a);
  EXPECT_GT(c, b);
}

TEST_P(SessionStoreTest, NewSessionIsActiveWithItsFields) {
  auto store = this->open();
  const uint64_t id = store->createSession(info("alice"));
  const auto s = store->session(id);
  ASSERT_TRUE(s.has_value());
  EXPECT_EQ(s->id, id);
  EXPECT_EQ(s->user, "alice");
  EXPECT_EQ(s->case_name, "healthy");
  EXPECT_EQ(s->mode, "mobilization");
  EXPECT_EQ(s->state, "active");
  EXPECT_EQ(s->started_ns, 1'700'000'000'000'000'000);
  EXPECT_EQ(s->samples, 0u);
  EXPECT_FALSE(store->session(id + 100).has_value());
}

TEST_P(SessionStoreTest, AppendCountsNewSamplesAndIgnoresDuplicates) {
  auto store = this->open();
  const uint64_t id = store->createSession(info("alice"));
  const auto first = samples(id, 0, 10);
  EXPECT_EQ(store->appendSamples(id, first, {}), 10u);
  // Overlapping resend (store-and-forward after an outage): only 10..14 are new.
  const auto again = samples(id, 5, 15);
  EXPECT_EQ(store->appendSamples(id, again, {}), 5u);
  EXPECT_EQ(store->appendSamples(id, first, {}), 0u);
  EXPECT_EQ(store->appendSamples(id, {}, {}), 0u);
  EXPECT_EQ(store->session(id)->samples, 15u);
}

// What a resumed session acknowledges at once: the record's stored prefix, up to its first
// gap, whatever the gap's place (and nothing without seq 0).
TEST_P(SessionStoreTest, TheStoredPrefixEndsAtTheFirstGap) {
  auto store = this->open();
  const uint64_t empty = store->createSession(info("alice"));
  EXPECT_EQ(store->storedPrefix(empty), 0u);
  const uint64_t whole = store->createSession(info("bob"));
  store->appendSamples(whole, samples(whole, 0, 250), {});
  EXPECT_EQ(store->storedPrefix(whole), 250u);
  const uint64_t gaps = store->createSession(info("carol"));
  store->appendSamples(gaps, samples(gaps, 0, 137), {});
  store->appendSamples(gaps, samples(gaps, 138, 300), {});
  store->appendSamples(gaps, samples(gaps, 400, 420), {});
  EXPECT_EQ(store->storedPrefix(gaps), 137u);
  store->appendSamples(gaps, samples(gaps, 137, 138), {});
  EXPECT_EQ(store->storedPrefix(gaps), 300u);
  const uint64_t late = store->createSession(info("dave"));
  store->appendSamples(late, samples(late, 5, 50), {});
  EXPECT_EQ(store->storedPrefix(late), 0u);
  store->appendSamples(late, samples(late, 0, 5), {});
  EXPECT_EQ(store->storedPrefix(late), 50u);
  // Other sessions' rows do not count.
  EXPECT_EQ(store->storedPrefix(whole), 250u);
}

TEST_P(SessionStoreTest, DuplicateKeepsTheFirstCopy) {
  auto store = this->open();
  const uint64_t id = store->createSession(info("alice"));
  auto s = sample(id, 3);
  store->appendSamples(id, {&s, 1}, {});
  auto changed = s;
  changed.fingers[0].fsr_n[0] = 99.0f;
  store->appendSamples(id, {&changed, 1}, {});
  store->forEachSample(id, [&](const Sample& got, bool) {
    EXPECT_EQ(got.fingers[0].fsr_n[0], s.fingers[0].fsr_n[0]);
  });
}

TEST_P(SessionStoreTest, ARepeatWithinOneBatchKeepsTheFirstCopyAndItsFlag) {
  auto store = this->open();
  const uint64_t id = store->createSession(info("alice"));
  std::vector<Sample> batch = {sample(id, 1), sample(id, 2), sample(id, 1), sample(id, 0)};
  batch[2].fingers[1].normal_n = 77.0f;
  const std::vector<uint8_t> valid = {0, 1, 1, 1};
  EXPECT_EQ(store->appendSamples(id, batch, valid), 3u);
  std::vector<uint64_t> seqs;
  store->forEachSample(id, [&](const Sample& got, bool ok) {
    seqs.push_back(got.seq);
    if (got.seq == 1) {
      EXPECT_EQ(got.fingers[1].normal_n, 2.0f) << "the first copy";
      EXPECT_FALSE(ok) << "with the first copy's flag";
    }
  });
  EXPECT_EQ(seqs, (std::vector<uint64_t>{0, 1, 2}));
  EXPECT_EQ(store->session(id)->rejected, 1u);
}

TEST_P(SessionStoreTest, SamplesComeBackWholeInSequenceOrder) {
  auto store = this->open();
  const uint64_t id = store->createSession(info("alice"));
  std::vector<Sample> shuffled = {sample(id, 20), sample(id, 3), sample(id, 11), sample(id, 0),
                                  sample(id, 7)};
  store->appendSamples(id, shuffled, {});
  EXPECT_EQ(seqsOf(*store, id), (std::vector<uint64_t>{0, 3, 7, 11, 20}));
  store->forEachSample(id, [&](const Sample& got, bool valid) {
    EXPECT_TRUE(valid);
    expectSameSample(got, sample(id, got.seq));
  });
}

TEST_P(SessionStoreTest, SessionsDoNotMix) {
  auto store = this->open();
  const uint64_t a = store->createSession(info("alice"));
  const uint64_t b = store->createSession(info("bob"));
  store->appendSamples(a, samples(a, 0, 4), {});
  store->appendSamples(b, samples(b, 0, 6), {});  // same seqs, another session: all new
  EXPECT_EQ(store->session(a)->samples, 4u);
  EXPECT_EQ(store->session(b)->samples, 6u);
  EXPECT_EQ(seqsOf(*store, a).size(), 4u);
}

TEST_P(SessionStoreTest, BatchesOfSeveralSessionsAreStoredAsEachWouldBeAlone) {
  auto store = this->open();
  const uint64_t a = store->createSession(info("alice"));
  const uint64_t b = store->createSession(info("bob"));
  using Batch = server::store::SessionStore::SampleBatch;
  const auto write = [&](std::vector<Sample> sa, std::vector<Sample> sb,
                         std::vector<uint8_t> vb = {}) {
    const std::vector<Batch> batches = {{a, sa, {}}, {b, sb, vb}};
    const auto r = store->appendSampleBatches(batches);
    EXPECT_EQ(r.size(), 2u);
    for (const auto& x : r) EXPECT_TRUE(x.stored) << x.error;
    return std::vector<uint64_t>{r[0].added, r[1].added};
  };
  EXPECT_EQ(write(samples(a, 0, 10), samples(b, 0, 6)), (std::vector<uint64_t>{10, 6}));
  // Some stored before (PostgreSQL's one COPY fails on the key): each batch counts its new.
  EXPECT_EQ(write(samples(a, 5, 15), samples(b, 6, 9)), (std::vector<uint64_t>{5, 3}));
  // A repeat within a batch keeps the first copy and its flag.
  std::vector<Sample> repeat = {sample(b, 9), sample(b, 9), sample(b, 10)};
  repeat[1].fingers[1].normal_n = 77.0f;
  EXPECT_EQ(write(samples(a, 20, 22), repeat, {0, 1, 1}), (std::vector<uint64_t>{2, 2}));
  EXPECT_TRUE(store->appendSampleBatches({}).empty());
  EXPECT_EQ(store->session(a)->samples, 17u);
  EXPECT_EQ(store->session(b)->samples, 11u);
  EXPECT_EQ(store->session(b)->rejected, 1u);
  store->forEachSample(a,
                       [&](const Sample& got, bool) { expectSameSample(got, sample(a, got.seq)); });
  store->forEachSample(b, [&](const Sample& got, bool) {
    if (got.seq == 9) {
      EXPECT_NE(got.fingers[1].normal_n, 77.0f) << "the first copy";
    } else {
      expectSameSample(got, sample(b, got.seq));
    }
  });
}

TEST_P(SessionStoreTest, InvalidSamplesAreKeptAndCounted) {
  auto store = this->open();
  const uint64_t id = store->createSession(info("alice"));
  auto batch = samples(id, 0, 4);
  batch[2].mcp_angles_rad[0] = std::nan("");
  const std::vector<uint8_t> valid = {1, 1, 0, 1};
  EXPECT_EQ(store->appendSamples(id, batch, valid), 4u);
  EXPECT_EQ(store->session(id)->rejected, 1u);
  std::vector<bool> flags;
  store->forEachSample(id, [&](const Sample& s, bool ok) {
    flags.push_back(ok);
    if (s.seq == 2) {
      EXPECT_TRUE(std::isnan(s.mcp_angles_rad[0]));
    }
  });
  EXPECT_EQ(flags, (std::vector<bool>{true, true, false, true}));
}

TEST_P(SessionStoreTest, EveryFieldRoundTripsThroughTheColumns) {
  auto store = this->open();
  for (uint64_t seed : {1u, 2u, 3u, 20240611u, 0xdeadbeefu}) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    std::mt19937_64 rng(seed);
    const uint64_t id = store->createSession(info("alice"));
    std::vector<Sample> batch;
    std::vector<uint8_t> valid;
    for (int i = 0; i < 50; ++i) {
      Sample s = randomSample(rng);
      s.session_id = id;
      s.seq = static_cast<uint64_t>(i) * 1000 + (rng() % 1000);  // distinct, in order
      batch.push_back(s);
      valid.push_back(static_cast<uint8_t>(rng() % 2));
    }
    // The first half alone, then all of it: the second half arrives beside samples stored
    // already (a resend), which PgStore stores by another path than a fresh batch.
    const std::size_t half = batch.size() / 2;
    ASSERT_EQ(store->appendSamples(id, std::span(batch).first(half), std::span(valid).first(half)),
              half);
    ASSERT_EQ(store->appendSamples(id, batch, valid), batch.size() - half);
    std::size_t n = 0;
    store->forEachSample(id, [&](const Sample& got, bool ok) {
      ASSERT_LT(n, batch.size());
      expectSameSample(got, batch[n]);
      EXPECT_EQ(ok, valid[n] != 0);
      ++n;
    });
    EXPECT_EQ(n, batch.size());
  }
}

TEST_P(SessionStoreTest, NonFiniteValuesRoundTrip) {
  auto store = this->open();
  const uint64_t id = store->createSession(info("alice"));
  Sample s = sample(id, 1);
  const double inf = std::numeric_limits<double>::infinity();
  s.mcp_angles_rad[0] = std::nan("");
  s.mcp_angles_rad[1] = inf;
  s.mcp_torque_nm[2] = -inf;
  s.fingers[1].fsr_n[2] = std::numeric_limits<float>::quiet_NaN();
  s.fingers[0].normal_n = -std::numeric_limits<float>::infinity();
  s.passivity_damping = std::numeric_limits<float>::quiet_NaN();
  const uint8_t invalid = 0;
  store->appendSamples(id, {&s, 1}, {&invalid, 1});
  int n = 0;
  store->forEachSample(id, [&](const Sample& got, bool ok) {
    ++n;
    EXPECT_FALSE(ok);
    expectSameSample(got, s);
  });
  EXPECT_EQ(n, 1);
}

TEST_P(SessionStoreTest, ALargeBatchAndALongRecordComeBackWhole) {
  // More than one statement's and one read page's worth (PgStore: 8192 each).
  auto store = this->open();
  const uint64_t id = store->createSession(info("alice"));
  const auto batch = samples(id, 0, 20'000);
  EXPECT_EQ(store->appendSamples(id, batch, {}), 20'000u);
  EXPECT_EQ(store->appendSamples(id, samples(id, 19'990, 20'010), {}), 10u);
  uint64_t next = 0, wrong = 0;
  store->forEachSample(id, [&](const Sample& s, bool valid) {
    wrong += s.seq != next || !valid || s.source_time_ns != sample(id, next).source_time_ns;
    ++next;
  });
  EXPECT_EQ(next, 20'010u);
  EXPECT_EQ(wrong, 0u);
  std::vector<uint64_t> window;
  store->forEachSampleIn(id, 8190, 8194, [&](const Sample& s, bool) { window.push_back(s.seq); });
  EXPECT_EQ(window, (std::vector<uint64_t>{8190, 8191, 8192, 8193, 8194}));
  EXPECT_EQ(store->countSamples(id, 0, UINT64_MAX), 20'010u);
}

TEST_P(SessionStoreTest, TheNextStoredSequenceNumberStepsOverAGap) {
  auto store = this->open();
  const uint64_t id = store->createSession(info("alice"));
  const uint64_t other = store->createSession(info("bob"));
  store->appendSamples(id, samples(id, 0, 10), {});
  store->appendSamples(id, samples(id, uint64_t{1} << 62, (uint64_t{1} << 62) + 2), {});
  store->appendSamples(other, samples(other, 20, 30), {});
  EXPECT_EQ(store->nextStoredSeq(id, 0), 0u);
  EXPECT_EQ(store->nextStoredSeq(id, 9), 9u);
  EXPECT_EQ(store->nextStoredSeq(id, 10), uint64_t{1} << 62) << "not the other session's 20";
  EXPECT_EQ(store->nextStoredSeq(id, (uint64_t{1} << 62) + 1), (uint64_t{1} << 62) + 1);
  EXPECT_EQ(store->nextStoredSeq(id, (uint64_t{1} << 62) + 2), std::nullopt);
  EXPECT_EQ(store->nextStoredSeq(id, UINT64_MAX), std::nullopt);
  EXPECT_EQ(store->nextStoredSeq(other + 1, 0), std::nullopt);
}

TEST_P(SessionStoreTest, TheCallbackMayUseTheStore) {
  auto store = this->open();
  const uint64_t id = store->createSession(info("alice"));
  store->appendSamples(id, samples(id, 0, 10), {});
  int n = 0;
  store->forEachSample(id, [&](const Sample& s, bool) {
    ++n;
    if (s.seq == 4) {
      EXPECT_EQ(store->session(id)->samples, 10u);
      EXPECT_EQ(store->countSamples(id, 0, 4), 5u);
    }
  });
  EXPECT_EQ(n, 10);
}

TEST_P(SessionStoreTest, EventsInInsertionOrder) {
  auto store = this->open();
  const uint64_t id = store->createSession(info("alice"));
  store->appendEvent(id, {200, "mark", "second, but earlier id"});
  store->appendEvent(id, {100, "feedback", "more force"});
  store->appendEvent(id + 1, {150, "mark", "other session"});
  const auto ev = store->events(id);
  ASSERT_EQ(ev.size(), 2u);
  EXPECT_EQ(ev[0].time_ns, 200);
  EXPECT_EQ(ev[0].kind, "mark");
  EXPECT_EQ(ev[0].text, "second, but earlier id");
  EXPECT_EQ(ev[1].text, "more force");
}

TEST_P(SessionStoreTest, ReachesInInsertionOrder) {
  auto store = this->open();
  const uint64_t id = store->createSession(info("alice"));
  store->appendReach(id, {"baseline", "flexion", 61.5, 11.25});
  store->appendReach(id, {"baseline", "extension", -20.0, 3.5});
  store->appendReach(id + 1, {"baseline", "flexion", 1.0, 1.0});
  store->appendReach(id, {"reassessment", "flexion", 64.0, 11.0});
  const auto r = store->reaches(id);
  ASSERT_EQ(r.size(), 3u);
  EXPECT_EQ(r[0].direction, "flexion");
  EXPECT_DOUBLE_EQ(r[0].angle_deg, 61.5);
  EXPECT_DOUBLE_EQ(r[0].force_n, 11.25);
  EXPECT_EQ(r[1].direction, "extension");
  EXPECT_EQ(r[2].phase, "reassessment");
  EXPECT_TRUE(store->reaches(id + 2).empty());
}

TEST_P(SessionStoreTest, FilesAreKeptByNameAndReplaced) {
  auto store = this->open();
  const uint64_t id = store->createSession(info("alice"));
  const std::string binary("\x00\x01\xff\n\x00z", 6);
  store->appendFile(id, {"thimbles.toml", "first"});
  store->appendFile(id, {"device.bin", binary});
  store->appendFile(id, {"thimbles.toml", "second"});
  const auto f = store->files(id);
  ASSERT_EQ(f.size(), 2u);
  EXPECT_EQ(f[0].name, "device.bin");
  EXPECT_EQ(f[0].content, binary);
  EXPECT_EQ(f[1].name, "thimbles.toml");
  EXPECT_EQ(f[1].content, "second");
  EXPECT_TRUE(store->files(id + 1).empty());
}

TEST_P(SessionStoreTest, CloseRecordsEndExpectedAndState) {
  auto store = this->open();
  const uint64_t id = store->createSession(info("alice"));
  store->appendSamples(id, samples(id, 0, 8), {});
  store->closeSession(id, 1'700'000'100'000'000'000, 10, "closed");
  const auto s = store->session(id);
  ASSERT_TRUE(s);
  EXPECT_EQ(s->state, "closed");
  EXPECT_EQ(s->ended_ns, 1'700'000'100'000'000'000);
  EXPECT_EQ(s->samples_expected, 10u);
  EXPECT_EQ(s->samples, 8u) << "two samples never arrived";
}

TEST_P(SessionStoreTest, RowsPastWhatWasSentAreNotCountedAgainstTheMissingOnes) {
  // 0-5 and 8-11 stored, 10 said sent: 6 and 7 are missing, whatever arrived past 9.
  auto store = this->open();
  const uint64_t id = store->createSession(info("alice"));
  store->appendSamples(id, samples(id, 0, 6), {});
  store->appendSamples(id, samples(id, 8, 12), {});
  store->closeSession(id, 1'700'000'100'000'000'000, 10, "incomplete");
  auto s = store->session(id);
  ASSERT_TRUE(s);
  EXPECT_EQ(s->samples, 10u);
  EXPECT_EQ(s->samples_below_expected, 8u);
  EXPECT_EQ(s->missing(), 2u);
  const auto listed = store->listSessions();
  ASSERT_EQ(listed.size(), 1u);
  EXPECT_EQ(listed[0].missing(), 2u) << "the list says what the session says";
  // Not closed yet (nothing said sent): nothing counted missing, nothing below.
  const uint64_t open_id = store->createSession(info("bob"));
  store->appendSamples(open_id, samples(open_id, 0, 3), {});
  s = store->session(open_id);
  ASSERT_TRUE(s);
  EXPECT_EQ(s->samples_below_expected, 0u);
  EXPECT_EQ(s->missing(), 0u);
}

TEST_P(SessionStoreTest, ListIsOrderedById) {
  auto store = this->open();
  const uint64_t a = store->createSession(info("alice"));
  const uint64_t b = store->createSession(info("bob"));
  store->appendSamples(b, samples(b, 0, 3), {});
  store->closeSession(a, 5, 0, "abandoned");
  const auto list = store->listSessions();
  ASSERT_EQ(list.size(), 2u);
  EXPECT_EQ(list[0].id, a);
  EXPECT_EQ(list[0].user, "alice");
  EXPECT_EQ(list[0].state, "abandoned");
  EXPECT_EQ(list[1].id, b);
  EXPECT_EQ(list[1].samples, 3u);
  EXPECT_EQ(list[1].state, "active");
}

TEST_P(SessionStoreTest, SessionsKeepTheirOwner) {
  auto store = this->open();
  SessionInfo a = info("alice");
  a.owner = "0110ab12cd34ef56:0000001c:00000001 (device)";
  const uint64_t ida = store->createSession(a);
  const uint64_t idb = store->createSession(info("bob"));
  EXPECT_EQ(store->session(ida)->owner, a.owner);
  EXPECT_EQ(store->session(idb)->owner, "");
  EXPECT_EQ(store->listSessions().front().owner, a.owner);
}

TEST_P(SessionStoreTest, ReaderSeesWhatTheWriterStoredWhileItIsOpen) {
  auto writer = this->open();
  const uint64_t id = writer->createSession(info("alice"));
  writer->appendSamples(id, samples(id, 0, 5), {});
  auto reader = this->open(Mode::kReadOnly);
  EXPECT_EQ(reader->session(id)->samples, 5u);
  writer->appendSamples(id, samples(id, 5, 9), {});
  EXPECT_EQ(reader->session(id)->samples, 9u);
  EXPECT_EQ(seqsOf(*reader, id).back(), 8u);
  EXPECT_THROW(reader->createSession(info("mallory")), StoreError) << "read-only";
  EXPECT_THROW(reader->appendSamples(id, samples(id, 9, 10), {}), StoreError) << "read-only";
  EXPECT_EQ(writer->session(id)->samples, 9u);
}

TEST_P(SessionStoreTest, AReadOnlyOpenOfNothingIsRefusedAndCreatesNothing) {
  try {
    this->open(Mode::kReadOnly);
    FAIL() << "opened a record that is not there";
  } catch (const StoreError& e) {
    EXPECT_THAT(e.what(), HasSubstr(describeStore(this->spec())));
  }
  // Nothing was made: a writer still finds it empty and makes the schema.
  auto store = this->open();
  EXPECT_TRUE(store->listSessions().empty());
  EXPECT_EQ(store->createSession(info("alice")), 1u);
}

TEST_P(SessionStoreTest, LessonsTrialsAndSampleRanges) {
  auto store = this->open();
  const uint64_t demo = store->createSession(info("alice"));
  LessonInfo l;
  l.name = "demo";
  l.demo_session = demo;
  l.case_name = "stiff";
  l.schedule = "faded";
  l.guided = 3;
  l.attempts = 4;
  l.trial_s = 6.5;
  l.assessment = false;
  l.targets = "band_min_n=12;";
  l.created_ns = 1'700'000'000'123'456'789;
  const uint64_t id = store->createLesson(l);
  const auto back = store->lesson(id);
  ASSERT_TRUE(back.has_value());
  EXPECT_EQ(back->name, "demo");
  EXPECT_EQ(back->demo_session, demo);
  EXPECT_EQ(back->case_name, "stiff");
  EXPECT_EQ(back->technique, "mobilization");
  EXPECT_EQ(back->schedule, "faded");
  EXPECT_EQ(back->guided, 3);
  EXPECT_EQ(back->attempts, 4);
  EXPECT_DOUBLE_EQ(back->trial_s, 6.5);
  EXPECT_FALSE(back->assessment);
  EXPECT_FALSE(back->takeover);
  EXPECT_EQ(back->targets, "band_min_n=12;");
  EXPECT_EQ(back->created_ns, l.created_ns);
  EXPECT_FALSE(store->lesson(id + 1).has_value());
  EXPECT_EQ(store->listLessons().size(), 1u);
  const uint64_t run = store->createSession(info("bob"));
  EXPECT_EQ(store->sessionLesson(run), 0u);
  store->setSessionLesson(run, id + 7);
  store->setSessionLesson(run, id);  // replaced
  EXPECT_EQ(store->sessionLesson(run), id);
  TrialRecord t;
  t.session_id = run;
  t.index = 2;
  t.phase = "attempt";
  t.first_seq = 100;
  t.last_seq = 4099;
  t.overall = 71.5;
  t.figures = "missing=0;";
  store->appendTrial(t);
  t.index = 1;
  t.phase = "guided";
  t.authority = 1.0;
  store->appendTrial(t);
  t.overall = 80.0;  // the same trial scored again: replaced
  store->appendTrial(t);
  const auto trials = store->trials(run);
  ASSERT_EQ(trials.size(), 2u);
  EXPECT_EQ(trials[0].phase, "guided") << "in the order they ran";
  EXPECT_DOUBLE_EQ(trials[0].authority, 1.0);
  EXPECT_DOUBLE_EQ(trials[0].overall, 80.0);
  EXPECT_EQ(trials[1].last_seq, 4099u);
  EXPECT_EQ(trials[1].figures, "missing=0;");
  EXPECT_TRUE(store->trials(demo).empty());
  // Samples by range, in order.
  store->appendSamples(run, samples(run, 0, 50), {});
  std::vector<uint64_t> seqs;
  store->forEachSampleIn(run, 10, 14, [&](const Sample& s, bool) { seqs.push_back(s.seq); });
  EXPECT_EQ(seqs, (std::vector<uint64_t>{10, 11, 12, 13, 14}));
  EXPECT_EQ(store->countSamples(run, 10, 14), 5u);
  EXPECT_EQ(store->countSamples(run, 40, UINT64_MAX), 10u);
  const auto ext = store->extent(run);
  ASSERT_TRUE(ext.has_value());
  EXPECT_EQ(ext->first_seq, 0u);
  EXPECT_EQ(ext->last_seq, 49u);
  EXPECT_EQ(ext->first_time_ns, sample(run, 0).source_time_ns);
  EXPECT_EQ(ext->last_time_ns, sample(run, 49).source_time_ns);
  EXPECT_FALSE(store->extent(run + 100).has_value());
}

TEST_P(SessionStoreTest, LessonsRememberWhetherATakeOverIsAllowed) {
  auto store = this->open();
  LessonInfo l;
  l.name = "without";
  l.demo_session = 1;
  l.case_name = "healthy";
  const uint64_t without = store->createLesson(l);
  l.name = "with";
  l.takeover = true;
  const uint64_t with = store->createLesson(l);
  EXPECT_FALSE(store->lesson(without)->takeover);
  EXPECT_TRUE(store->lesson(with)->takeover);
  EXPECT_EQ(store->listLessons().back().name, "with");
}

TEST_P(SessionStoreTest, RefusesANewerSchemaNamingTheRecord) {
  uint64_t id = 0;
  {
    auto store = this->open();
    id = store->createSession(info("alice"));
    store->appendSamples(id, samples(id, 0, 10), {});
  }
  this->backend_->setSchemaVersion(8);
  for (auto mode : {Mode::kReadWrite, Mode::kReadOnly}) {
    try {
      this->open(mode);
      FAIL() << "opened a newer schema";
    } catch (const StoreError& e) {
      EXPECT_THAT(e.what(), HasSubstr(describeStore(this->spec())));
      EXPECT_THAT(
          e.what(),
          HasSubstr("was written by a newer telehand (schema 8, this program knows up to 7)"));
    }
  }
  this->backend_->setSchemaVersion(5);
  EXPECT_EQ(this->open(Mode::kReadOnly)->session(id)->samples, 10u) << "left untouched";
}

TEST_P(SessionStoreTest, RefusesForeignTablesNamingTheRecord) {
  this->backend_->addForeignTable();
  for (auto mode : {Mode::kReadWrite, Mode::kReadOnly}) {
    try {
      this->open(mode);
      FAIL() << "opened another program's tables as a record";
    } catch (const StoreError& e) {
      EXPECT_THAT(e.what(), HasSubstr(describeStore(this->spec())));
      EXPECT_THAT(e.what(), HasSubstr("is not a telehand record database"));
      EXPECT_THAT(e.what(), HasSubstr("inventory"));
    }
  }
}

}  // namespace
}  // namespace telehand::server::store
