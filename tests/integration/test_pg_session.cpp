// A session recorded into PostgreSQL by a real telehand-server (--db postgresql://...), read
// back by telehand-records from PostgreSQL, and the same record copied into SQLite and
// exported from there: the two CSVs are the same, row for row. The cluster is a throw-away
// one of this test process (tests/support/pg_cluster.h); DDS runs on a domain and partition
// of the test's own.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "../support/pg_cluster.h"
#include "process.h"
#include "process_test.h"
#include "telehand/server/store/pg_store.h"
#include "telehand/server/store/sqlite_store.h"

namespace telehand::test {
namespace {

using namespace std::chrono_literals;

class PgSessionTest : public ProcessTest {
 protected:
  PgSessionTest() : ProcessTest("itpg", TELEHAND_LOOPBACK_XML) {}
};

std::vector<std::string> lines(const std::string& path) {
  std::ifstream in(path);
  std::vector<std::string> out;
  for (std::string l; std::getline(in, l);) out.push_back(l);
  return out;
}

TEST_F(PgSessionTest, TheServerRecordsIntoPostgresqlAndTheRecordReadsTheSameAsSqlite) {
  const auto shared = sharedPgCluster();
  if (!shared.skip.empty()) GTEST_SKIP() << shared.skip;
  ASSERT_TRUE(shared.error.empty()) << shared.error;
  useOwnDomain();
  const std::string schema = "it_" + std::to_string(getpid());
  shared.cluster->exec("CREATE SCHEMA " + schema, "telehand");
  // The cluster trusts local connections: the password is sent for nothing, and must never
  // be shown.
  const std::string secret = "s3cret-never-shown";
  const std::string uri = "postgresql://telehand:" + secret +
                          "@/telehand?host=" + shared.cluster->dir() + "&options=-csearch_path%3D" +
                          schema;

  Process server(cmd(TELEHAND_SERVER_BIN, {"--db", uri, "--seconds", "60"}), path("server.log"));
  Process client(cmd(TELEHAND_CLIENT_BIN, {"--seconds", "3", "-q"}), path("client.log"));
  const auto client_rc = client.wait(30s);
  ASSERT_TRUE(client_rc.has_value()) << "client did not finish\n" << client.output();
  EXPECT_EQ(*client_rc, 0) << client.output() << server.output();
  EXPECT_EQ(server.stop(), 0) << server.output();
  const uint64_t session = matchNumber(client.output(), R"(session (\d+) open)");
  const uint64_t sent = matchNumber(client.output(), R"((\d+) samples sent)");
  ASSERT_GT(session, 0u) << client.output();
  ASSERT_GT(sent, 2000u) << client.output();  // 3 s at 1 kHz
  EXPECT_NE(server.output().find("postgresql://telehand:***@"), std::string::npos)
      << server.output();

  // telehand-records reads the record from PostgreSQL: closed, nothing missing.
  Process list({TELEHAND_RECORDS_BIN, "--db", uri, "list"}, path("list.log"));
  ASSERT_EQ(list.wait(30s), 0) << list.output();
  std::string row;
  for (const auto& l : lines(path("list.log"))) {
    if (l.rfind(std::to_string(session) + " ", 0) == 0) row = l;
  }
  ASSERT_FALSE(row.empty()) << list.output();
  std::istringstream fields(row);
  std::vector<std::string> f;
  for (std::string w; fields >> w;) f.push_back(w);
  EXPECT_NE(std::find(f.begin(), f.end(), "closed"), f.end()) << row;
  EXPECT_EQ(f.back(), "0") << "missing: " << row;
  EXPECT_EQ(f[f.size() - 2], std::to_string(sent)) << "samples: " << row;
  Process pg_export(
      {TELEHAND_RECORDS_BIN, "--db", uri, "export", std::to_string(session), "-o", path("pg.csv")},
      path("pg-export.log"));
  ASSERT_EQ(pg_export.wait(60s), 0) << pg_export.output();

  // The store's own reading: every sample, in order, once, valid; the session closed and
  // complete. The same record copied into SQLite.
  server::store::PgStore store(uri, server::store::SessionStore::Mode::kReadOnly);
  const auto info = store.session(session);
  ASSERT_TRUE(info.has_value());
  EXPECT_EQ(info->state, "closed");
  EXPECT_EQ(info->samples, sent);
  EXPECT_EQ(info->samples_expected, sent);
  EXPECT_EQ(info->rejected, 0u);
  std::vector<Sample> record;
  std::vector<uint8_t> valid;
  std::vector<std::string> want = {""};
  for (const auto& c : server::store::sampleColumns()) want[0] += (want[0].empty() ? "" : ",") + c;
  uint64_t next = 0, gaps = 0;
  store.forEachSample(session, [&](const Sample& s, bool ok) {
    gaps += s.seq != next;
    next = s.seq + 1;
    record.push_back(s);
    valid.push_back(ok ? 1 : 0);
    want.push_back(server::store::sampleCsvRow(s, ok));
  });
  EXPECT_EQ(gaps, 0u);
  EXPECT_EQ(next, sent);
  uint64_t copy_id = 0;
  {
    server::store::SqliteStore copy(path("copy.db"));
    copy_id = copy.createSession(*info);
    EXPECT_EQ(copy.appendSamples(copy_id, record, valid), sent);
    copy.closeSession(copy_id, info->ended_ns, info->samples_expected, info->state);
  }
  Process sqlite_export({TELEHAND_RECORDS_BIN, "--db", path("copy.db"), "export",
                         std::to_string(copy_id), "-o", path("sqlite.csv")},
                        path("sqlite-export.log"));
  ASSERT_EQ(sqlite_export.wait(60s), 0) << sqlite_export.output();

  const auto pg_csv = lines(path("pg.csv"));
  const auto sqlite_csv = lines(path("sqlite.csv"));
  ASSERT_EQ(pg_csv.size(), sent + 1);
  EXPECT_EQ(pg_csv, want) << "the export is the store's record, row for row";
  EXPECT_EQ(pg_csv, sqlite_csv) << "PostgreSQL and SQLite export the same record alike";

  for (const auto* p : {&server, &list, &pg_export}) {
    EXPECT_EQ(p->output().find(secret), std::string::npos) << p->output();
  }
  shared.cluster->exec("DROP SCHEMA " + schema + " CASCADE", "telehand");
}

}  // namespace
}  // namespace telehand::test
