#pragma once
// A throw-away PostgreSQL cluster for tests and benchmarks: initdb in a directory of its own
// under /tmp, a postmaster listening only on a unix socket in that directory (no TCP port,
// so tests running beside each other cannot clash), stopped by its PID and removed at the
// end. A watchdog (a shell that dies with the thread that made the cluster) stops and
// removes it too when the test process dies without cleaning up (a crash, a ctest timeout).
//
// initdb refuses to run as root: as root (CI, this machine's containers) the cluster is made
// and run as the `postgres` system user through runuser, its directory given to that user;
// otherwise as the user running the test.
#include <libpq-fe.h>
#include <pwd.h>
#include <signal.h>
#include <stdlib.h>
#include <sys/types.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <memory>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "telehand/app/process.h"

namespace telehand::test {

class PgCluster {
 public:
  /// Where initdb, pg_ctl and postgres are (the newest /usr/lib/postgresql/N/bin, else
  /// PATH), or nullopt with `why` saying what is missing. As root, also the `postgres` user
  /// and runuser.
  static std::optional<std::string> findBinDir(std::string* why) {
    namespace fs = std::filesystem;
    std::vector<std::pair<int, std::string>> found;
    std::error_code ec;
    for (const auto& e : fs::directory_iterator("/usr/lib/postgresql", ec)) {
      const auto bin = e.path() / "bin";
      if (fs::exists(bin / "initdb") && fs::exists(bin / "pg_ctl") &&
          fs::exists(bin / "postgres")) {
        found.emplace_back(std::atoi(e.path().filename().c_str()), bin.string());
      }
    }
    std::optional<std::string> dir;
    if (!found.empty()) {
      dir = std::max_element(found.begin(), found.end())->second;
    } else if (const auto initdb = app::findProgram("initdb")) {
      dir = fs::path(*initdb).parent_path().string();
    }
    if (!dir) {
      if (why) {
        *why =
            "PostgreSQL's server programs (initdb, pg_ctl, postgres) are not installed "
            "(/usr/lib/postgresql/*/bin or PATH; Debian package postgresql, deploy/setup.sh)";
      }
      return std::nullopt;
    }
    if (getuid() == 0) {
      if (!getpwnam("postgres")) {
        if (why) *why = "running as root and there is no 'postgres' user to run PostgreSQL as";
        return std::nullopt;
      }
      if (!app::findProgram("runuser")) {
        if (why) *why = "running as root and runuser (util-linux) is missing";
        return std::nullopt;
      }
    }
    return dir;
  }

  /// `durable`: fsync and synchronous commits as a production server has them (benchmarks);
  /// otherwise off, for fast tests. Throws std::runtime_error, with the log, when the cluster
  /// cannot be made or started.
  explicit PgCluster(bool durable = false) : durable_(durable) {
    std::string why;
    const auto bin = findBinDir(&why);
    if (!bin) throw std::runtime_error(why);
    bin_ = *bin;
    std::string tmpl = "/tmp/telehand-pg-XXXXXX";
    if (!mkdtemp(tmpl.data())) throw std::runtime_error("mkdtemp failed");
    dir_ = tmpl;
    if (getuid() == 0) {
      const passwd* pw = getpwnam("postgres");
      if (chown(dir_.c_str(), pw->pw_uid, pw->pw_gid) != 0) {
        throw std::runtime_error("cannot give " + dir_ + " to the postgres user");
      }
    }
    // From here on the directory is the watchdog's to remove should this process die.
    watchdog_ = std::make_unique<app::Process>(
        app::ProcessOptions{.argv = {"/bin/sh", "-c", kWatchdogScript, "pg-watchdog", dir_},
                            .null_stdin = true,
                            .die_with_parent = true});
    run({bin_ + "/initdb", "-D", data(), "-U", "telehand", "-A", "trust", "-E", "UTF8",
         "--locale=C", "-N"},
        "initdb");
    start();
  }

  ~PgCluster() {
    stop();
    std::error_code ec;
    std::filesystem::remove_all(dir_, ec);
    if (watchdog_) watchdog_->stop(std::chrono::seconds(5));
  }
  PgCluster(const PgCluster&) = delete;
  PgCluster& operator=(const PgCluster&) = delete;

  /// Starts the postmaster (again, on the same data after stop()); waits until it accepts
  /// connections.
  void start() {
    std::string opts = "-k " + dir_ + " -c listen_addresses='' -c max_connections=200";
    if (!durable_) opts += " -c fsync=off -c synchronous_commit=off -c full_page_writes=off";
    run({bin_ + "/pg_ctl", "-D", data(), "-l", dir_ + "/postgres.log", "-w", "-t", "60", "-o", opts,
         "start"},
        "pg_ctl-start");
    std::ifstream pidfile(data() + "/postmaster.pid");
    long pid = 0;
    pidfile >> pid;
    if (pid <= 0) throw std::runtime_error("no postmaster.pid in " + data() + "\n" + log());
    pid_ = static_cast<pid_t>(pid);
  }

