// Sessions per server core (docs/performance.md "Capacity"): N sessions on the Bullet hand,
// each streaming 1 kHz live DeviceStates and its record as 100-sample RecordChunks of a pinch
// mobilization (index MCP flexion 50 ± 15 deg at 3 Hz), paced in real time for S seconds,
// through one SessionManager on an SQLite record, the whole process pinned to one core.
//
// The serving loop is ServerLink::serve's without DDS: the client streams arrive into reader
// queues as their samples fall due (DeviceState keep-last 256 per session, so a server too
// slow to take them loses the oldest; RecordChunk reliable keep-all), and each round takes
// the chunks (up to 1024), then the live samples (up to 256, or 4096 with the hands
// deferred: ServerLink::serve's batches), then ticks the manager (which
// steps the hands for at most --hand-slice-ms, telehand-server's default 2 ms; 0: each live
// sample steps its hand as it is taken); with nothing to take and no hand work owed it waits
// for the next sample due.
//
// Per N: samples recorded of those sent (by the end of the run, and after a drain and
// CLOSE), how late the chunks were stored and the live samples taken (from when they fell
// due), live samples the reader overwrote, hand steps done of those due (one per ms of each
// session), HandStates published per session per second, and the process's CPU time per
// sample (and share of the core), all after a warm-up (the first seconds wake every finger
// of a hand). The record holds when every sample is stored and the chunks are at most
// kChunkLagOkMs late at p99; the hand is full when the server took every live sample (none
// overwritten, p99 at most kLiveLagOkMs late), the hands stepped over none and made 99 % of
// their steps.
//
// Usage: telehand_bench_capacity [--sessions 16,32,48,64] [--seconds 13] [--warmup 3]
//          [--cpu K] [--hand-slice-ms 2] [--no-hand] [--case healthy] [--quick]
#include <sched.h>
#include <spdlog/spdlog.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include "../support/grip_sample.h"
#include "telehand/config/config.h"
#include "telehand/core/clock.h"
#include "telehand/protocol/wire.h"
#include "telehand/server/session/session_manager.h"
#include "telehand/server/sim/hand_model.h"
#include "telehand/server/store/sqlite_store.h"

using namespace telehand;
namespace fs = std::filesystem;

namespace {

int64_t now() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec * kNsPerS + ts.tv_nsec;
}

int64_t cpuNs() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec * kNsPerS + ts.tv_nsec;
}

void sleepUntil(int64_t t) {
  timespec ts{t / kNsPerS, t % kNsPerS};
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
  }
}

double quantileMs(std::vector<int64_t>& ns, double p) {
  if (ns.empty()) return 0.0;
  const auto k =
      std::min(ns.size() - 1, static_cast<std::size_t>(p * static_cast<double>(ns.size())));
  std::nth_element(ns.begin(), ns.begin() + static_cast<std::ptrdiff_t>(k), ns.end());
  return static_cast<double>(ns[k]) * 1e-6;
}

double maxMs(const std::vector<int64_t>& ns) {
  return ns.empty() ? 0.0 : static_cast<double>(*std::max_element(ns.begin(), ns.end())) * 1e-6;
}

double loadAverage() {
  std::ifstream f("/proc/loadavg");
  double l = -1.0;
  f >> l;
  return l;
}

/// Counts what the manager publishes.
class CountingOutbox final : public server::session::Outbox {
 public:
  void publish(const telehand_msg_SessionStatus& s) override { statuses.push_back(s); }
  void publish(const telehand_msg_JointModel& m) override { models.push_back(m); }
  void publish(const telehand_msg_HandState&) override { ++hand_states; }
  void publish(const telehand_msg_SessionEvent&) override { ++events; }
  std::vector<telehand_msg_SessionStatus> statuses;
  std::vector<telehand_msg_JointModel> models;
  uint64_t hand_states = 0;
  uint64_t events = 0;
};

constexpr int64_t kMs = 1'000'000;
constexpr std::size_t kChunk = 100;
constexpr std::size_t kLiveDepth = 256;           // ServerLink's DeviceState reader history
constexpr std::size_t kLiveBatch = 256;           // DeviceStates taken per round (the hand inline)
constexpr std::size_t kDeferredLiveBatch = 4096;  // and with the hands deferred
constexpr std::size_t kChunkBatch = 1024;
constexpr double kChunkLagOkMs = 500.0;  // the record's acknowledgement period
constexpr double kLiveLagOkMs = 50.0;    // SessionManager::kMaxCatchUpSteps of device time

