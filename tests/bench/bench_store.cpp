// Record store write throughput (docs/performance.md "Record store"): SQLite against
// PostgreSQL under the load of SESSIONS sessions recording RATE samples/s each, in 100-sample
// chunks as telehand-server receives them (RecordChunk).
//
// Two shapes of writer:
//  - server: one store and one thread writing every session's chunks in turn, as one
//    telehand-server does (its SessionManager stores on the DDS thread);
//  - shared: one store (connection, SQLite handle) and one thread per session, as many
//    servers sharing one record would write (64 servers of one session each: the worst case).
// For each: saturated (chunks as fast as they go, for SECONDS: the samples/s the store
// takes, and the headroom, that rate over SESSIONS x RATE) and paced (each session's chunk
// every CHUNK/RATE s, for SECONDS: whether the store keeps up, the append latency, and how
// far the last chunk of a round ran behind its due time).
//
// The PostgreSQL cluster is a throw-away one (tests/support/pg_cluster.h) with production
// durability: fsync and synchronous_commit on, so every append waits for its WAL flush. The
// SQLite file is as SqliteStore opens it (WAL, synchronous=NORMAL: a commit does not wait for
// the disk; a power loss can take the last commits, never corrupt). Both in /tmp unless --dir.
//
// Usage: telehand_bench_store [--quick] [--backend sqlite|postgres|both] [--sessions N]
//          [--rate HZ] [--seconds S] [--pg URI (an existing server instead of a throw-away one)]
//          [--async-commit (PostgreSQL with synchronous_commit off: commits do not wait for
//          the WAL flush, SQLite's durability in WAL mode)] [--dir DIR]
#include <spdlog/spdlog.h>
#include <sys/resource.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "../support/pg_cluster.h"
#include "telehand/core/clock.h"
#include "telehand/core/error.h"
#include "telehand/server/store/open_store.h"

using namespace telehand;
using server::store::SessionInfo;
using server::store::SessionStore;

namespace {

constexpr std::size_t kChunk = 100;

int64_t now() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec * kNsPerS + ts.tv_nsec;
}

void sleepUntil(int64_t t) {
  timespec ts{t / kNsPerS, t % kNsPerS};
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
  }
}

struct Options {
  std::string backend = "both";
  int sessions = 64;
  double rate = 1000.0;
  double seconds = 10.0;
  std::string pg_uri, dir;
  bool quick = false;
  bool async_commit = false;  ///< PostgreSQL: synchronous_commit off, through the URI
};

/// A chunk of a session: every field filled, varying as a recording does.
std::vector<Sample> chunk(uint64_t session, uint64_t first_seq, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<Sample> out(kChunk);
  for (std::size_t i = 0; i < kChunk; ++i) {
    Sample& s = out[i];
    s.session_id = session;
    s.seq = first_seq + i;
    s.source_time_ns = 1'700'000'000'000'000'000 + static_cast<int64_t>(s.seq) * 1'000'000;
    s.model_version = 3;
    s.flags = static_cast<uint32_t>(rng() & 0x3ff);
    for (auto& f : s.fingers) {
      for (auto& v : f.position_m) v = 0.05 * u(rng);
      for (auto& v : f.orientation_q) v = u(rng);
      for (auto& v : f.fsr_n) v = static_cast<float>(10.0 + 5.0 * u(rng));
      f.tangential_n = static_cast<float>(u(rng));
      f.normal_n = static_cast<float>(12.0 + u(rng));
      for (auto& v : f.command_n) v = u(rng);
    }
    for (auto& v : s.mcp_angles_rad) v = u(rng);
    for (auto& v : s.mcp_torque_nm) v = 0.1 * u(rng);
    s.passivity_energy_j = static_cast<float>(u(rng));
    s.passivity_damping = static_cast<float>(u(rng));
  }
  return out;
}

struct Result {
  uint64_t samples = 0, errors = 0;
  uint64_t due = 0;  ///< paced: samples the schedule asked for
  double seconds = 0.0;
  std::vector<int64_t> latency_ns;  ///< per append
  int64_t worst_lag_ns = 0;         ///< paced: how late the latest append finished past due
};

double quantile(std::vector<int64_t>& v, double p) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  return static_cast<double>(v[std::min(
             v.size() - 1, static_cast<std::size_t>(p * static_cast<double>(v.size())))]) *
         1e-6;
}

