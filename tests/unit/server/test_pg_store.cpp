// What only the PostgreSQL store does: its schema marker and columns, refusal of what is not
// a telehand record (left untouched), two programs creating the schema at once, writers on
// two connections at once, a server that goes away and comes back, and URIs (bad ones named,
// passwords never shown). What every store does is test_store_contract.cpp's.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "../../support/pg_cluster.h"
#include "store_samples.h"
#include "telehand/core/error.h"
#include "telehand/server/store/open_store.h"
#include "telehand/server/store/pg_store.h"
#include "telehand/server/store/sqlite_store.h"

namespace telehand::server::store {
namespace {

using ::testing::HasSubstr;
using ::testing::Not;
using namespace store_test;
using Mode = SessionStore::Mode;

/// A fresh schema in the test process's cluster per test, dropped afterwards.
class PgStoreTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto shared = test::sharedPgCluster();
    if (!shared.skip.empty()) GTEST_SKIP() << shared.skip;
    if (!shared.error.empty()) FAIL() << shared.error;
    cluster_ = shared.cluster;
    static std::atomic<int> counter{0};
    schema_ = "pgstore_" + std::to_string(::getpid()) + "_" + std::to_string(counter++);
    sql("CREATE SCHEMA " + schema_);
  }
  void TearDown() override {
    if (cluster_) sql("DROP SCHEMA IF EXISTS " + schema_ + " CASCADE");
  }
  std::string uri() const { return cluster_->uri("telehand", schema_); }
  void sql(const std::string& s) const { cluster_->exec(s, "telehand"); }
  std::string value(const std::string& s) const { return cluster_->value(s, "telehand"); }
  std::string table(const std::string& t) const { return schema_ + "." + t; }

  test::PgCluster* cluster_ = nullptr;
  std::string schema_;
};

TEST_F(PgStoreTest, TheSchemaIsMarkedAndHasTheSqliteColumns) {
  { PgStore store(uri()); }
  EXPECT_EQ(value("SELECT application_id FROM " + table("telehand_schema")),
            std::to_string(0x54484E44));
  EXPECT_EQ(value("SELECT version FROM " + table("telehand_schema")), "7");
  EXPECT_EQ(value("SELECT count(*) FROM " + table("telehand_schema")), "1");
  EXPECT_THAT(value("SELECT obj_description('" + table("telehand_schema") + "'::regclass)"),
              HasSubstr("telehand session records, schema 7"));
  std::string want = "session_id";
  for (const auto& c : sampleColumns()) want += "," + c;
  EXPECT_EQ(value("SELECT string_agg(column_name, ',' ORDER BY ordinal_position) FROM "
                  "information_schema.columns WHERE table_schema = '" +
                  schema_ + "' AND table_name = 'samples'"),
            want);
  EXPECT_EQ(value("SELECT data_type FROM information_schema.columns WHERE table_schema = '" +
                  schema_ + "' AND table_name = 'samples' AND column_name = 'thumb_fsr1_n'"),
            "real");
  EXPECT_EQ(value("SELECT data_type FROM information_schema.columns WHERE table_schema = '" +
                  schema_ + "' AND table_name = 'samples' AND column_name = 'thumb_px_m'"),
            "double precision");
  EXPECT_EQ(value("SELECT data_type FROM information_schema.columns WHERE table_schema = '" +
                  schema_ + "' AND table_name = 'samples' AND column_name = 'flags'"),
            "bigint");
  // Opening again finds it current and changes nothing.
  { PgStore again(uri()); }
  EXPECT_EQ(value("SELECT count(*) FROM " + table("telehand_schema")), "1");
}

TEST_F(PgStoreTest, NanIsKeptAsNullAsInSqlite) {
  PgStore store(uri());
  const uint64_t id = store.createSession(info("alice"));
  Sample s = sample(id, 0);
  s.mcp_angles_rad[1] = std::nan("");
  s.mcp_torque_nm[0] = std::numeric_limits<double>::infinity();
  store.appendSamples(id, {&s, 1}, {});
  EXPECT_EQ(value("SELECT count(*) FROM " + table("samples") + " WHERE beta_rad IS NULL"), "1");
  EXPECT_EQ(value("SELECT tau_alpha_nm FROM " + table("samples")), "Infinity");
}

