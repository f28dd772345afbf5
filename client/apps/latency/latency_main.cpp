// telehand-latency: the loopback latency probe. Sends DeviceState-sized samples at a fixed
// rate through an echo (the server's, or a child process of its own), reports one-way
// latency as RTT/2 the way ddsperf does, and can run Cyclone's ddsperf ping-pong at the same
// size and rate afterwards so that the README's figures come with their baseline.
#include <dds/ddsi/ddsi_cdrstream.h>
#include <fcntl.h>
#include <poll.h>
#include <pthread.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>
#include <random>
#include <sstream>
#include <thread>

#include "telehand/core/clock.h"
#include "telehand/protocol/dds.h"

extern char** environ;

namespace {
using namespace std::chrono_literals;
using telehand::Error;
using Sample = telehand_msg_DeviceState;

constexpr int kExitError = 2;
constexpr int kExitInterrupted = 130;
constexpr auto kAutoEchoWait = 2s;    // a server echo must answer within 2 s, or one is started
constexpr auto kServerEchoWait = 5s;  // --echo server was asked for: allow slower discovery
constexpr auto kSelfEchoWait = 10s;   // includes exec and the child's domain start-up
constexpr auto kDrain = 500ms;        // after the last ping: later pongs count as lost
constexpr auto kChildGrace = 2s;      // SIGTERM to SIGKILL
constexpr double kDdsperfInitWaitS = 10.0;
constexpr uint32_t kDdsperfMinSize = 12;  // KS topic: seq, key, octet-sequence length

std::atomic<bool> g_stop{false};
void onSignal(int) { g_stop.store(true); }

int64_t monoNs() noexcept { return telehand::SteadyClock{}.nowNs(); }

std::string fmt(const char* f, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, f, v);
  return buf;
}

struct Settings {
  double seconds = 10.0;
  double rate_hz = 1000.0;
  double warmup_s = 1.0;
  std::string echo = "auto";
  bool echo_only = false;
  bool compare = false;
  bool quiet = false;
  std::string ddsperf = "ddsperf";
  std::string json_path;
  std::string dds_config;  // as given, for messages and the self echo's command line
  telehand::dds::Options dds;
};

/// Percentiles of one-way latency in µs. Ranks follow ddsperf (the value at n - ceil(n/k)
/// in ascending order for the 1/k tail) so that both tools' numbers mean the same thing.
struct Summary {
  std::size_t count = 0;
  double p50_us = 0, p90_us = 0, p99_us = 0, p999_us = 0, max_us = 0, mean_us = 0;
};

double tailUs(const std::vector<int64_t>& sorted_rtt, std::size_t k) {
  const std::size_t n = sorted_rtt.size();
  return static_cast<double>(sorted_rtt[n - (n + k - 1) / k]) / 2e3;
}

Summary summarize(std::vector<int64_t>& rtt_ns) {
  Summary s;
  s.count = rtt_ns.size();
  if (rtt_ns.empty()) return s;
  std::sort(rtt_ns.begin(), rtt_ns.end());
  double sum = 0;
  for (int64_t r : rtt_ns) sum += static_cast<double>(r);
  s.p50_us = tailUs(rtt_ns, 2);
  s.p90_us = tailUs(rtt_ns, 10);
  s.p99_us = tailUs(rtt_ns, 100);
  s.p999_us = tailUs(rtt_ns, 1000);
  s.max_us = static_cast<double>(rtt_ns.back()) / 2e3;
  s.mean_us = sum / static_cast<double>(rtt_ns.size()) / 2e3;
  return s;
}

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const std::size_t m = v.size() / 2;
  return v.size() % 2 ? v[m] : (v[m - 1] + v[m]) / 2;
}

/// Aggregates per-second summaries as this tool does for ddsperf: median over seconds of
/// p50/p90/p99/mean, maximum of max, total count.
Summary aggregateSeconds(const std::vector<Summary>& secs) {
  Summary a;
  std::vector<double> p50, p90, p99, mean;
  for (const auto& s : secs) {
    p50.push_back(s.p50_us);
    p90.push_back(s.p90_us);
    p99.push_back(s.p99_us);
    mean.push_back(s.mean_us);
    a.max_us = std::max(a.max_us, s.max_us);
    a.count += s.count;
  }
  a.p50_us = median(p50);
  a.p90_us = median(p90);
  a.p99_us = median(p99);
  a.mean_us = median(mean);
  return a;
}

/// A child process started with fork+exec and ended by its PID only. It dies with us
/// (PR_SET_PDEATHSIG), so a killed probe leaves no echo or ddsperf behind.
class Child {
 public:
  Child(std::string name, const std::vector<std::string>& argv, const std::vector<std::string>& env,
        int out_fd)
      : name_(std::move(name)) {
    // Everything the child touches is prepared before fork: only async-signal-safe calls
    // are allowed between fork and exec in a process that already runs DDS threads.
    std::vector<char*> args, envp;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    for (const auto& e : env) envp.push_back(const_cast<char*>(e.c_str()));
    envp.push_back(nullptr);
    const int null_fd = open("/dev/null", O_RDONLY | O_CLOEXEC);
    int exec_err[2];
    if (null_fd < 0 || pipe2(exec_err, O_CLOEXEC) != 0) {
      throw Error("cannot start " + name_ + ": " + std::strerror(errno));
    }
    const pid_t parent = getpid();
    pid_ = fork();
    if (pid_ == 0) {
      prctl(PR_SET_PDEATHSIG, SIGTERM);
      if (getppid() != parent) _exit(127);
      dup2(null_fd, STDIN_FILENO);
      if (out_fd >= 0) {
        dup2(out_fd, STDOUT_FILENO);
        dup2(out_fd, STDERR_FILENO);
      }
      execve(args[0], args.data(), envp.data());
      const int e = errno;
      [[maybe_unused]] const ssize_t w = write(exec_err[1], &e, sizeof e);
      _exit(127);
    }
    const int fork_errno = errno;
    close(null_fd);
    close(exec_err[1]);
    if (pid_ < 0) {
      close(exec_err[0]);
      throw Error("cannot fork " + name_ + ": " + std::strerror(fork_errno));
    }
    int e = 0;
    ssize_t n;
    do n = read(exec_err[0], &e, sizeof e);
    while (n < 0 && errno == EINTR);
    close(exec_err[0]);
    if (n > 0) {  // exec failed; the child has exited already
      waitpid(pid_, &status_, 0);
      pid_ = -1;
      throw Error("cannot run " + argv[0] + ": " + std::strerror(e));
    }
  }
  Child(const Child&) = delete;
  Child& operator=(const Child&) = delete;
  ~Child() { stop(); }