/// One writer: `sessions` sessions of one store, in turn. Paced: each round (one chunk per
/// session) is due every kChunk / rate seconds.
void writer(SessionStore& store, const std::vector<uint64_t>& sessions, const Options& o,
            bool paced, const std::atomic<bool>& go, Result& r) {
  std::mt19937_64 rng(sessions.front());
  std::vector<std::vector<Sample>> pool;
  for (int i = 0; i < 8; ++i) pool.push_back(chunk(sessions.front(), 0, rng));
  while (!go.load()) std::this_thread::yield();
  const int64_t t0 = now();
  const int64_t end = t0 + static_cast<int64_t>(o.seconds * 1e9);
  const auto period = static_cast<int64_t>(static_cast<double>(kChunk) / o.rate * 1e9);
  for (uint64_t round = 0;; ++round) {
    const int64_t due = t0 + static_cast<int64_t>(round) * period;
    if (paced) {
      if (due >= end) break;
      sleepUntil(due);
    } else if (now() >= end) {
      break;
    }
    for (const uint64_t s : sessions) {
      r.due += kChunk;
      auto& c = pool[round % pool.size()];
      for (std::size_t i = 0; i < kChunk; ++i) {
        c[i].session_id = s;
        c[i].seq = round * kChunk + i;
      }
      const int64_t a = now();
      try {
        r.samples += store.appendSamples(s, c, {});
      } catch (const StoreError& e) {
        if (r.errors++ == 0) std::fprintf(stderr, "store error: %s\n", e.what());
      }
      r.latency_ns.push_back(now() - a);
    }
    if (paced) r.worst_lag_ns = std::max(r.worst_lag_ns, now() - (due + period));
  }
  r.seconds = static_cast<double>(now() - t0) * 1e-9;
}

/// One measurement: `shared`: a store and a thread per session; otherwise one of each.
Result measure(const std::string& spec, const Options& o, bool shared, bool paced) {
  std::vector<std::unique_ptr<SessionStore>> stores;
  std::vector<std::vector<uint64_t>> sessions;
  stores.push_back(server::store::openStore(spec));
  sessions.emplace_back();
  for (int i = 0; i < o.sessions; ++i) {
    if (shared && i > 0) {
      stores.push_back(server::store::openStore(spec));
      sessions.emplace_back();
    }
    SessionInfo info;
    info.user = "bench";
    info.case_name = "healthy";
    info.mode = "mobilization";
    sessions.back().push_back(stores.back()->createSession(info));
  }
  std::vector<Result> results(stores.size());
  std::atomic<bool> go{false};
  std::vector<std::thread> threads;
  for (std::size_t i = 0; i < stores.size(); ++i) {
    threads.emplace_back([&, i] { writer(*stores[i], sessions[i], o, paced, go, results[i]); });
  }
  go.store(true);
  for (auto& t : threads) t.join();
  Result all;
  for (auto& r : results) {
    all.samples += r.samples;
    all.errors += r.errors;
    all.due += r.due;
    all.seconds = std::max(all.seconds, r.seconds);
    all.worst_lag_ns = std::max(all.worst_lag_ns, r.worst_lag_ns);
    all.latency_ns.insert(all.latency_ns.end(), r.latency_ns.begin(), r.latency_ns.end());
  }
  return all;
}

/// CPU seconds a process has used: itself, and its children it has reaped (/proc/PID/stat).
double cpuSeconds(pid_t pid, bool with_reaped) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
  std::string line;
  if (!std::getline(in, line)) return 0.0;
  // After the command's closing parenthesis: state ppid ... utime(14) stime(15) cutime(16)
  // cstime(17), counted from field 3.
  std::istringstream f(line.substr(line.rfind(')') + 2));
  std::vector<std::string> v;
  for (std::string w; f >> w && v.size() < 15;) v.push_back(w);
  if (v.size() < 15) return 0.0;
  const double tick = static_cast<double>(sysconf(_SC_CLK_TCK));
  double t = std::stod(v[11]) + std::stod(v[12]);
  if (with_reaped) t += std::stod(v[13]) + std::stod(v[14]);
  return t / tick;
}

/// CPU seconds of a PostgreSQL server: the postmaster, the backends it reaped, and the
/// processes still running under it (background writer, WAL writer, checkpointer, backends).
double serverCpuSeconds(pid_t postmaster) {
  if (postmaster <= 0) return 0.0;
  double t = cpuSeconds(postmaster, true);
  for (const auto& e : std::filesystem::directory_iterator("/proc")) {
    const std::string name = e.path().filename().string();
    if (name.empty() || !std::isdigit(static_cast<unsigned char>(name[0]))) continue;
    std::ifstream in(e.path() / "stat");
    std::string line;
    if (!std::getline(in, line)) continue;
    std::istringstream f(line.substr(line.rfind(')') + 2));
    std::string state;
    long ppid = 0;
    f >> state >> ppid;
    if (ppid == postmaster) t += cpuSeconds(static_cast<pid_t>(std::stol(name)), false);
  }
  return t;
}

double selfCpuSeconds() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return static_cast<double>(u.ru_utime.tv_sec + u.ru_stime.tv_sec) +
         static_cast<double>(u.ru_utime.tv_usec + u.ru_stime.tv_usec) * 1e-6;
}