TEST_F(PgStoreTest, RefusesANewerSchemaAndLeavesItUntouched) {
  {
    PgStore store(uri());
    const uint64_t id = store.createSession(info("alice"));
    store.appendSamples(id, samples(id, 0, 10), {});
  }
  sql("UPDATE " + table("telehand_schema") + " SET version = 9");
  for (auto mode : {Mode::kReadWrite, Mode::kReadOnly}) {
    try {
      PgStore store(uri(), mode);
      FAIL() << "opened a newer schema";
    } catch (const StoreError& e) {
      EXPECT_THAT(e.what(), HasSubstr(uri()));
      EXPECT_THAT(e.what(), HasSubstr("was written by a newer telehand (schema 9, this program "
                                      "knows up to 7); it was left untouched"));
    }
  }
  EXPECT_EQ(value("SELECT version FROM " + table("telehand_schema")), "9");
  EXPECT_EQ(value("SELECT count(*) FROM " + table("samples")), "10");
}

TEST_F(PgStoreTest, RefusesAnotherProgramsTablesAndLeavesThemUntouched) {
  sql("CREATE TABLE " + table("samples") + " (x INTEGER); INSERT INTO " + table("samples") +
      " VALUES (42)");
  for (auto mode : {Mode::kReadWrite, Mode::kReadOnly}) {
    try {
      PgStore store(uri(), mode);
      FAIL() << "opened a foreign schema";
    } catch (const StoreError& e) {
      EXPECT_THAT(e.what(), HasSubstr(uri()));
      EXPECT_THAT(e.what(), HasSubstr("is not a telehand record database (schema '" + schema_ +
                                      "' holds samples; no telehand_schema table)"));
    }
  }
  EXPECT_EQ(value("SELECT x FROM " + table("samples")), "42");
  EXPECT_EQ(value("SELECT count(*) FROM pg_tables WHERE schemaname = '" + schema_ + "'"), "1")
      << "nothing created beside it";
}

// Schema 5 (before the pool): a reader reads it as it is, a writer adds the pool's tables.
TEST_F(PgStoreTest, ASchema5RecordGainsThePoolTables) {
  uint64_t id = 0;
  {
    PgStore store(uri());
    id = store.createSession({});
  }
  sql("DROP TABLE " + table("pool_servers") + ", " + table("session_owners") + ", " +
      table("pool_opens") + ", " + table("checkpoints"));
  sql("UPDATE " + table("telehand_schema") + " SET version = 5");
  {
    PgStore reader(uri(), SessionStore::Mode::kReadOnly);
    EXPECT_TRUE(reader.session(id).has_value());
    EXPECT_EQ(reader.poolOwner(id), "");
    EXPECT_FALSE(reader.checkpoint(id).has_value());
    EXPECT_EQ(value("SELECT version FROM " + table("telehand_schema")), "5")
        << "a reader changes nothing";
  }
  PgStore store(uri());
  EXPECT_EQ(value("SELECT version FROM " + table("telehand_schema")), "7");
  EXPECT_TRUE(store.poolClaim(id, "a").won);
  EXPECT_EQ(store.poolOwner(id), "a");
}

// A pool member whose process died: its connection closes, and with it its member lock; the
// others take its sessions over at once, not when its lease runs out. A member alive keeps
// them, and a store trusts the others' connections only once its own has lasted a lease.
TEST_F(PgStoreTest, APoolMemberWhoseConnectionClosedIsGoneBeforeItsLeaseRunsOut) {
  using namespace std::chrono_literals;
  constexpr int64_t kMinute = 60'000'000'000;
  constexpr int64_t kShort = 300'000'000;
  auto a = std::make_unique<PgStore>(uri());
  PgStore b(uri());
  // Short leases first (the trust in connections starts a lease after the lock), then long.
  a->poolHeartbeat("a", 0, kShort);
  b.poolHeartbeat("b", 0, kShort);
  std::this_thread::sleep_for(350ms);
  a->poolHeartbeat("a", 0, kMinute);
  b.poolHeartbeat("b", 0, kMinute);
  const uint64_t id = a->createSession({});
  ASSERT_TRUE(a->poolClaim(id, "a").won);
  EXPECT_TRUE(b.poolOrphans().empty());
  EXPECT_FALSE(b.poolClaim(id, "b").won) << "a's lease runs and its connection is there";
  EXPECT_EQ(b.poolMembers().size(), 2u);
  // A third store, still new: it trusts nobody's connection yet, only leases.
  PgStore c(uri());
  c.poolHeartbeat("c", 0, kMinute);

  a.reset();  // the process dies: its connection closes (the lease would run a minute more)
  std::vector<uint64_t> orphans;
  for (int i = 0; i < 100 && orphans.empty(); ++i) {  // the backend ends within moments
    orphans = b.poolOrphans();
    if (orphans.empty()) std::this_thread::sleep_for(20ms);
  }
  EXPECT_EQ(orphans, std::vector<uint64_t>{id});
  EXPECT_TRUE(c.poolOrphans().empty()) << "c's own connection has not lasted a lease";
  EXPECT_FALSE(c.poolClaim(id, "c").won);
  const auto members = b.poolMembers();
  ASSERT_EQ(members.size(), 2u) << "a is not assigned OPENs any more";
  EXPECT_NE(members[0].server, "a");
  EXPECT_NE(members[1].server, "a");
  const PoolClaim taken = b.poolClaim(id, "b");
  EXPECT_TRUE(taken.won);
  EXPECT_EQ(taken.previous, "a");
  EXPECT_FALSE(taken.previous_connected);
  EXPECT_GT(taken.previous_lease_until_ns, taken.now_ns) << "before a's lease ran out";
  EXPECT_EQ(b.poolOwner(id), "b");

  // A member that leaves lets go of its lock: another process may take the name.
  b.poolLeave("b");
  PgStore b2(uri());
  b2.poolHeartbeat("b", 0, kMinute);
  EXPECT_EQ(value("SELECT count(*) FROM pg_locks WHERE locktype = 'advisory' AND objsubid = 2 "
                  "AND granted AND objid::bigint = (hashtext('b')::bigint & 4294967295) AND "
                  "classid::bigint = (hashtext('telehand-pool:" +
                  schema_ + "')::bigint & 4294967295)"),
            "1");
}