  pid_t pid() const noexcept { return pid_; }
  const std::string& name() const noexcept { return name_; }

  /// True while it runs; reaps it otherwise.
  bool alive() {
    if (pid_ <= 0) return false;
    if (waitpid(pid_, &status_, WNOHANG) == pid_) pid_ = -1;
    return pid_ > 0;
  }

  /// SIGTERM, then SIGKILL after `grace`. Returns the wait status.
  int stop(std::chrono::milliseconds grace = kChildGrace) {
    if (!alive()) return status_;
    kill(pid_, SIGTERM);
    const int64_t deadline = monoNs() + grace.count() * telehand::kNsPerMs;
    while (monoNs() < deadline) {
      if (!alive()) return status_;
      std::this_thread::sleep_for(10ms);
    }
    std::cerr << "telehand-latency: " << name_ << " (pid " << pid_
              << ") ignored SIGTERM; sending SIGKILL\n";
    kill(pid_, SIGKILL);
    waitpid(pid_, &status_, 0);
    pid_ = -1;
    return status_;
  }

  std::string describeExit() const {
    if (WIFEXITED(status_)) return "exited with status " + std::to_string(WEXITSTATUS(status_));
    if (WIFSIGNALED(status_)) return std::string("killed by ") + strsignal(WTERMSIG(status_));
    return "ended";
  }
  bool exitedOk() const noexcept { return WIFEXITED(status_) && WEXITSTATUS(status_) == 0; }

 private:
  std::string name_;
  pid_t pid_ = -1;
  int status_ = 0;
};

/// The environment for a child, with CYCLONEDDS_URI replaced when a config was given, so that
/// ddsperf joins the same network set-up as telehand did.
std::vector<std::string> childEnv(const std::string& dds_uri) {
  std::vector<std::string> env;
  for (char** e = environ; *e; ++e) {
    if (!dds_uri.empty() && std::strncmp(*e, "CYCLONEDDS_URI=", 15) == 0) continue;
    env.emplace_back(*e);
  }
  if (!dds_uri.empty()) env.push_back("CYCLONEDDS_URI=" + dds_uri);
  return env;
}

/// The config as Cyclone's URI: inline XML stays as is, a file becomes file://ABSOLUTE.
std::string configUri(const std::string& config) {
  if (config.empty() || config.front() == '<') return config;
  return "file://" + std::filesystem::absolute(config).string();
}

/// Resolves a program name through PATH as execvp would.
std::optional<std::string> findProgram(const std::string& name) {
  if (name.find('/') != std::string::npos) {
    return access(name.c_str(), X_OK) == 0 ? std::optional(name) : std::nullopt;
  }
  const char* path = std::getenv("PATH");
  std::stringstream dirs(path ? path : "/usr/bin:/bin");
  std::string dir;
  while (std::getline(dirs, dir, ':')) {
    const std::string full = (dir.empty() ? "." : dir) + "/" + name;
    if (access(full.c_str(), X_OK) == 0) return full;
  }
  return std::nullopt;
}

/// Serialized payload size of a DeviceState as Cyclone writes it (without the 4-byte
/// encapsulation header), to show that "DeviceState-sized" means the same on the wire.
uint32_t serializedSize(const Sample& s, uint32_t* xcdr_version) {
  const uint32_t* ops = telehand_msg_DeviceState_desc.m_ops;
  *xcdr_version = dds_stream_minimum_xcdr_version(ops);
  dds_ostream_t os;
  dds_ostream_init(&os, 0, *xcdr_version);
  dds_stream_write(&os, reinterpret_cast<const char*>(&s), ops);
  const uint32_t n = os.m_index;
  dds_ostream_fini(&os);
  return n;
}

/// Prints a progress line to stderr at most once a second.
class Progress {
 public:
  explicit Progress(bool quiet) : quiet_(quiet), tty_(isatty(STDERR_FILENO) != 0) {}
  void line(const std::string& text) {
    if (quiet_) return;
    std::cerr << (tty_ ? "\r\033[K" : "") << text << (tty_ ? "" : "\n") << std::flush;
    dirty_ = tty_;
  }
  void done() {
    if (dirty_) std::cerr << "\n";
    dirty_ = false;
  }

 private:
  bool quiet_, tty_, dirty_ = false;
};

// ---------------------------------------------------------------------------------------
// Echo

