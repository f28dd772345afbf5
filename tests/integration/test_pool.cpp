// A pool of three telehand-servers on one record (docs/pool.md), real processes over loopback
// DDS: twelve simulated MF-2 sessions are spread over the pool by the record's assignment (the
// least-loaded server takes each OPEN), the owner of four of them is killed (SIGKILL) in the
// middle, and the others take its sessions over from the record, each hand from its
// checkpoint. Every session ends closed with every sample its client sent, field for field
// (the client's digest of what it sent against the record's), and the record's owner events
// say who owned each session when. The same on an SQLite file the servers share and on
// PostgreSQL (a throw-away cluster, tests/support/pg_cluster.h).
#include <gtest/gtest.h>
#include <signal.h>
#include <unistd.h>

#include <fstream>
#include <map>
#include <memory>
#include <regex>
#include <thread>

#include "../support/pg_cluster.h"
#include "process.h"
#include "process_test.h"
#include "telehand/core/clock.h"
#include "telehand/server/store/open_store.h"

namespace telehand::test {
namespace {

using namespace std::chrono_literals;

class PoolTest : public ProcessTest, public ::testing::WithParamInterface<std::string> {
 protected:
  PoolTest() : ProcessTest("pool", TELEHAND_LOOPBACK_XML) {}

  static constexpr int kServers = 3;
  static constexpr int kSessions = 12;
  // The twelve clients stand for twelve machines elsewhere. On one small host at equal
  // priority their loops (about a tenth of a core each) starve the servers and the
  // database, whose take-over is what is measured: they yield the CPU to them.
  static constexpr int kClientNice = 10;

  std::vector<std::string> serverCmd(const std::string& db, int k) {
    {
      std::ofstream cfg(path("server.toml"));
      cfg << "[server]\nresume_wait_s = 60\n";
    }
    return cmd(TELEHAND_SERVER_BIN, {"--config", path("server.toml"), "--db", db, "--pool",
                                     "--pool-id", "s" + std::to_string(k), "--seconds", "150"});
  }

  static std::string await(Process& p, const std::string& pattern,
                           std::chrono::milliseconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    std::smatch m;
    while (std::chrono::steady_clock::now() < deadline) {
      const std::string out = p.output();
      if (std::regex_search(out, m, std::regex(pattern))) return m[1];
      std::this_thread::sleep_for(50ms);
    }
    return {};
  }