// Schema 6 (before the massage's web columns): a reader reads the web as 0, a writer adds them.
TEST_F(PgStoreTest, ASchema6RecordGainsTheWebColumns) {
  uint64_t id = 0;
  std::vector<Sample> v(3);
  {
    PgStore store(uri());
    id = store.createSession({});
    for (uint64_t i = 0; i < v.size(); ++i) {
      v[i].session_id = id;
      v[i].seq = i;
    }
    store.appendSamples(id, v, {});
  }
  std::string drop;
  for (const std::string f : {"thumb", "index"}) {
    drop += "ALTER TABLE " + table("samples") + " DROP COLUMN " + f + "_depth_m;";
    for (const char* c : {"x", "y", "z"})
      drop += "ALTER TABLE " + table("samples") + " DROP COLUMN " + f + "_tissue" + c + "_n;";
  }
  sql(drop);
  sql("UPDATE " + table("telehand_schema") + " SET version = 6");
  {
    PgStore reader(uri(), SessionStore::Mode::kReadOnly);
    int n = 0;
    reader.forEachSample(id, [&](const Sample& s, bool) {
      EXPECT_EQ(s.fingers[0].contact_depth_m, 0.0);
      ++n;
    });
    EXPECT_EQ(n, 3);
    EXPECT_EQ(value("SELECT version FROM " + table("telehand_schema")), "6");
  }
  PgStore store(uri());
  EXPECT_EQ(value("SELECT version FROM " + table("telehand_schema")), "7");
  Sample s;
  s.session_id = id;
  s.seq = 3;
  s.fingers[0].contact_depth_m = 0.004;
  s.fingers[1].tissue_force_n[2] = -9.5;
  store.appendSamples(id, std::vector<Sample>{s}, {});
  double depth = 0.0, fz = 0.0;
  store.forEachSample(id, [&](const Sample& x, bool) {
    depth += x.fingers[0].contact_depth_m;
    fz += x.fingers[1].tissue_force_n[2];
  });
  EXPECT_DOUBLE_EQ(depth, 0.004);
  EXPECT_DOUBLE_EQ(fz, -9.5);
}

TEST_F(PgStoreTest, RefusesAMarkerThatIsNotTelehandsOrLacksTheTables) {
  sql("CREATE TABLE " + table("telehand_schema") +
      " (application_id BIGINT NOT NULL, version INTEGER NOT NULL)");
  sql("INSERT INTO " + table("telehand_schema") + " VALUES (1234, 5)");
  try {
    PgStore store(uri());
    FAIL() << "opened a foreign marker";
  } catch (const StoreError& e) {
    EXPECT_THAT(e.what(), HasSubstr("is not a telehand record database"));
  }
  sql("UPDATE " + table("telehand_schema") + " SET application_id = " + std::to_string(0x54484E44));
  try {
    PgStore store(uri());
    FAIL() << "opened a marker without tables";
  } catch (const StoreError& e) {
    EXPECT_THAT(e.what(), HasSubstr(uri()));
    EXPECT_THAT(e.what(), HasSubstr("carries the telehand marker but schema 5 without the tables "
                                    "events, explorations"));
  }
  EXPECT_EQ(value("SELECT count(*) FROM pg_tables WHERE schemaname = '" + schema_ + "'"), "1");
}