/// --echo-only: answer every ping with the same sample on the pong topic.
int runEcho(const Settings& s, bool seconds_given) {
  namespace dds = telehand::dds;
  dds::Participant participant(s.dds);
  dds::Topic<Sample> ping_topic(participant, dds::topic::kLatencyPing);
  dds::Topic<Sample> pong_topic(participant, dds::topic::kLatencyPong);
  dds::Reader<Sample> ping_reader(participant, ping_topic, dds::qos::latencyProbe());
  dds::Writer<Sample> pong_writer(participant, pong_topic, dds::qos::latencyProbe());
  dds::WaitSet waitset(participant);
  waitset.attach(ping_reader.handle(), 1);
  if (!s.quiet) {
    std::cerr << "telehand-latency: echoing on domain " << s.dds.domain << ", partition '"
              << s.dds.partition << "' "
              << (seconds_given ? fmt("for %g s", s.seconds) : "until SIGINT/SIGTERM") << "\n";
  }
  const int64_t end_ns =
      seconds_given ? monoNs() + static_cast<int64_t>(s.seconds * 1e9) : INT64_MAX;
  uint64_t echoes = 0, write_errors = 0;
  // A 100 ms timeout bounds how long a signal waits to be seen; data wakes the waitset.
  while (!g_stop.load() && monoNs() < end_ns) {
    waitset.wait(100ms);
    echoes += ping_reader.take([&](const Sample& x, const dds_sample_info_t&) {
      if (pong_writer.write(x) < 0) ++write_errors;
    });
  }
  if (!s.quiet) {
    std::cerr << "telehand-latency: echo stopped after " << echoes << " echoes, " << write_errors
              << " write errors\n";
  }
  return 0;
}

// ---------------------------------------------------------------------------------------
// Pinger

struct PingResult {
  double load_at_start = 0;  // 1-minute load average: context for the figures
  std::string echo_desc;
  std::string partition;
  uint64_t warmup_pings = 0;
  uint64_t planned = 0;  // measured pings planned
  uint64_t sent = 0;     // measured pings sent
  uint64_t received = 0;
  uint64_t late = 0;  // RTT longer than one period
  uint64_t duplicates = 0;
  uint64_t foreign = 0;  // pongs of another run or outside the sequence range
  uint64_t write_errors = 0;
  uint64_t overruns = 0;  // pinger woke more than one period late
  double wake_p99_us = 0, wake_max_us = 0;
  double measured_s = 0;
  bool interrupted = false;
  Summary pooled;
  Summary per_second;  // aggregated like ddsperf's output, for the comparison
  std::size_t seconds_count = 0;
};

/// Waits until the ping writer reaches a reader and the pong reader a writer.
bool awaitEcho(const telehand::dds::Writer<Sample>& ping, const telehand::dds::Reader<Sample>& pong,
               std::chrono::milliseconds timeout, Child* child) {
  const int64_t deadline = monoNs() + timeout.count() * telehand::kNsPerMs;
  while (monoNs() < deadline && !g_stop.load()) {
    if (ping.matchedReaders() > 0 && pong.matchedWriters() > 0) return true;
    if (child && !child->alive()) {
      throw Error("the self echo (" + child->name() + ") " + child->describeExit() +
                  " before it matched");
    }
    std::this_thread::sleep_for(10ms);
  }
  return false;
}