  /// Fast shutdown (SIGINT to the postmaster, by its PID), waited for; SIGKILL after 30 s.
  void stop() {
    if (pid_ <= 0) return;
    kill(pid_, SIGINT);
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(30);
    while (kill(pid_, 0) == 0 && std::chrono::steady_clock::now() < deadline) {
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    if (kill(pid_, 0) == 0) kill(pid_, SIGKILL);
    pid_ = -1;
  }

  pid_t pid() const { return pid_; }
  const std::string& dir() const { return dir_; }

  /// A connection URI to database `db` as the cluster's superuser, over the unix socket;
  /// `schema` non-empty: the session's search_path is that schema.
  std::string uri(const std::string& db = "postgres", const std::string& schema = "") const {
    std::string u = "postgresql:///" + db + "?host=" + dir_ + "&user=telehand";
    if (!schema.empty()) u += "&options=-csearch_path%3D" + schema;
    return u;
  }

  /// Runs `sql` on database `db`; throws std::runtime_error with PostgreSQL's message.
  void exec(const std::string& sql, const std::string& db = "postgres") const {
    PGconn* c = connectTo(db);
    const auto done = [&](const std::string& why) {
      PQfinish(c);
      if (!why.empty()) throw std::runtime_error(sql + ": " + why);
    };
    if (PQstatus(c) != CONNECTION_OK) done(PQerrorMessage(c));
    PGresult* r = PQexec(c, sql.c_str());
    const bool ok = PQresultStatus(r) == PGRES_COMMAND_OK || PQresultStatus(r) == PGRES_TUPLES_OK;
    const std::string why = ok ? "" : PQresultErrorMessage(r);
    PQclear(r);
    done(why);
  }

  /// Runs `sql` on database `db` and returns the first column of its first row ("" if none).
  std::string value(const std::string& sql, const std::string& db = "postgres") const {
    PGconn* c = connectTo(db);
    std::string out, why;
    if (PQstatus(c) != CONNECTION_OK) {
      why = PQerrorMessage(c);
    } else {
      PGresult* r = PQexec(c, sql.c_str());
      if (PQresultStatus(r) != PGRES_TUPLES_OK) {
        why = PQresultErrorMessage(r);
      } else if (PQntuples(r) > 0) {
        out = PQgetvalue(r, 0, 0);
      }
      PQclear(r);
    }
    PQfinish(c);
    if (!why.empty()) throw std::runtime_error(sql + ": " + why);
    return out;
  }

  std::string log() const {
    std::ifstream in(dir_ + "/postgres.log");
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
  }

 private:
  // $1: the cluster's directory. On SIGTERM (the thread that made the cluster died, or the
  // cluster is done with): the postmaster named in postmaster.pid, if it still runs, is
  // stopped (fast, then killed), and the directory removed.
  static constexpr const char* kWatchdogScript = R"sh(
dir=$1
cleanup() {
  pidfile="$dir/data/postmaster.pid"
  if [ -f "$pidfile" ]; then
    pid=$(head -n 1 "$pidfile")
    if [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null; then
      kill -INT "$pid"
      i=0
      while kill -0 "$pid" 2>/dev/null && [ $i -lt 300 ]; do sleep 0.1; i=$((i + 1)); done
      kill -KILL "$pid" 2>/dev/null
    fi
  fi
  rm -rf "$dir"
  exit 0
}
trap cleanup TERM INT HUP
while :; do sleep 1; done
)sh";

  std::string data() const { return dir_ + "/data"; }

  /// A connection whose notices (IF EXISTS ... skipping) stay quiet.
  PGconn* connectTo(const std::string& db) const {
    PGconn* c = PQconnectdb(uri(db).c_str());
    if (c)
      PQsetNoticeProcessor(
          c, [](void*, const char*) {}, nullptr);
    return c;
  }

  /// Runs a PostgreSQL program (as the postgres user when root) to its end.
  void run(std::vector<std::string> argv, const std::string& name) const {
    if (getuid() == 0) argv.insert(argv.begin(), {"runuser", "-u", "postgres", "--"});
    const std::string out = dir_ + "/" + name + ".out";
    app::Process p(app::ProcessOptions{
        .argv = argv, .search_path = true, .out_path = out, .null_stdin = true});
    const auto rc = p.wait(std::chrono::seconds(120));
    if (rc != 0) {
      std::ifstream in(out);
      std::ostringstream s;
      s << in.rdbuf();
      throw std::runtime_error(argv.front() + " (" + name + ") failed: " + s.str() + "\n" + log());
    }
  }

  bool durable_;
  std::string bin_, dir_;
  pid_t pid_ = -1;
  std::unique_ptr<app::Process> watchdog_;
};

/// The one cluster of this test process: made at first use, stopped and removed when the
/// process exits. `skip` says why there is none when PostgreSQL is not installed; `error`
/// when it is but the cluster could not be started (a failure, not a skip).
struct SharedPgCluster {
  PgCluster* cluster = nullptr;
  std::string skip, error;
};

inline SharedPgCluster sharedPgCluster() {
  static std::unique_ptr<PgCluster> cluster;
  static std::string skip, error;
  static bool tried = false;
  if (!tried) {
    tried = true;
    if (!PgCluster::findBinDir(&skip)) {
      skip = "no PostgreSQL to test against: " + skip;
    } else {
      skip.clear();
      try {
        cluster = std::make_unique<PgCluster>();
        cluster->exec("CREATE DATABASE telehand");
      } catch (const std::exception& e) {
        error = std::string("cannot start a PostgreSQL cluster: ") + e.what();
        cluster.reset();
      }
    }
  }
  return {cluster.get(), skip, error};
}

}  // namespace telehand::test