struct Options {
  std::vector<int> sessions = {16, 32, 48, 64};
  int seconds = 13;
  int warmup = 3;  // seconds of each row before its figures are taken
  int cpu = -1;
  bool hand = true;
  std::string case_name = "healthy";
  double hand_slice_ms = 2.0;  // telehand-server's default; 0: the hand steps with each sample
  double hand_share = server::session::SessionManager::kHandShare;
};

struct Client {
  uint64_t session_id = 0;
  int64_t offset_ns = 0;                      // its loop's phase within the millisecond
  uint64_t next_seq = 0;                      // the next sample it sends
  int phase = 0;                              // where in the pinch cycle it starts
  std::deque<telehand_msg_DeviceState> live;  // the server's reader queue
  std::vector<telehand_msg_DeviceState> chunk;
  uint64_t chunk_seq = 0;
};

struct PendingChunk {
  std::size_t client = 0;
  int64_t ready_ns = 0;
  uint64_t chunk_seq = 0;
  std::vector<telehand_msg_DeviceState> samples;
};

struct Result {
  int sessions = 0;
  uint64_t expected = 0, recorded_in_run = 0, recorded = 0, stored = 0;
  uint64_t live_taken = 0, live_overwritten = 0;
  uint64_t steps_due = 0, steps = 0, skipped = 0;
  double hand_hz = 0.0, cpu_share = 0.0, cpu_us_per_sample = 0.0;
  double chunk_p50 = 0, chunk_p99 = 0, chunk_max = 0, live_p50 = 0, live_p99 = 0, live_max = 0;
  double load = 0.0;
  bool holds = false;
  bool hand_full = false;
};