PingResult runPinger(const Settings& s, Progress& progress) {
  namespace dds = telehand::dds;
  PingResult r;
  const int64_t period_ns = static_cast<int64_t>(std::llround(1e9 / s.rate_hz));
  r.warmup_pings = static_cast<uint64_t>(std::llround(s.warmup_s * s.rate_hz));
  r.planned = static_cast<uint64_t>(std::llround(s.seconds * s.rate_hz));
  const uint64_t total = r.warmup_pings + r.planned;

  // A random key per run: pongs of another probe sharing the partition are told apart.
  std::random_device rd;
  const uint64_t run_id = (static_cast<uint64_t>(rd()) << 32) | rd();

  struct Endpoints {
    dds::Participant participant;
    dds::Topic<Sample> ping_topic{participant, dds::topic::kLatencyPing};
    dds::Topic<Sample> pong_topic{participant, dds::topic::kLatencyPong};
    dds::Writer<Sample> ping{participant, ping_topic, dds::qos::latencyProbe()};
    dds::Reader<Sample> pong{participant, pong_topic, dds::qos::latencyProbe()};
    explicit Endpoints(const dds::Options& o) : participant(o) {}
  };
  std::optional<Endpoints> ep;
  std::optional<Child> echo_child;

  if (s.echo != "self") {
    ep.emplace(s.dds);
    const auto wait = s.echo == "server" ? kServerEchoWait : kAutoEchoWait;
    if (awaitEcho(ep->ping, ep->pong, wait, nullptr)) {
      r.echo_desc = "external (telehand-server or telehand-latency --echo-only)";
      r.partition = s.dds.partition;
      if (ep->ping.matchedReaders() > 1) {
        std::cerr << "telehand-latency: warning: " << ep->ping.matchedReaders()
                  << " echoes answer on this partition; duplicate pongs are ignored\n";
      }
    } else if (s.echo == "server") {
      throw Error("no echo matched within " + std::to_string(kServerEchoWait.count()) +
                  " s on domain " + std::to_string(s.dds.domain) + ", partition '" +
                  s.dds.partition +
                  "': start telehand-server with the same --domain/--partition/--dds-config, "
                  "or use --echo self");
    } else {
      ep.reset();
    }
  }
  if (!ep) {
    if (g_stop.load()) throw Error("interrupted");
    // A private partition keeps a server or another probe from answering or listening.
    dds::Options o = s.dds;
    o.partition = s.dds.partition + ".latency-" + std::to_string(getpid());
    std::vector<std::string> argv = {
        "/proc/self/exe",         "--echo-only", "--quiet",  "--domain",
        std::to_string(o.domain), "--partition", o.partition};
    if (!s.dds_config.empty()) {
      argv.push_back("--dds-config");
      argv.push_back(s.dds_config);
    }
    echo_child.emplace("self echo", argv, childEnv(""), -1);
    ep.emplace(o);
    if (!awaitEcho(ep->ping, ep->pong, kSelfEchoWait, &*echo_child)) {
      if (g_stop.load()) throw Error("interrupted");
      throw Error("the self echo (pid " + std::to_string(echo_child->pid()) +
                  ") did not match within " + std::to_string(kSelfEchoWait.count()) +
                  " s; check --dds-config and the network");
    }
    r.echo_desc =
        "self (telehand-latency --echo-only, pid " + std::to_string(echo_child->pid()) + ")";
    r.partition = o.partition;
  }

  // Preallocated: the receiver stores each measured RTT at its sequence number.
  std::vector<int64_t> rtt_ns(r.planned, -1);
  std::vector<int64_t> wake_late_ns(total, 0);
  std::atomic<uint64_t> sent{0}, received{0}, duplicates{0}, foreign{0};
  std::atomic<int64_t> window_max_rtt{0};
  std::atomic<bool> receiving{true};
  dds::GuardCondition wake_guard(ep->participant);

  const uint64_t warmup = r.warmup_pings;
  std::string receiver_error;  // read only after join
  std::thread receiver([&] {
    pthread_setname_np(pthread_self(), "lat-recv");
    prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);
    try {
      dds::WaitSet ws(ep->participant);
      ws.attach(ep->pong.handle(), 1);
      ws.attach(wake_guard.handle(), 2);
      while (receiving.load(std::memory_order_acquire)) {
        ws.wait(100ms);
        ep->pong.take([&](const Sample& x, const dds_sample_info_t&) {
          const int64_t now = monoNs();
          if (x.session_id != run_id || x.seq >= total) {
            foreign.fetch_add(1, std::memory_order_relaxed);
            return;
          }
          if (x.seq < warmup) return;
          int64_t& slot = rtt_ns[x.seq - warmup];
          if (slot >= 0) {
            duplicates.fetch_add(1, std::memory_order_relaxed);
            return;
          }
          slot = now - x.source_time_ns;
          received.fetch_add(1, std::memory_order_relaxed);
          int64_t m = window_max_rtt.load(std::memory_order_relaxed);
          while (slot > m && !window_max_rtt.compare_exchange_weak(m, slot)) {
          }
        });
      }
    } catch (const std::exception& e) {
      receiver_error = e.what();
      g_stop.store(true);  // ends the pinger; the error is reported after the join
    }
  });

  std::atomic<bool> pinging{true};
  uint64_t write_errors = 0, overruns = 0;
  std::thread pinger([&] {
    pthread_setname_np(pthread_self(), "lat-ping");
    // The default 50 µs slack makes a 1 kHz sleep wake ~84 µs late on these VMs (docs/facts.md).
    prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);
    Sample x{};
    x.session_id = run_id;
    int64_t start = monoNs() + period_ns;
    for (uint64_t seq = 0; seq < total && !g_stop.load(std::memory_order_relaxed); ++seq) {
      const int64_t due = start + static_cast<int64_t>(seq) * period_ns;
      const timespec ts{static_cast<time_t>(due / telehand::kNsPerS),
                        static_cast<long>(due % telehand::kNsPerS)};
      while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
      }
      const int64_t now = monoNs();
      wake_late_ns[seq] = now - due;
      if (now - due > period_ns) {
        // Re-anchor instead of sending a burst to catch up: a burst would measure queueing.
        ++overruns;
        start += now - due;
      }
      x.seq = seq;
      // Monotonic, not the IDL's realtime: only this process reads it back, and RTT must not
      // jump with NTP.
      x.source_time_ns = monoNs();
      if (ep->ping.write(x) < 0) ++write_errors;
      sent.store(seq + 1, std::memory_order_release);
    }
    pinging.store(false, std::memory_order_release);
  });

  getloadavg(&r.load_at_start, 1);
  const int64_t t0 = monoNs();
  const double total_s = s.warmup_s + s.seconds;
  int64_t next_report = t0 + telehand::kNsPerS;
  while (pinging.load(std::memory_order_acquire)) {
    std::this_thread::sleep_for(20ms);
    if (monoNs() < next_report) continue;
    next_report += telehand::kNsPerS;
    const uint64_t n = sent.load();
    const double t = static_cast<double>(monoNs() - t0) / 1e9;
    char line[160];
    std::snprintf(line, sizeof line,
                  "telehand-latency: %5.1f/%.0f s  %s  sent %llu  pongs %llu  max one-way %.0f us",
                  t, total_s, n < r.warmup_pings ? "warm-up" : "measure",
                  static_cast<unsigned long long>(n > r.warmup_pings ? n - r.warmup_pings : 0),
                  static_cast<unsigned long long>(received.load()),
                  static_cast<double>(window_max_rtt.exchange(0)) / 2e3);
    progress.line(line);
  }
  pinger.join();
  r.measured_s = std::max(0.0, static_cast<double>(monoNs() - t0) / 1e9 - s.warmup_s);
  // Pongs still in flight get a bounded time to arrive; whatever is missing then is lost.
  const uint64_t sent_total = sent.load();
  r.sent = sent_total > r.warmup_pings ? sent_total - r.warmup_pings : 0;
  const int64_t drain_end = monoNs() + std::chrono::nanoseconds(kDrain).count();
  while (received.load() < r.sent && monoNs() < drain_end) std::this_thread::sleep_for(5ms);
  receiving.store(false, std::memory_order_release);
  wake_guard.trigger();
  receiver.join();
  progress.done();
  if (!receiver_error.empty()) throw Error("pong receiver failed: " + receiver_error);
  r.interrupted = g_stop.load();
  r.write_errors = write_errors;
  r.overruns = overruns;
  r.duplicates = duplicates.load();
  r.foreign = foreign.load();

  if (echo_child) {
    echo_child->stop();
    if (!echo_child->exitedOk()) {
      std::cerr << "telehand-latency: warning: the self echo " << echo_child->describeExit()
                << "\n";
    }
  }

  std::vector<int64_t> all;
  all.reserve(r.sent);
  const auto per_second_n = static_cast<std::size_t>(std::llround(s.rate_hz));
  std::vector<Summary> secs;
  std::vector<int64_t> bucket;
  bucket.reserve(per_second_n);
  for (std::size_t i = 0; i < r.sent; ++i) {
    if (rtt_ns[i] >= 0) {
      all.push_back(rtt_ns[i]);
      bucket.push_back(rtt_ns[i]);
      if (rtt_ns[i] > period_ns) ++r.late;
    }
    // Seconds by send index, as ddsperf reports by wall second; a short last one is dropped.
    if ((i + 1) % per_second_n == 0) {
      secs.push_back(summarize(bucket));
      bucket.clear();
    }
  }
  r.received = all.size();
  r.seconds_count = secs.size();
  r.per_second = aggregateSeconds(secs);
  r.pooled = summarize(all);
  std::vector<int64_t> wake(wake_late_ns.begin(),
                            wake_late_ns.begin() + static_cast<std::ptrdiff_t>(sent_total));
  if (!wake.empty()) {
    std::sort(wake.begin(), wake.end());
    r.wake_p99_us = static_cast<double>(wake[wake.size() - (wake.size() + 99) / 100]) / 1e3;
    r.wake_max_us = static_cast<double>(wake.back()) / 1e3;
  }
  return r;
}

