// telehand-server: hosts sessions, keeps every record, publishes joint models and hand state.
#include <unistd.h>

#include <csignal>
#include <iostream>
#include <optional>
#include <thread>

#include "telehand/app/cli.h"
#include "telehand/app/dds_cli.h"
#include "telehand/app/malloc_tuning.h"
#include "telehand/core/clock.h"
#include "telehand/core/log.h"
#include "telehand/protocol/dds.h"
#include "telehand/server/link/server_link.h"
#include "telehand/server/session/serve_watch.h"
#include "telehand/server/store/open_store.h"
#include "telehand/server/store/server_lock.h"

int main(int argc, char** argv) {
  using namespace telehand;
  // First, before any thread: a server that has served a burst of sessions gives their
  // memory back only without glibc's per-thread caches (malloc_tuning.h).
  app::runWithoutMallocThreadCache(argv);
  // And its large blocks mapped apart from the heap, so that they leave no holes in it.
  app::holdMmapThreshold();
  CLI::App app{
      "telehand-server: authoritative session host. Opens and closes sessions on "
      "request, records every DeviceState sample (SQLite, or a PostgreSQL database shared with "
      "other servers), publishes each "
      "session's JointModel and a decimated HandState, and echoes latency probes."};
  std::string config_path, db, log_level = "info";
  dds::Options dds_opts;
  double seconds = 0.0, hand_hz = 0.0;
  app.add_option("-c,--config", config_path, "TOML file with a [server] table")
      ->check(CLI::ExistingFile);
  app.add_option("--db", db,
                 "record store (overrides server.db; default records/telehand.db): an SQLite file "
                 "path, or a PostgreSQL URI postgresql://[user@]host[:port]/dbname (postgres:// "
                 "too; the password from ~/.pgpass or PGPASSWORD rather than the URI)");
  auto* hand_rate =
      app.add_option("--hand-rate", hand_hz, "HandState rate in Hz (1-1000; 60-100 recommended)");
  double hand_deadband = -1.0;
  app.add_option(
         "--hand-deadband", hand_deadband,
         "HandState perceptual deadband for remote viewers, Weber fraction (e.g. 0.05; 0 = off)")
      ->check(CLI::Range(0.0, 0.5));
  double hand_slice_ms = static_cast<double>(server::session::SessionManager::kHandSliceNs) / 1e6;
  app.add_option("--hand-slice-ms", hand_slice_ms,
                 "the Bullet hands step between rounds of taking and recording samples, at most "
                 "this long at a time, within --hand-share of the serving thread (64 sessions "
                 "on one core record every sample, docs/performance.md \"Capacity\"); 0: each "
                 "live sample steps its hand as it is taken, and hands short of CPU hold up the "
                 "intake")
      ->check(CLI::Range(0.0, 100.0))
      ->capture_default_str();
  double hand_share = server::session::SessionManager::kHandShare;
  app.add_option("--hand-share", hand_share,
                 "with a slice, the most of the serving thread's time the hands may take; hands "
                 "short of it step over samples (HandState slows, the record keeps every one)")
      ->check(CLI::Range(0.01, 1.0))
      ->capture_default_str();
  bool insecure = false;
  app::addDdsOptions(app, dds_opts, insecure, "server");
  std::string hand = std::string(TELEHAND_DEPLOY_DIR) + "/hand/hand24.urdf";
  std::string cases = std::string(TELEHAND_DEPLOY_DIR) + "/cases";
  bool list_dofs = false;
  CLI::Option* hand_opt =
      app.add_option("--hand", hand,
                     "hand model (URDF) for the Bullet simulation; 'none': HandState from the "
                     "shared joint model (overrides the config file's)")
          ->capture_default_str();
  CLI::Option* cases_opt =
      app.add_option("--cases", cases,
                     "directory of patient cases (*.toml; overrides the config file's)")
          ->capture_default_str();
  app.add_flag("--list-dofs", list_dofs,
               "print the hand's joint rotations in HandState.joint_angles_rad order and exit");
  bool pool = false;
  std::string pool_id;
  app.add_flag("--pool", pool,
               "serve as one server of a pool sharing the record (docs/pool.md): always so on "
               "PostgreSQL; on an SQLite file, every server of the pool gives --pool");
  app.add_option("--pool-id", pool_id,
                 "this server's name in the pool (default: host:pid); unique in the pool")
      ->check([](const std::string& v) {
        return v.empty() || v.size() > 64 ? std::string("1 to 64 characters") : std::string();
      });
  app.add_option("--seconds", seconds, "stop after this many seconds (0 = until Ctrl-C)");
  app.add_option("--log-level", log_level, "trace, debug, info, warn, error, off")
      ->capture_default_str();
  TELEHAND_CLI_PARSE(app, argc, argv)

  try {
    setupLogging("telehand-server", log_level);
    ServerConfig cfg = config_path.empty() ? ServerConfig{} : loadServerConfig(config_path);
    app::resolveDdsSecurity(dds_opts, insecure, "server", "telehand-server");
    if (!db.empty()) cfg.db_path = db;
    if (*hand_rate) cfg.hand_state_hz = hand_hz;
    if (hand_deadband >= 0.0) cfg.hand_deadband_weber = hand_deadband;
    // The flags lie in the ranges of the config keys they stand for.
    validateServerConfig(
        cfg, config_path.empty() ? std::string("command line") : "command line and " + config_path);
    // Given on the command line, they override the config file's (as --db does).
    if (*hand_opt || cfg.hand_model.empty()) cfg.hand_model = hand == "none" ? "" : hand;
    if (*cases_opt || cfg.cases_dir.empty()) cfg.cases_dir = cases;
    std::optional<server::sim::HandModel> hand_model;
    if (!cfg.hand_model.empty()) hand_model = server::sim::HandModel::load(cfg.hand_model);
    if (list_dofs) {
      if (!hand_model) throw ConfigError("--list-dofs needs a hand model");
      int i = 0;
      for (const auto& n : hand_model->dofNames()) std::cout << i++ << " " << n << "\n";
      return 0;
    }
    if (listPatientCases(cfg.cases_dir).empty()) {
      throw ConfigError("no patient cases (*.toml) in '" + cfg.cases_dir + "'");
    }

    const auto store = server::store::openStore(cfg.db_path);
    // One server per SQLite record (docs/recovery.md), or a pool of them on one machine; a
    // PostgreSQL record is shared by a pool (docs/pool.md).
    const bool shared = server::store::isPostgresUri(cfg.db_path);
    if (shared) pool = true;
    std::optional<server::store::ServerLock> lock;
    if (!shared) lock.emplace(cfg.db_path, pool);
    if (pool && pool_id.empty()) {
      char host[256] = {};
      gethostname(host, sizeof host - 1);
      pool_id = std::string(host) + ":" + std::to_string(getpid());
    }
    // A pool's server announces a 3 s lease (Cyclone's is 10 s): after one dies, the clients'
    // reliable writers stop waiting for its readers that much sooner (docs/pool.md).
    if (pool) dds_opts.lease_s = 3.0;
    server::link::ServerLink link(dds_opts, cfg.renew_when_idle);
    server::session::SessionManager manager(*store, link, cfg, hand_model ? &*hand_model : nullptr);
    // With a slice, the hands step between rounds of taking and recording, at most a slice
    // at a time (docs/performance.md "Capacity").
    manager.setHandSlice(hand_slice_ms > 0.0 ? static_cast<int64_t>(hand_slice_ms * 1e6) : 0);
    manager.setHandShare(hand_share);
    // PostgreSQL: the samples are written on a thread and connection of their own, so that a
    // slow record holds up the acknowledgements and not the serve loop (docs/pool.md).
    if (manager.writeSamplesOnThread()) {
      spdlog::info("samples go to the record on a writer thread of their own");
    }
    // The lease is renewed on a thread (and a connection) of its own as well as by the serve
    // loop: a loop held up for a moment (closing sessions, a busy record, a starved CPU)
    // keeps its sessions; one held up for kServeStallNs (wedged) lets them go to the pool.
    std::jthread beat;
    if (pool) {
      // The pool takes on what the record holds open as orphans, a share per server.
      manager.joinPool(pool_id);
      spdlog::info("serving as '{}' in the pool on {}", pool_id, store->location());
      beat = std::jthread([db_spec = cfg.db_path, pool_id, &manager, &link](std::stop_token token) {
        using Manager = server::session::SessionManager;
        std::unique_ptr<server::store::SessionStore> own;
        int64_t reported_ns = 0;
        bool stalled = false;
        server::session::ServeWatch watch(Manager::kServeStallNs);
        while (!token.stop_requested()) {
          const int64_t now = SteadyClock{}.nowNs();
          if (!watch.alive(manager.progress(), now)) {
            if (!stalled) {
              spdlog::error(
                  "pool: the serve loop has handled nothing for {:.1f} s: the lease is not "
                  "renewed, and the pool takes this server's sessions over",
                  static_cast<double>(watch.idleNs(now)) * 1e-9);
            }
            stalled = true;
            std::this_thread::sleep_for(std::chrono::nanoseconds(Manager::kLeaseRenewNs));
            continue;
          }
          stalled = false;
          try {
            if (!own) own = server::store::openStore(db_spec);
            own->poolHeartbeat(pool_id, 0, Manager::kPoolLeaseNs);
            // A dead server's sessions: claimed at the serve loop's next round, not its next
            // heartbeat (up to 0.2 s later, more when the loop is busy).
            if (!own->poolOrphans().empty()) {
              manager.claimSoon();
              link.wake();
            }
          } catch (const Error& e) {
            if (now - reported_ns > 5'000'000'000) {
              reported_ns = now;
              spdlog::error("pool: cannot renew the lease: {}", e.what());
            }
            own.reset();
          }
          std::this_thread::sleep_for(std::chrono::nanoseconds(Manager::kLeaseRenewNs));
        }
      });
    } else if (const std::size_t n = manager.recoverFromStore(SteadyClock{}.nowNs())) {
      spdlog::info("{} session(s) found open or suspended in {}: waiting {:g} s for their clients",
                   n, store->location(), cfg.resume_wait_s);
    }
    installStopSignals();
    spdlog::info("serving on DDS domain {} partition '{}', records in {}, hand {}, cases in {}",
                 dds_opts.domain, dds_opts.partition, store->location(),
                 hand_model ? cfg.hand_model : "none (shared joint model)", cfg.cases_dir);

    std::atomic<bool> stop{false};
    const auto t0 = std::chrono::steady_clock::now();
    // Turns Ctrl-C, SIGTERM and --seconds into a stop request the serve loop sees at once.
    std::jthread stopper([&](std::stop_token token) {
      while (!token.stop_requested() && !stop.load()) {
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
        const bool timed_out = seconds > 0.0 && std::chrono::steady_clock::now() - t0 >
                                                    std::chrono::duration<double>(seconds);
        if (g_stop_requested.load() || timed_out) {
          stop.store(true);
          link.wake();
        }
      }
    });
    const auto tick = std::chrono::nanoseconds(static_cast<int64_t>(1e9 / cfg.hand_state_hz));
    link.serve(manager, stop, tick);
    if (beat.joinable()) {
      beat.request_stop();
      beat.join();
    }
    manager.leavePool();  // its sessions suspended: the others take them on at once
    stop.store(true);
    stopper.request_stop();
    stopper.join();
    const auto& st = manager.stats();
    const auto& lc = link.counters();
    spdlog::info(
        "stopped: {} samples recorded, {} live, {} invalid, {} for unknown sessions, "
        "{} bad commands, {} refused (security), {} store errors, {} echoes; hands: {} steps, "
        "{} live samples stepped over (short of CPU)",
        st.recorded_samples, st.live_samples, st.nonfinite_samples, st.unknown_session_samples,
        st.bad_commands, st.refused, st.store_errors, lc.echoes.load(), st.hand_steps,
        st.hand_samples_skipped);
    if (const auto crypto = telehand::dds::cryptoCounts()) {
      spdlog::info("security: {}", telehand::dds::cryptoSummary(*crypto));
    }
    return 0;
  } catch (const telehand::Error& e) {
    std::cerr << "telehand-server: " << e.what() << "\n";
    return 2;
  }
}