Result run(const Options& opt, int n, const server::sim::HandModel* hand) {
  const fs::path dir =
      fs::temp_directory_path() /
      ("telehand-bench-capacity-" + std::to_string(getpid()) + "-" + std::to_string(n));
  fs::remove_all(dir);
  fs::create_directories(dir);
  Result r;
  r.sessions = n;
  {
    ServerConfig config;
    config.db_path = (dir / "telehand.db").string();
    config.cases_dir = std::string(TELEHAND_DEPLOY_DIR) + "/cases";
    config.max_sessions = std::max(config.max_sessions, n);
    server::store::SqliteStore store(config.db_path);
    CountingOutbox out;
    server::session::SessionManager manager(store, out, config, hand);
    manager.setHandSlice(static_cast<int64_t>(opt.hand_slice_ms * 1e6));
    manager.setHandShare(opt.hand_share);

    // The pinch: one cycle of 1,000 samples' grips (3 periods of 3 Hz), shared by all.
    std::vector<Client> clients(static_cast<std::size_t>(n));
    for (int i = 0; i < n; ++i) {
      telehand_msg_SessionCommand c{};
      c.client_id = static_cast<uint64_t>(i + 1);
      c.request_seq = 1;
      c.kind = telehand_msg_CMD_OPEN;
      c.mode = telehand_msg_MODE_MOBILIZATION;
      copyString(c.case_name, opt.case_name);
      copyString(c.user, "student");
      const std::size_t before = out.statuses.size();
      manager.onCommand(c, now());
      if (out.statuses.size() == before) {
        std::fprintf(stderr, "session %d did not open\n", i);
        std::exit(1);
      }
      Client& cl = clients[static_cast<std::size_t>(i)];
      cl.session_id = out.statuses.back().session_id;
      cl.offset_ns = static_cast<int64_t>(i) * kMs / n;
      cl.phase = (i * 37) % 1000;
    }
    const auto params = fromWire(out.models.back(), nullptr);
    const JointModel joint(*params);
    std::vector<telehand_msg_DeviceState> cycle(1000);
    for (int k = 0; k < 1000; ++k) {
      const double t = k * 1e-3;
      const Vec3 a(degToRad(50.0 + 15.0 * std::sin(2 * kPi * 3.0 * t)), degToRad(2.0),
                   degToRad(1.0));
      telehand_msg_DeviceState& d = cycle[static_cast<std::size_t>(k)];
      d = telehand_msg_DeviceState{};
      d.model_version = 1;
      d.flags = sample_flags::kSentLive;
      telehand::test::setGrip(d, joint, a);
      d.fingers[0].normal_n = d.fingers[1].normal_n = 14.0f;
    }

    const uint64_t per_session = static_cast<uint64_t>(opt.seconds) * 1000;
    r.expected = per_session * static_cast<uint64_t>(n);
    r.steps_due = r.expected;
    std::deque<PendingChunk> chunks;
    std::vector<int64_t> chunk_lag, live_lag;
    chunk_lag.reserve(r.expected / kChunk + 16);
    live_lag.reserve(r.expected + 16);
    const uint64_t warm_samples = static_cast<uint64_t>(opt.warmup) * 1000;
    const int64_t t0 = now() + 20 * kMs;
    const int64_t warm_end = t0 + static_cast<int64_t>(warm_samples) * kMs;
    bool measuring = false;
    sleepUntil(t0);
    std::size_t rr = 0;  // where the round-robin take of live samples starts
    const auto arrive = [&](int64_t t) {
      // Every sample due by t arrives: into its session's live reader (the oldest overwritten
      // past the history's depth) and its client's next chunk.
      for (std::size_t i = 0; i < clients.size(); ++i) {
        Client& cl = clients[i];
        while (cl.next_seq < per_session &&
               t0 + cl.offset_ns + static_cast<int64_t>(cl.next_seq) * kMs <= t) {
          telehand_msg_DeviceState d =
              cycle[(cl.next_seq + static_cast<uint64_t>(cl.phase)) % 1000];
          d.session_id = cl.session_id;
          d.seq = cl.next_seq;
          d.source_time_ns = t0 + cl.offset_ns + static_cast<int64_t>(cl.next_seq) * kMs;
          if (cl.live.size() == kLiveDepth) {
            cl.live.pop_front();
            if (measuring) ++r.live_overwritten;
          }
          cl.live.push_back(d);
          cl.chunk.push_back(d);
          ++cl.next_seq;
          if (cl.chunk.size() == kChunk) {
            chunks.push_back({i, d.source_time_ns, cl.chunk_seq++, std::move(cl.chunk)});
            cl.chunk.clear();
            cl.chunk.reserve(kChunk);
          }
        }
      }
    };
    const auto nextDue = [&]() {
      int64_t next = INT64_MAX;
      for (const Client& cl : clients) {
        if (cl.next_seq < per_session) {
          next = std::min(next, t0 + cl.offset_ns + static_cast<int64_t>(cl.next_seq) * kMs);
        }
      }
      return next;
    };
    const auto takeChunks = [&](std::size_t max) {
      std::size_t taken = 0;
      while (!chunks.empty() && taken < max) {
        PendingChunk& p = chunks.front();
        telehand_msg_RecordChunk c{};
        c.session_id = clients[p.client].session_id;
        c.chunk_seq = p.chunk_seq;
        c.samples._buffer = p.samples.data();
        c.samples._length = static_cast<uint32_t>(p.samples.size());
        c.samples._maximum = c.samples._length;
        manager.onChunk(c, now());
        if (measuring) chunk_lag.push_back(now() - p.ready_ns);
        chunks.pop_front();
        ++taken;
      }
      return taken;
    };
    const auto takeLive = [&](std::size_t max) {
      std::size_t taken = 0, empty = 0;
      while (taken < max && empty < clients.size()) {
        Client& cl = clients[rr];
        rr = (rr + 1) % clients.size();
        if (cl.live.empty()) {
          ++empty;
          continue;
        }
        empty = 0;
        const int64_t t = now();
        if (measuring) live_lag.push_back(t - cl.live.front().source_time_ns);
        manager.onDeviceState(cl.live.front(), t);
        cl.live.pop_front();
        ++taken;
      }
      r.live_taken += taken;
      return taken;
    };
    int64_t cpu0 = 0, t_measure = 0;
    uint64_t steps0 = 0, hands0 = 0, live0 = 0, skipped0 = 0;
    while (true) {
      const int64_t t = now();
      if (!measuring && t >= warm_end) {
        // The first seconds of a session wake every finger of its hand (docs/performance.md
        // "The authoritative hand"): the figures are the steady state's, after them.
        measuring = true;
        cpu0 = cpuNs();
        t_measure = t;
        steps0 = manager.stats().hand_steps;
        skipped0 = manager.stats().hand_samples_skipped;
        hands0 = out.hand_states;
        live0 = r.live_taken;
      }
      arrive(t);
      const std::size_t took = takeChunks(kChunkBatch) +
                               takeLive(opt.hand_slice_ms > 0.0 ? kDeferredLiveBatch : kLiveBatch);
      manager.tick(now());
      // As ServerLink::serve: sleep when nothing arrived, no longer than the hands' budget
      // allows while they have samples waiting.
      const int64_t hand_wait = manager.handWaitNs(now());
      if (took == 0 && hand_wait != 0) {
        const int64_t next = nextDue();
        if (next == INT64_MAX && chunks.empty() && hand_wait < 0) break;
        int64_t until = now() + 2 * kMs;
        if (next != INT64_MAX) until = std::min(until, next);
        if (hand_wait > 0) until = std::min(until, now() + hand_wait);
        sleepUntil(until);
      }
    }
    const int64_t cpu_run = cpuNs() - cpu0;
    const int64_t wall_run = std::max<int64_t>(now() - t_measure, 1);
    r.recorded_in_run = manager.stats().recorded_samples;
    const uint64_t measured = static_cast<uint64_t>(n) * (per_session - warm_samples);
    r.steps_due = measured;
    r.steps = manager.stats().hand_steps - steps0;
    r.skipped = manager.stats().hand_samples_skipped - skipped0;
    r.hand_hz =
        static_cast<double>(out.hand_states - hands0) / n / (static_cast<double>(wall_run) * 1e-9);
    r.cpu_share = static_cast<double>(cpu_run) / static_cast<double>(wall_run);
    r.cpu_us_per_sample = static_cast<double>(cpu_run) * 1e-3 / static_cast<double>(measured);
    (void)live0;
    // Drain: whatever the readers still hold, then every client closes.
    arrive(INT64_MAX);
    for (auto& cl : clients) {
      if (!cl.chunk.empty()) {
        const std::size_t i = static_cast<std::size_t>(&cl - clients.data());
        chunks.push_back({i, now(), cl.chunk_seq++, std::move(cl.chunk)});
      }
    }
    takeChunks(SIZE_MAX);
    for (const auto& cl : clients) {
      telehand_msg_SessionCommand c{};
      c.kind = telehand_msg_CMD_CLOSE;
      c.session_id = cl.session_id;
      c.client_id = static_cast<uint64_t>(&cl - clients.data() + 1);
      c.samples_sent = per_session;
      manager.onCommand(c, now());
    }
    for (int i = 0; i < 100 && manager.activeSessions() > 0; ++i) {
      manager.tick(now());
      sleepUntil(now() + 10 * kMs);
    }
    r.recorded = manager.stats().recorded_samples;
    for (const auto& cl : clients) {
      if (const auto info = store.session(cl.session_id)) r.stored += info->samples;
    }
    r.chunk_p50 = quantileMs(chunk_lag, 0.5);
    r.chunk_p99 = quantileMs(chunk_lag, 0.99);
    r.chunk_max = maxMs(chunk_lag);
    r.live_p50 = quantileMs(live_lag, 0.5);
    r.live_p99 = quantileMs(live_lag, 0.99);
    r.live_max = maxMs(live_lag);
  }
  fs::remove_all(dir);
  r.load = loadAverage();
  r.holds = r.stored == r.expected && r.chunk_p99 <= kChunkLagOkMs;
  r.hand_full = r.live_overwritten == 0 && r.skipped == 0 && r.steps >= r.steps_due * 99 / 100 &&
                r.live_p99 <= kLiveLagOkMs;
  return r;
}