// ---------------------------------------------------------------------------------------
// ddsperf

struct DdsperfResult {
  std::string pong_cmd, ping_cmd;
  std::vector<Summary> seconds;
  std::size_t warmup_lines = 0;
  std::size_t foreign_lines = 0;  // from other ddsperf pongs in the domain
  uint64_t timeouts = 0;
  Summary aggregate;
  bool interrupted = false;
};

std::string joinArgs(const std::vector<std::string>& argv) {
  std::string out;
  for (const auto& a : argv) out += (out.empty() ? "" : " ") + a;
  return out;
}

/// "12.345us" -> 12.345; accepts ns/us/ms/s in case ddsperf changes its units.
std::optional<double> parseUs(const std::string& v) {
  char* end = nullptr;
  const double x = std::strtod(v.c_str(), &end);
  const std::string unit(end);
  if (end == v.c_str()) return std::nullopt;
  if (unit == "us") return x;
  if (unit == "ns") return x / 1e3;
  if (unit == "ms") return x * 1e3;
  if (unit == "s") return x * 1e6;
  return std::nullopt;
}

/// Parses `[pid] T  host:pid size S mean Xus min Xus 50% Xus 90% Xus 99% Xus max Xus cnt N`.
/// Returns the line's time and summary if it is one of those from the pong `pong_pid`.
std::optional<std::pair<double, Summary>> parsePingLine(const std::string& line, pid_t pong_pid,
                                                        bool* foreign) {
  std::istringstream in(line);
  std::vector<std::string> tok;
  for (std::string t; in >> t;) tok.push_back(t);
  if (tok.size() < 19 || tok[3] != "size" || tok[5] != "mean") return std::nullopt;
  const std::string suffix = ":" + std::to_string(pong_pid);
  if (tok[2].size() < suffix.size() ||
      tok[2].compare(tok[2].size() - suffix.size(), suffix.size(), suffix) != 0) {
    *foreign = true;
    return std::nullopt;
  }
  Summary s;
  for (std::size_t i = 5; i + 1 < tok.size(); i += 2) {
    const std::string& k = tok[i];
    if (k == "cnt") {
      s.count = std::stoull(tok[i + 1]);
      continue;
    }
    const auto v = parseUs(tok[i + 1]);
    if (!v) return std::nullopt;
    if (k == "mean")
      s.mean_us = *v;
    else if (k == "50%")
      s.p50_us = *v;
    else if (k == "90%")
      s.p90_us = *v;
    else if (k == "99%")
      s.p99_us = *v;
    else if (k == "max")
      s.max_us = *v;
  }
  return std::pair{std::strtod(tok[1].c_str(), nullptr), s};
}