/// `postmaster`: the PostgreSQL server's PID when it is this program's, for its CPU time.
void bench(const char* name, const std::string& spec, const Options& o, pid_t postmaster) {
  const double need = o.sessions * o.rate;
  for (const bool shared : {false, true}) {
    const char* shape = shared ? "shared" : "server";
    for (const bool paced : {false, true}) {
      const double cpu0 = selfCpuSeconds() + serverCpuSeconds(postmaster);
      Result r = measure(spec, o, shared, paced);
      // The backends of the closed connections exit and are reaped by the postmaster.
      if (postmaster > 0) std::this_thread::sleep_for(std::chrono::milliseconds(300));
      const double cpu = selfCpuSeconds() + serverCpuSeconds(postmaster) - cpu0;
      if (paced) {
        // Kept up: every sample due stored, and no round finished a period late.
        std::printf("%-10s %-6s paced     %9llu of %9llu due stored, worst lag %8.2f ms", name,
                    shape, static_cast<unsigned long long>(r.samples),
                    static_cast<unsigned long long>(r.due),
                    static_cast<double>(r.worst_lag_ns) * 1e-6);
      } else {
        const double rate = static_cast<double>(r.samples) / r.seconds;
        std::printf("%-10s %-6s saturated %9.0f samples/s, headroom %5.2fx          ", name, shape,
                    rate, rate / need);
      }
      std::printf("  append p50 %7.2f p99 %7.2f max %8.2f ms", quantile(r.latency_ns, 0.5),
                  quantile(r.latency_ns, 0.99), quantile(r.latency_ns, 1.0));
      // CPU per sample, the writer's and the database server's: what a core holds, whatever
      // else the machine runs meanwhile.
      if (r.samples > 0 && (postmaster > 0 || std::strcmp(name, "sqlite") == 0)) {
        std::printf("  CPU %5.1f us/sample (%4.0fk samples/s per core)",
                    cpu / static_cast<double>(r.samples) * 1e6,
                    static_cast<double>(r.samples) / cpu * 1e-3);
      }
      if (r.errors) std::printf("  ERRORS %llu", static_cast<unsigned long long>(r.errors));
      std::printf("\n");
      std::fflush(stdout);
    }
  }
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "%s needs a value\n", a.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--quick") {
      o.quick = true;
      o.sessions = 8;
      o.seconds = 0.5;
    } else if (a == "--backend") {
      o.backend = next();
    } else if (a == "--sessions") {
      o.sessions = std::atoi(next().c_str());
    } else if (a == "--rate") {
      o.rate = std::atof(next().c_str());
    } else if (a == "--seconds") {
      o.seconds = std::atof(next().c_str());
    } else if (a == "--pg") {
      o.pg_uri = next();
    } else if (a == "--async-commit") {
      o.async_commit = true;
    } else if (a == "--dir") {
      o.dir = next();
    } else {
      std::fprintf(stderr,
                   "usage: telehand_bench_store [--quick] [--backend sqlite|postgres|both] "
                   "[--sessions N] [--rate HZ] [--seconds S] [--pg URI] [--async-commit] "
                   "[--dir DIR]\n");
      return 2;
    }
  }
  if (o.sessions < 1 || o.rate <= 0.0 || o.seconds <= 0.0 ||
      (o.backend != "sqlite" && o.backend != "postgres" && o.backend != "both")) {
    std::fprintf(stderr, "bad --sessions, --rate, --seconds or --backend\n");
    return 2;
  }
  spdlog::set_level(spdlog::level::warn);
  std::printf("%d sessions x %.0f samples/s = %.0f samples/s in %zu-sample chunks, %g s each\n",
              o.sessions, o.rate, o.sessions * o.rate, kChunk, o.seconds);
  try {
    if (o.backend != "postgres") {
      namespace fs = std::filesystem;
      const fs::path dir = fs::path(o.dir.empty() ? fs::temp_directory_path().string() : o.dir) /
                           ("telehand-bench-store-" + std::to_string(getpid()));
      bench("sqlite", (dir / "records.db").string(), o, 0);
      std::error_code ec;
      fs::remove_all(dir, ec);
    }
    if (o.backend != "sqlite") {
      std::unique_ptr<test::PgCluster> cluster;
      std::string uri = o.pg_uri;
      if (uri.empty()) {
        std::string why;
        if (!test::PgCluster::findBinDir(&why)) {
          std::printf("postgresql: skipped (%s)\n", why.c_str());
          return 0;
        }
        cluster = std::make_unique<test::PgCluster>(/*durable=*/true);
        cluster->exec("CREATE DATABASE telehand");
        uri = cluster->uri("telehand");
      }
      if (o.async_commit) {
        uri += std::string(uri.find('?') == std::string::npos ? "?" : "&") +
               "options=-csynchronous_commit%3Doff";
      }
      bench(o.async_commit ? "pg-async" : "postgresql", uri, o, cluster ? cluster->pid() : 0);
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "telehand_bench_store: %s\n", e.what());
    return 1;
  }
  return 0;
}