TEST_F(PgStoreTest, AReadOnlyOpenOfAnEmptySchemaCreatesNothing) {
  EXPECT_THROW(PgStore(uri(), Mode::kReadOnly), StoreError);
  EXPECT_EQ(value("SELECT count(*) FROM pg_tables WHERE schemaname = '" + schema_ + "'"), "0");
}

TEST_F(PgStoreTest, TwoProgramsOpeningAnEmptySchemaAtOnceCreateItOnce) {
  std::vector<std::thread> openers;
  std::atomic<int> opened{0}, failed{0};
  for (int i = 0; i < 4; ++i) {
    openers.emplace_back([&] {
      try {
        PgStore store(uri());
        store.createSession(info("x"));
        ++opened;
      } catch (const std::exception& e) {
        ++failed;
        ADD_FAILURE() << e.what();
      }
    });
  }
  for (auto& t : openers) t.join();
  EXPECT_EQ(opened.load(), 4);
  EXPECT_EQ(failed.load(), 0);
  EXPECT_EQ(value("SELECT count(*) FROM " + table("telehand_schema")), "1");
  EXPECT_EQ(value("SELECT count(*) FROM " + table("sessions")), "4");
}

TEST_F(PgStoreTest, WritersOnTwoConnectionsAppendAtOnce) {
  // Two servers sharing the record: each writes its own sessions, chunk by chunk, with the
  // resends of a link that lost acknowledgements.
  PgStore a(uri()), b(uri());
  const uint64_t sa = a.createSession(info("alice"));
  const uint64_t sb = b.createSession(info("bob"));
  constexpr uint64_t kChunks = 40, kChunk = 100;
  auto write = [&](PgStore& store, uint64_t session, uint64_t& added) {
    for (uint64_t c = 0; c < kChunks; ++c) {
      added += store.appendSamples(session, samples(session, c * kChunk, (c + 1) * kChunk), {});
      if (c % 5 == 4) added += store.appendSamples(session, samples(session, 0, kChunk), {});
    }
  };
  uint64_t added_a = 0, added_b = 0;
  std::thread ta([&] { write(a, sa, added_a); });
  std::thread tb([&] { write(b, sb, added_b); });
  ta.join();
  tb.join();
  EXPECT_EQ(added_a, kChunks * kChunk);
  EXPECT_EQ(added_b, kChunks * kChunk);
  PgStore reader(uri(), Mode::kReadOnly);
  for (uint64_t s : {sa, sb}) {
    SCOPED_TRACE("session " + std::to_string(s));
    EXPECT_EQ(reader.session(s)->samples, kChunks * kChunk);
    uint64_t next = 0, gaps = 0;
    reader.forEachSample(s, [&](const Sample& got, bool) {
      gaps += got.seq != next;
      next = got.seq + 1;
      EXPECT_EQ(got.session_id, s);
    });
    EXPECT_EQ(gaps, 0u);
    EXPECT_EQ(next, kChunks * kChunk);
  }
}

TEST_F(PgStoreTest, AStoreReconnectsWhenTheServerIsBackAndLosesNothing) {
  PgStore store(uri());
  const uint64_t id = store.createSession(info("alice"));
  EXPECT_EQ(store.appendSamples(id, samples(id, 0, 100), {}), 100u);
  cluster_->stop();
  const auto batch = samples(id, 100, 200);
  // The lost connection, a failed attempt to connect again, then at once (no attempt).
  for (const char* want : {"lost the connection to record database",
                           "cannot connect to record "
                           "database",
                           "is unreachable"}) {
    try {
      store.appendSamples(id, batch, {});
      ADD_FAILURE() << "stored with the server down";
    } catch (const StoreError& e) {
      EXPECT_THAT(e.what(), HasSubstr(want));
      EXPECT_THAT(e.what(), HasSubstr(uri()));
    }
  }
  cluster_->start();
  // What the recorder kept is retried until the store takes it; what was stored before is
  // still there.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(15);
  uint64_t added = 0;
  bool stored = false;
  while (!stored && std::chrono::steady_clock::now() < deadline) {
    try {
      added = store.appendSamples(id, batch, {});
      stored = true;
    } catch (const StoreError&) {
      std::this_thread::sleep_for(std::chrono::milliseconds(200));
    }
  }
  ASSERT_TRUE(stored);
  EXPECT_EQ(added, 100u);
  EXPECT_EQ(store.session(id)->samples, 200u);
}