DdsperfResult runDdsperf(const Settings& s, const std::string& path, uint32_t size,
                         Progress& progress) {
  DdsperfResult r;
  const std::string domain = std::to_string(s.dds.domain);
  const double ping_s = s.warmup_s + s.seconds;
  // The pong outlives the ping (which first waits for it to match); it is stopped by PID.
  const std::vector<std::string> pong_argv = {
      path, "-i", domain, "-u", "-D", fmt("%g", ping_s + kDdsperfInitWaitS + 5), "pong"};
  const std::vector<std::string> ping_argv = {
      path,           "-i",
      domain,         "-u",
      "-Qminmatch:1", "-Qinitwait:" + fmt("%g", kDdsperfInitWaitS),
      "-D",           fmt("%g", ping_s),
      "ping",         fmt("%g", s.rate_hz) + "Hz",
      "size",         std::to_string(size)};
  r.pong_cmd = joinArgs(pong_argv);
  r.ping_cmd = joinArgs(ping_argv);
  const auto env = childEnv(configUri(s.dds_config));

  int pong_pipe[2], ping_pipe[2];
  if (pipe2(pong_pipe, O_CLOEXEC) != 0 || pipe2(ping_pipe, O_CLOEXEC) != 0) {
    throw Error(std::string("pipe: ") + std::strerror(errno));
  }
  std::string pong_out, ping_out;
  std::optional<Child> pong, ping;
  try {
    pong.emplace("ddsperf pong", pong_argv, env, pong_pipe[1]);
    ping.emplace("ddsperf ping", ping_argv, env, ping_pipe[1]);
  } catch (...) {
    for (int fd : {pong_pipe[0], pong_pipe[1], ping_pipe[0], ping_pipe[1]}) close(fd);
    throw;
  }
  close(pong_pipe[1]);
  close(ping_pipe[1]);

  // Both outputs are drained while they run so that a long run cannot block on a full pipe.
  pollfd fds[2] = {{ping_pipe[0], POLLIN, 0}, {pong_pipe[0], POLLIN, 0}};
  std::string* outs[2] = {&ping_out, &pong_out};
  const int64_t t0 = monoNs();
  const int64_t deadline = t0 + static_cast<int64_t>((ping_s + kDdsperfInitWaitS + 10) * 1e9);
  int64_t next_report = t0 + telehand::kNsPerS;
  int open_fds = 2;
  while (open_fds > 0) {
    if (g_stop.load() || monoNs() > deadline) break;
    if (poll(fds, 2, 200) < 0 && errno != EINTR) break;
    for (int i = 0; i < 2; ++i) {
      if (fds[i].fd < 0 || !(fds[i].revents & (POLLIN | POLLHUP | POLLERR))) continue;
      char buf[4096];
      const ssize_t n = read(fds[i].fd, buf, sizeof buf);
      if (n > 0) {
        outs[i]->append(buf, static_cast<std::size_t>(n));
      } else if (n == 0 || errno != EINTR) {
        close(fds[i].fd);
        fds[i].fd = -1;
        --open_fds;
      }
    }
    if (fds[0].fd < 0 && !ping->alive()) break;  // the ping is done; the pong is stopped below
    if (monoNs() >= next_report) {
      next_report += telehand::kNsPerS;
      const double t = static_cast<double>(monoNs() - t0) / 1e9;
      progress.line("telehand-latency: ddsperf ping-pong running, " + fmt("%5.1f", t) +
                    " s of about " + fmt("%.0f", ping_s + 1) + " s");
    }
  }
  progress.done();
  r.interrupted = g_stop.load();
  const bool timed_out = monoNs() > deadline;
  const pid_t pong_pid = pong->pid();  // stop() forgets it
  ping->stop();
  pong->stop();
  for (const auto& f : fds) {
    if (f.fd >= 0) close(f.fd);
  }
  if (r.interrupted) return r;
  if (timed_out) throw Error("ddsperf ping did not finish in time; its output:\n" + ping_out);
  if (!ping->exitedOk()) {
    throw Error("ddsperf ping " + ping->describeExit() + " (command: " + r.ping_cmd +
                "); its output:\n" + ping_out + "ddsperf pong output:\n" + pong_out);
  }

  std::istringstream lines(ping_out);
  for (std::string line; std::getline(lines, line);) {
    if (const auto p = line.find("total ");
        line.find("ping timed out") != std::string::npos && p != std::string::npos) {
      r.timeouts = std::max<uint64_t>(r.timeouts, std::strtoull(line.c_str() + p + 6, nullptr, 10));
      continue;
    }
    bool foreign = false;
    const auto parsed = parsePingLine(line, pong_pid, &foreign);
    if (foreign) ++r.foreign_lines;
    if (!parsed) continue;
    // Line T covers (T-1, T]: drop the warm-up seconds as for telehand's own run.
    if (parsed->first <= s.warmup_s + 1e-6) {
      ++r.warmup_lines;
      continue;
    }
    r.seconds.push_back(parsed->second);
  }
  if (r.seconds.empty()) {
    throw Error("ddsperf ping printed no latency line after the warm-up (command: " + r.ping_cmd +
                "); its output:\n" + ping_out);
  }
  r.aggregate = aggregateSeconds(r.seconds);
  return r;
}

// ---------------------------------------------------------------------------------------
// Reports

void printPing(const Settings& s, const PingResult& r, std::size_t size_of, uint32_t ser,
               uint32_t xcdr) {
  const double period_us = 1e6 / s.rate_hz;
  std::printf("telehand-latency: DeviceState round trips over Cyclone DDS\n");
  std::printf("  echo       %s\n", r.echo_desc.c_str());
  std::printf("  DDS        domain %u, partition '%s', config %s\n", s.dds.domain,
              r.partition.c_str(),
              s.dds_config.empty() ? "(Cyclone default / CYCLONEDDS_URI)" : s.dds_config.c_str());
  std::printf(
      "  sample     telehand_msg_DeviceState: sizeof %zu B, serialized %u B (XCDR%u) "
      "+ 4 B header\n",
      size_of, ser, xcdr);
  std::printf("  QoS        best-effort, keep-last 1, volatile (qos::latencyProbe)\n");
  std::printf(
      "  host       %ld CPUs online, load average %.2f at start (other load inflates "
      "the tail)\n",
      sysconf(_SC_NPROCESSORS_ONLN), r.load_at_start);
  std::printf(
      "  schedule   %g Hz for %g s after %g s warm-up (discarded); clock_nanosleep "
      "TIMER_ABSTIME, 1 ns timer slack%s\n",
      s.rate_hz, s.seconds, s.warmup_s,
      r.interrupted ? fmt("; INTERRUPTED after %.1f s", r.measured_s).c_str() : "");
  const uint64_t lost = r.sent - r.received;
  std::printf(
      "  pings      %llu sent, %llu answered, %llu lost (%.3f %%), %llu late (RTT > %g "
      "us period)\n",
      static_cast<unsigned long long>(r.sent), static_cast<unsigned long long>(r.received),
      static_cast<unsigned long long>(lost),
      r.sent ? 100.0 * static_cast<double>(lost) / static_cast<double>(r.sent) : 0.0,
      static_cast<unsigned long long>(r.late), period_us);
  std::printf(
      "  pinger     wake-up late p99 %.1f us, max %.1f us; %llu overruns, %llu write "
      "errors\n",
      r.wake_p99_us, r.wake_max_us, static_cast<unsigned long long>(r.overruns),
      static_cast<unsigned long long>(r.write_errors));
  if (r.duplicates || r.foreign) {
    std::printf("  ignored    %llu duplicate pongs, %llu pongs of other runs\n",
                static_cast<unsigned long long>(r.duplicates),
                static_cast<unsigned long long>(r.foreign));
  }
  std::printf("\none-way latency = RTT/2, us, over all %zu answered pings:\n", r.pooled.count);
  std::printf("  %9s %9s %9s %9s %9s %9s\n", "p50", "p90", "p99", "p99.9", "max", "mean");
  std::printf("  %9.1f %9.1f %9.1f %9.1f %9.1f %9.1f\n", r.pooled.p50_us, r.pooled.p90_us,
              r.pooled.p99_us, r.pooled.p999_us, r.pooled.max_us, r.pooled.mean_us);
}