std::vector<int> parseList(const std::string& s) {
  std::vector<int> out;
  std::size_t a = 0;
  while (a <= s.size()) {
    const std::size_t b = std::min(s.find(',', a), s.size());
    if (b > a) out.push_back(std::stoi(s.substr(a, b - a)));
    a = b + 1;
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  Options opt;
  int i = 1;
  try {
    for (; i < argc; ++i) {
      const std::string a = argv[i];
      auto next = [&]() -> std::string {
        if (i + 1 >= argc) {
          std::fprintf(stderr, "%s needs a value\n", a.c_str());
          std::exit(2);
        }
        return argv[++i];
      };
      if (a == "--sessions") {
        opt.sessions = parseList(next());
      } else if (a == "--seconds") {
        opt.seconds = std::stoi(next());
      } else if (a == "--hand-slice-ms") {
        opt.hand_slice_ms = std::stod(next());
      } else if (a == "--hand-share") {
        opt.hand_share = std::stod(next());
      } else if (a == "--warmup") {
        opt.warmup = std::stoi(next());
      } else if (a == "--cpu") {
        opt.cpu = std::stoi(next());
      } else if (a == "--no-hand") {
        opt.hand = false;
      } else if (a == "--case") {
        opt.case_name = next();
      } else if (a == "--quick") {
        opt.sessions = {4};
        opt.seconds = 3;
        opt.warmup = 1;
      } else {
        const bool help = a == "--help" || a == "-h";
        if (!help) std::fprintf(stderr, "unknown option '%s'\n", a.c_str());
        std::fprintf(help ? stdout : stderr,
                     "usage: %s [--sessions 16,32,48,64] [--seconds 13] [--warmup 3] [--cpu K] "
                     "[--hand-slice-ms MS] [--hand-share F] [--no-hand] [--case NAME] [--quick]\n"
                     "N sessions of 1 kHz samples through one SessionManager pinned to one core: "
                     "recorded / sent, lateness, the hands' steps (docs/performance.md "
                     "\"Capacity\")\n",
                     argv[0]);
        return help ? 0 : 2;
      }
    }
  } catch (const std::exception&) {
    // std::stoi/stod on what followed an option.
    std::fprintf(stderr, "telehand_bench_capacity: bad value '%s' for %s\n", argv[i], argv[i - 1]);
    return 2;
  }
  spdlog::set_level(spdlog::level::warn);
  // One core: the serving thread and everything it calls (SQLite, Bullet) on it.
  const int ncpu = static_cast<int>(sysconf(_SC_NPROCESSORS_ONLN));
  const int cpu = opt.cpu >= 0 ? opt.cpu : ncpu - 1;
  cpu_set_t set;
  CPU_ZERO(&set);
  CPU_SET(cpu, &set);
  if (sched_setaffinity(0, sizeof set, &set) != 0) {
    std::perror("sched_setaffinity");
    return 1;
  }
  std::unique_ptr<server::sim::HandModel> hand;
  if (opt.hand) {
    hand = std::make_unique<server::sim::HandModel>(
        server::sim::HandModel::load(std::string(TELEHAND_DEPLOY_DIR) + "/hand/hand24.urdf"));
  }
  std::printf(
      "capacity: case '%s', pinch 50 +/- 15 deg at 3 Hz, %d s per row, 1 kHz live + 100-sample "
      "chunks per session, SQLite, %s, hand slice %g ms (0: with each sample) within %g of the "
      "thread, pinned to CPU %d "
      "of %d; figures after the first %d s\n",
      opt.case_name.c_str(), opt.seconds, opt.hand ? "Bullet hand" : "no hand", opt.hand_slice_ms,
      opt.hand_share, cpu, ncpu, opt.warmup);
  std::printf("%8s | %-26s | %-24s | %-24s | %-11s | %-18s | %12s | %8s | %-15s | %5s | %s\n",
              "sessions", "recorded (in run) / sent", "chunk lag p50/p99/max ms",
              "live lag p50/p99/max ms", "live lost", "hand steps / due", "stepped over",
              "HandSt/s", "CPU us/sample", "load", "record / hand");
  bool all = true;
  for (const int n : opt.sessions) {
    const Result r = run(opt, n, hand.get());
    std::printf(
        "%8d | %9llu (%9llu) / %9llu | %6.1f / %6.1f / %7.1f | %6.1f / %6.1f / %7.1f | %11llu | "
        "%8llu (%5.1f %%) | %12llu | %8.1f | %6.2f (%3.0f %%) | %5.2f | %s / %s\n",
        r.sessions, static_cast<unsigned long long>(r.stored),
        static_cast<unsigned long long>(r.recorded_in_run),
        static_cast<unsigned long long>(r.expected), r.chunk_p50, r.chunk_p99, r.chunk_max,
        r.live_p50, r.live_p99, r.live_max, static_cast<unsigned long long>(r.live_overwritten),
        static_cast<unsigned long long>(r.steps),
        100.0 * static_cast<double>(r.steps) / static_cast<double>(r.steps_due),
        static_cast<unsigned long long>(r.skipped), r.hand_hz, r.cpu_us_per_sample,
        100.0 * r.cpu_share, r.load, r.holds ? "holds" : "BEHIND",
        r.hand_full ? "full" : "degraded");
    std::fflush(stdout);
    if (r.stored != r.expected) all = false;
  }
  if (!all) std::printf("RECORD INCOMPLETE\n");
  return 0;
}