TEST_F(PgStoreTest, AnUnreachableServerIsNamedWithoutThePassword) {
  for (const std::string& bad :
       {std::string("postgresql://alice:s3cret@/telehand?host=/nonexistent/telehand-socket"),
        std::string("postgres://alice:s3cret@127.0.0.1:1/telehand?connect_timeout=3"),
        std::string("postgresql:///telehand?host=/nonexistent/x&user=alice&password=s3cret")}) {
    SCOPED_TRACE(describeStore(bad));
    try {
      openStore(bad, Mode::kReadOnly);
      ADD_FAILURE() << "connected";
    } catch (const StoreError& e) {
      EXPECT_THAT(e.what(),
                  HasSubstr("cannot connect to record database '" + describeStore(bad) + "'"));
      EXPECT_THAT(e.what(), Not(HasSubstr("s3cret")));
      EXPECT_THAT(e.what(), HasSubstr("***"));
    }
  }
}

TEST_F(PgStoreTest, AMissingDatabaseIsNamedAndSaysHowToMakeIt) {
  const std::string missing = cluster_->uri("no_such_records");
  try {
    PgStore store(missing);
    FAIL() << "connected";
  } catch (const StoreError& e) {
    EXPECT_THAT(e.what(), HasSubstr(missing));
    EXPECT_THAT(e.what(), HasSubstr("\"no_such_records\" does not exist"));
    EXPECT_THAT(e.what(), HasSubstr("createdb"));
  }
}

TEST(PgStoreUri, ABadUriIsNamedWithoutThePassword) {
  for (const std::string& bad : {std::string("postgresql://alice:s3cret@host:port/db"),
                                 std::string("postgresql://alice:s3cret@host/db?nonsense=1"),
                                 std::string("postgresql://alice:s3cret%zz@host/db"),
                                 std::string("postgresql://h/db?password=s3cret%zz")}) {
    try {
      openStore(bad);
      ADD_FAILURE() << "opened " << describeStore(bad);
    } catch (const StoreError& e) {
      // Malformed for libpq's parser, or for the connection that reads it.
      EXPECT_THAT(e.what(), HasSubstr("record database"));
      EXPECT_THAT(e.what(), HasSubstr("'" + describeStore(bad) + "'"));
      EXPECT_THAT(e.what(), Not(HasSubstr("s3cret")));
    }
  }
}

TEST(PgStoreUri, PasswordsAreRedacted) {
  EXPECT_EQ(redactUri("postgresql://alice:s3cret@db.example:5432/telehand"),
            "postgresql://alice:***@db.example:5432/telehand");
  EXPECT_EQ(redactUri("postgres://alice@db/telehand"), "postgres://alice@db/telehand");
  EXPECT_EQ(redactUri("postgresql://db/telehand?user=a&password=s3cret&sslmode=require"),
            "postgresql://db/telehand?user=a&password=***&sslmode=require");
  EXPECT_EQ(redactUri("postgresql:///telehand?host=/run/pg&sslpassword=k3y"),
            "postgresql:///telehand?host=/run/pg&sslpassword=***");
  EXPECT_EQ(redactUri("postgresql://a:b@h1:5432,h2:5433/x"),
            "postgresql://a:***@h1:5432,h2:5433/x");
  EXPECT_EQ(redactUri("postgresql://a:p@ss@h/x"), "postgresql://a:***@h/x");
  EXPECT_EQ(redactUri("postgresql://a:p?w@h"), "postgresql://a:***@h");
  EXPECT_EQ(describeStore("records/telehand.db"), "records/telehand.db");
  EXPECT_EQ(describeStore("postgresql://a:b@h/x"), "postgresql://a:***@h/x");
}

TEST(PgStoreUri, TheSpecPicksTheStore) {
  EXPECT_TRUE(isPostgresUri("postgresql://h/x"));
  EXPECT_TRUE(isPostgresUri("postgres://h/x"));
  EXPECT_FALSE(isPostgresUri("records/telehand.db"));
  EXPECT_FALSE(isPostgresUri("postgresql.db"));
  EXPECT_FALSE(isPostgresUri(":memory:"));
  auto sqlite = openStore(":memory:");
  EXPECT_NE(dynamic_cast<SqliteStore*>(sqlite.get()), nullptr);
}

}  // namespace
}  // namespace telehand::server::store