void printCompare(const Settings& s, const PingResult& r, const DdsperfResult& d,
                  const std::string& path, uint32_t size) {
  std::printf("\nddsperf baseline (%s), run after telehand in the same domain and config:\n",
              path.c_str());
  std::printf("  pong       %s\n", d.pong_cmd.c_str());
  std::printf("  ping       %s\n", d.ping_cmd.c_str());
  std::printf(
      "  sample     KS topic, %u B payload (= DeviceState serialized), best-effort, "
      "keep-last 1\n",
      size);
  std::printf(
      "  reports    %zu per-second reports after %zu warm-up, %zu round trips, %llu "
      "pings timed out\n",
      d.seconds.size(), d.warmup_lines, d.aggregate.count,
      static_cast<unsigned long long>(d.timeouts));
  if (d.foreign_lines) {
    std::printf("  ignored    %zu report lines from other ddsperf pongs in domain %u\n",
                d.foreign_lines, s.dds.domain);
  }
  std::printf(
      "  method     ddsperf prints percentiles per second only, so p50/p90/p99/mean are\n"
      "             the median over seconds of each second's value and max is the\n"
      "             largest of all; telehand is aggregated the same way here (%zu s),\n"
      "             its pooled figures are above. Both: one-way = RTT/2, ddsperf's rank "
      "rule.\n"
      "  delivery   ddsperf answers and times pongs in a listener on Cyclone's receive\n"
      "             thread; telehand's echo and probe take samples on waitset threads,\n"
      "             as the product does (one thread wake-up more per direction).\n",
      r.seconds_count);
  std::printf("\n  %-14s %10s %10s %17s\n", "one-way, us", "telehand", "ddsperf",
              "telehand/ddsperf");
  const auto row = [](const char* name, double a, double b) {
    std::printf("  %-14s %10.1f %10.1f %17.2f\n", name, a, b, b > 0 ? a / b : 0.0);
  };
  row("p50", r.per_second.p50_us, d.aggregate.p50_us);
  row("p90", r.per_second.p90_us, d.aggregate.p90_us);
  row("p99", r.per_second.p99_us, d.aggregate.p99_us);
  row("max", r.per_second.max_us, d.aggregate.max_us);
  row("mean", r.per_second.mean_us, d.aggregate.mean_us);
}

void jsonSummary(std::ostream& o, const Summary& x, bool p999) {
  o << "{\"count\": " << x.count << ", \"p50_us\": " << x.p50_us << ", \"p90_us\": " << x.p90_us
    << ", \"p99_us\": " << x.p99_us;
  if (p999) o << ", \"p99_9_us\": " << x.p999_us;
  o << ", \"max_us\": " << x.max_us << ", \"mean_us\": " << x.mean_us << "}";
}

std::string jsonString(const std::string& v) {
  std::string out = "\"";
  for (char c : v) {
    if (c == '"' || c == '\\') out += '\\';
    if (static_cast<unsigned char>(c) < 0x20) {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\u%04x", static_cast<unsigned>(c));
      out += buf;
      continue;
    }
    out += c;
  }
  return out + "\"";
}