  void run(const std::string& db) {
    std::vector<std::unique_ptr<Process>> servers;
    for (int k = 1; k <= kServers; ++k) {
      servers.push_back(
          std::make_unique<Process>(serverCmd(db, k), path("server" + std::to_string(k) + ".log")));
      ASSERT_FALSE(await(*servers.back(), R"(serving as '(s\d)')", 30s).empty())
          << servers.back()->output();
    }
    std::vector<std::unique_ptr<Process>> clients;
    std::vector<uint64_t> ids;
    for (int i = 0; i < kSessions; ++i) {
      clients.push_back(std::make_unique<Process>(
          cmd(TELEHAND_CLIENT_BIN, {"--seconds", "30", "--connect-timeout", "30", "-q",
                                    "--no-fault-stop", "--seed", std::to_string(11 + i)}),
          path("client" + std::to_string(i) + ".log"), kClientNice));
      const std::string id = await(*clients.back(), R"(session (\d+) open)", 30s);
      ASSERT_FALSE(id.empty()) << clients.back()->output();
      ids.push_back(std::stoull(id));
    }
    // Who owns what, and whom each OPEN was assigned to (the session's first owner event):
    // the record's assignment spreads them evenly. A server whose lease ran out in a stall
    // on a loaded machine may have lost sessions to the others since (counted below).
    std::map<std::string, std::vector<uint64_t>> owned, assigned;
    {
      const auto store = server::store::openStore(db, server::store::SessionStore::Mode::kReadOnly);
      for (uint64_t id : ids) {
        owned[store->poolOwner(id)].push_back(id);
        for (const auto& e : store->events(id)) {
          if (e.text.rfind("owner: server ", 0) == 0) {
            assigned[e.text.substr(14)].push_back(id);
            break;
          }
        }
      }
    }
    // Evenly on an idle machine (4/4/4); a server stalled past its lease while OPENs came
    // is passed over for them (7/3/2 beside two background cases, 3 for 4 once at -j 2).
    // Every server takes OPENs, and none takes twice its share.
    ASSERT_EQ(assigned.size(), static_cast<std::size_t>(kServers));
    std::string spread;
    for (const auto& [server, sessions] : assigned)
      spread += server + ":" + std::to_string(sessions.size()) + " ";
    for (const auto& [server, sessions] : assigned) {
      EXPECT_GE(sessions.size(), 2u) << spread;
      EXPECT_LE(sessions.size(), static_cast<std::size_t>(2 * kSessions / kServers)) << spread;
    }
    std::this_thread::sleep_for(4s);
    const std::string victim = owned.begin()->first;
    const int v = victim.back() - '1';
    // The victim's sessions still open at the kill: on a loaded machine the OPENs can take
    // so long that the first sessions end before it.
    std::vector<uint64_t> victims;
    {
      const auto store = server::store::openStore(db, server::store::SessionStore::Mode::kReadOnly);
      for (uint64_t id : owned[victim]) {
        if (store->session(id)->state == "active") victims.push_back(id);
      }
    }
    ASSERT_GE(victims.size(), 2u) << "the kill came after most of " << victim
                                  << "'s sessions ended";
    const int64_t killed_ns = wallNs();
    ASSERT_EQ(::kill(servers[static_cast<std::size_t>(v)]->pid(), SIGKILL), 0);
    ASSERT_TRUE(servers[static_cast<std::size_t>(v)]->wait(10s).has_value());

    std::map<uint64_t, std::string> digests;
    std::map<uint64_t, uint64_t> sent;
    for (std::size_t i = 0; i < clients.size(); ++i) {
      const auto rc = clients[i]->wait(90s);
      const std::string out = clients[i]->output();
      ASSERT_TRUE(rc.has_value()) << "client " << i << " did not finish\n" << out;
      EXPECT_EQ(*rc, 0) << out;
      sent[ids[i]] = matchNumber(out, R"((\d+) samples sent)");
      std::smatch m;
      if (std::regex_search(out, m, std::regex(R"(sent (\d+ samples, digest [0-9a-f]+))"))) {
        digests[ids[i]] = m[1];
      }
      // 30 s at 1 kHz; a loaded host loses ticks (RecoveryTest checks that the loop runs on
      // through an outage), a client that stopped at the kill would not have half of them.
      EXPECT_GT(sent[ids[i]], 15000u) << out;
    }
    for (int k = 0; k < kServers; ++k) {
      if (k != v) {
        EXPECT_EQ(servers[static_cast<std::size_t>(k)]->stop(), 0);
      }
    }

    const auto store = server::store::openStore(db, server::store::SessionStore::Mode::kReadOnly);
    double worst_claim_s = 0.0, worst_resume_s = 0.0;
    int spurious = 0, by_connection = 0, by_lease = 0;
    for (uint64_t id : ids) {
      const auto info = store->session(id);
      ASSERT_TRUE(info.has_value());
      EXPECT_EQ(info->state, "closed") << id;
      EXPECT_EQ(info->samples, sent[id]) << id;
      EXPECT_EQ(info->samples_expected, sent[id]) << id;
      SampleDigest d;
      store->forEachSample(id, [&](const Sample& s, bool) { d.add(s); });
      EXPECT_EQ(d.text(), digests[id]) << "session " << id << ": the record holds what was sent";
      // Owner events: the OPEN's owner, then each take-over naming the owner before it, after
      // that owner's lease had run out: one owner at every moment. The victim's sessions were
      // taken over from it (a server whose lease ran out while it was stalled on this loaded
      // machine may have lost a session too: counted and shown).
      std::string all, current;
      int64_t resumed_ns = 0, from_victim_ns = 0;
      int takeovers = 0;
      // Taken over when the owner's lease ran out, or (PostgreSQL) when its connection to the
      // record had closed: its process was gone, and no write of its could land any more.
      const std::regex took(R"(owner: server (s\d) took the session over from server (s\d), )"
                            R"(whose (lease ran out|connection to the record had closed) )"
                            R"(.*at (\d+).*record clock (\d+)\))");
      for (const auto& e : store->events(id)) {
        all += e.kind + ": " + e.text + "\n";
        if (e.text.rfind("resumed: ", 0) == 0 && from_victim_ns != 0 && resumed_ns == 0) {
          resumed_ns = e.time_ns;
        }
        if (e.text.rfind("owner: server ", 0) != 0) continue;
        std::smatch m;
        if (current.empty()) {
          current = e.text.substr(14);
          EXPECT_EQ(current.size(), 2u) << all;
          continue;
        }
        ASSERT_TRUE(std::regex_search(e.text, m, took)) << all;
        EXPECT_EQ(m[2].str(), current) << "a take-over names the owner before it\n" << all;
        EXPECT_NE(m[1].str(), current) << all;
        const int64_t lease_end = std::stoll(m[4]), claimed = std::stoll(m[5]);
        if (m[3].str() == "lease ran out") {
          EXPECT_GE(claimed, lease_end) << "one owner at every moment\n" << all;
        } else {
          // Before its lease ran out: only from the server this test killed, after the kill.
          EXPECT_EQ(m[2].str(), victim) << "a live server's connection seen closed\n" << all;
          EXPECT_GE(claimed, killed_ns) << "one owner at every moment\n" << all;
          EXPECT_EQ(GetParam(), std::string("postgresql")) << all;
        }
        if (m[2].str() == victim && from_victim_ns == 0) {
          ++(m[3].str() == "lease ran out" ? by_lease : by_connection);
          from_victim_ns = claimed;
          worst_claim_s = std::max(worst_claim_s, static_cast<double>(claimed - killed_ns) * 1e-9);
        }
        current = m[1].str();
        ++takeovers;
      }
      EXPECT_EQ(current, store->poolOwner(id)) << "the last owner event names the owner\n" << all;
      if (std::find(victims.begin(), victims.end(), id) == victims.end()) {
        spurious += takeovers;
        continue;
      }
      EXPECT_GT(from_victim_ns, 0) << "taken over from the killed server\n" << all;
      EXPECT_GT(resumed_ns, from_victim_ns) << all;
      worst_resume_s = std::max(worst_resume_s, static_cast<double>(resumed_ns - killed_ns) * 1e-9);
      EXPECT_NE(all.find("the hand goes on from its checkpoint"), std::string::npos) << all;
    }
    std::cout << "pool on " << GetParam() << ": killed " << victim << " (sessions";
    for (uint64_t id : victims) std::cout << " " << id;
    std::cout << "); taken over within " << worst_claim_s << " s (" << by_connection
              << " seen gone by its closed connection, " << by_lease
              << " by its lease), resumed by their clients within " << worst_resume_s
              << " s of the kill; " << spurious
              << " take-over(s) of live servers' sessions (leases run out in stalls)\n";
    // How fast is a benchmark's question (tests/bench/bench_pool.sh runs this test and
    // reports the figures); here only that on SQLite the take-over came from the pool's lease
    // (1 s) and not from a client's own 4 s without acknowledgement, with room for a loaded
    // machine. On PostgreSQL the record also sees the dead server's connection close, sooner.
    if (GetParam() == "sqlite") {
      EXPECT_GT(worst_claim_s, 0.5) << "no claim before the dead server's lease ran out";
    }
    EXPECT_LE(worst_resume_s, 15.0);
  }
};

TEST_P(PoolTest, AKilledServersSessionsAreTakenOverAndEndComplete) {
  useOwnDomain();
  if (GetParam() == "sqlite") {
    run(path("records.db"));
    return;
  }
  const auto shared = sharedPgCluster();
  if (!shared.skip.empty()) GTEST_SKIP() << shared.skip;
  ASSERT_TRUE(shared.error.empty()) << shared.error;
  const std::string schema = "pool_" + std::to_string(getpid());
  shared.cluster->exec("CREATE SCHEMA " + schema, "telehand");
  run("postgresql://telehand@/telehand?host=" + shared.cluster->dir() +
      "&options=-csearch_path%3D" + schema);
  shared.cluster->exec("DROP SCHEMA " + schema + " CASCADE", "telehand");
}

INSTANTIATE_TEST_SUITE_P(Store, PoolTest, ::testing::Values("sqlite", "postgresql"),
                         [](const auto& p) { return p.param; });

}  // namespace
}  // namespace telehand::test