void writeJson(std::ostream& o, const Settings& s, const PingResult& r, std::size_t size_of,
               uint32_t ser, const DdsperfResult* d, uint32_t ddsperf_size) {
  o.precision(6);
  o << "{\n  \"tool\": \"telehand-latency\",\n  \"definition\": \"one-way = RTT/2\",\n"
    << "  \"settings\": {\"seconds\": " << s.seconds << ", \"rate_hz\": " << s.rate_hz
    << ", \"warmup_s\": " << s.warmup_s << ", \"domain\": " << s.dds.domain
    << ", \"partition\": " << jsonString(r.partition)
    << ", \"dds_config\": " << jsonString(s.dds_config) << "},\n"
    << "  \"host\": {\"cpus\": " << sysconf(_SC_NPROCESSORS_ONLN)
    << ", \"load_avg_1min_at_start\": " << r.load_at_start << "},\n"
    << "  \"sample\": {\"type\": \"telehand_msg_DeviceState\", \"sizeof\": " << size_of
    << ", \"serialized\": " << ser << "},\n"
    << "  \"telehand\": {\"echo\": " << jsonString(r.echo_desc)
    << ", \"interrupted\": " << (r.interrupted ? "true" : "false") << ", \"sent\": " << r.sent
    << ", \"received\": " << r.received << ", \"lost\": " << r.sent - r.received
    << ", \"late\": " << r.late << ", \"duplicates\": " << r.duplicates
    << ", \"overruns\": " << r.overruns << ", \"wake_late_p99_us\": " << r.wake_p99_us
    << ", \"wake_late_max_us\": " << r.wake_max_us << ",\n    \"pooled\": ";
  jsonSummary(o, r.pooled, true);
  o << ",\n    \"per_second_median\": ";
  jsonSummary(o, r.per_second, false);
  o << "}";
  if (d) {
    o << ",\n  \"ddsperf\": {\"ping\": " << jsonString(d->ping_cmd)
      << ", \"pong\": " << jsonString(d->pong_cmd) << ", \"size\": " << ddsperf_size
      << ", \"seconds\": " << d->seconds.size() << ", \"timeouts\": " << d->timeouts
      << ",\n    \"per_second_median\": ";
    jsonSummary(o, d->aggregate, false);
    const auto ratio = [](double a, double b) { return b > 0 ? a / b : 0.0; };
    o << ",\n    \"ratio_telehand_over_ddsperf\": {\"p50\": "
      << ratio(r.per_second.p50_us, d->aggregate.p50_us)
      << ", \"p90\": " << ratio(r.per_second.p90_us, d->aggregate.p90_us)
      << ", \"p99\": " << ratio(r.per_second.p99_us, d->aggregate.p99_us)
      << ", \"max\": " << ratio(r.per_second.max_us, d->aggregate.max_us) << "}}";
  }
  o << "\n}\n";
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "telehand-latency: loopback latency probe. Sends DeviceState samples at --rate through an "
      "echo (a telehand-server's, or a child 'telehand-latency --echo-only' in a private "
      "partition) and prints one-way latency (RTT/2) percentiles; --compare-ddsperf then runs "
      "Cyclone's ddsperf ping-pong at the same size and rate and prints the ratio."};
  Settings s;
  std::string echo_choice = "auto";
  auto* seconds_opt = app.add_option("--seconds", s.seconds,
                                     "measured seconds (with --echo-only: stop after this; "
                                     "default there: until SIGINT/SIGTERM)")
                          ->capture_default_str()
                          ->check(CLI::PositiveNumber);
  app.add_option("--rate", s.rate_hz, "pings per second, Hz")
      ->capture_default_str()
      ->check(CLI::Range(1.0, 20000.0));
  app.add_option("--warmup", s.warmup_s, "seconds sent first and discarded")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 3600.0));
  app.add_option("--echo", echo_choice,
                 "auto: a server echo if one matches within 2 s, else self; server; self")
      ->capture_default_str()
      ->check(CLI::IsMember({"auto", "server", "self"}));
  auto* echo_only = app.add_flag("--echo-only", s.echo_only,
                                 "only echo pings (the other end of a probe) until "
                                 "SIGINT/SIGTERM or --seconds");
  app.add_option("--domain", s.dds.domain, "DDS domain id")->check(CLI::Range(0, 230));
  app.add_option("--partition", s.dds.partition, "DDS partition")->capture_default_str();
  app.add_option("--dds-config", s.dds_config, "Cyclone DDS XML config file")
      ->check(CLI::ExistingFile);
  auto* compare = app.add_flag("--compare-ddsperf", s.compare,
                               "afterwards run ddsperf ping-pong at the same size and rate");
  app.add_option("--ddsperf", s.ddsperf, "ddsperf program (package cyclonedds-tools)")
      ->capture_default_str();
  app.add_option("--json", s.json_path, "also write the results to this JSON file");
  app.add_flag("-q,--quiet", s.quiet, "no progress lines on stderr");
  echo_only->excludes(compare);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // CLI11's own codes (105, 106...) would not tell a script "bad usage" the way 2 does.
    return app.exit(e) == 0 ? 0 : kExitError;
  }
  s.echo = echo_choice;
  s.dds.config = s.dds_config;

  std::signal(SIGINT, onSignal);
  std::signal(SIGTERM, onSignal);
  try {
    if (s.echo_only) return runEcho(s, seconds_opt->count() > 0);

    const auto samples = (s.warmup_s + s.seconds) * s.rate_hz;
    if (samples > 1e7) {  // two int64 per ping are preallocated
      throw telehand::ConfigError("--seconds x --rate asks for " + fmt("%.0f", samples) +
                                  " pings; keep it under 1e7");
    }
    if (s.seconds * s.rate_hz < 1) {
      throw telehand::ConfigError("--seconds x --rate is less than one ping");
    }
    std::string ddsperf_path;
    if (s.compare) {
      const auto found = findProgram(s.ddsperf);
      if (!found) {
        throw Error("ddsperf not found ('" + s.ddsperf +
                    "'): install the Debian package cyclonedds-tools or pass --ddsperf PATH");
      }
      ddsperf_path = *found;
    }
    // Fail before measuring, not after; append mode keeps an earlier result until this one.
    if (!s.json_path.empty() && !std::ofstream(s.json_path, std::ios::app)) {
      throw Error("cannot write --json file '" + s.json_path + "'");
    }

    Sample probe{};
    uint32_t xcdr = 0;
    const uint32_t ser = serializedSize(probe, &xcdr);
    const uint32_t ddsperf_size = std::max(ser, kDdsperfMinSize);

    Progress progress(s.quiet);
    const PingResult r = runPinger(s, progress);
    printPing(s, r, sizeof(Sample), ser, xcdr);
    std::fflush(stdout);
    if (r.received == 0 && !r.interrupted) {
      throw Error("no pong came back: the echo matched but did not answer");
    }

    std::optional<DdsperfResult> d;
    if (s.compare && !r.interrupted) {
      d = runDdsperf(s, ddsperf_path, ddsperf_size, progress);
      if (d->interrupted) {
        std::cerr << "telehand-latency: interrupted; ddsperf comparison skipped\n";
      } else {
        printCompare(s, r, *d, ddsperf_path, ddsperf_size);
      }
    }
    if (!s.json_path.empty()) {
      std::ofstream json(s.json_path, std::ios::trunc);
      writeJson(json, s, r, sizeof(Sample), ser, d && !d->interrupted ? &*d : nullptr,
                ddsperf_size);
      if (!json) throw Error("writing --json file '" + s.json_path + "' failed");
    }
    return g_stop.load() ? kExitInterrupted : 0;
  } catch (const telehand::Error& e) {
    std::cerr << "telehand-latency: " << e.what() << "\n";
    return kExitError;
  } catch (const std::exception& e) {
    std::cerr << "telehand-latency: " << e.what() << "\n";
    return kExitError;
  }
}
