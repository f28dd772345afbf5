#include "echo.h"

#include <pthread.h>
#include <spdlog/fmt/fmt.h>
#include <sys/prctl.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <ctime>
#include <optional>
#include <random>
#include <thread>

#include "telehand/app/signals.h"

extern char** environ;

namespace telehand::latency {

std::vector<std::string> childEnv(const std::string& dds_uri) {
  std::vector<std::string> env;
  for (char** e = environ; *e; ++e) {
    if (!dds_uri.empty() && std::strncmp(*e, "CYCLONEDDS_URI=", 15) == 0) continue;
    env.emplace_back(*e);
  }
  if (!dds_uri.empty()) env.push_back("CYCLONEDDS_URI=" + dds_uri);
  return env;
}

int runEcho(const Settings& s, bool seconds_given) {
  dds::Participant participant(s.dds);
  dds::Topic<Sample> ping_topic(participant, dds::topic::kLatencyPing);
  dds::Topic<Sample> pong_topic(participant, dds::topic::kLatencyPong);
  dds::Reader<Sample> ping_reader(participant, ping_topic, dds::qos::latencyProbe());
  dds::Writer<Sample> pong_writer(participant, pong_topic, dds::qos::latencyProbe());
  if (!s.quiet) {
    std::cerr << "telehand-latency: echoing on domain " << s.dds.domain << ", partition '"
              << s.dds.partition << "' (take: " << s.take << ") "
              << (seconds_given ? fmt::format("for {:g} s", s.seconds) : "until SIGINT/SIGTERM")
              << "\n";
  }
  const int64_t end_ns =
      seconds_given ? monoNs() + static_cast<int64_t>(s.seconds * 1e9) : INT64_MAX;
  const auto running = [&] { return !g_stop_requested.load() && monoNs() < end_ns; };
  uint64_t echoes = 0, write_errors = 0;
  // Answers every ping waiting with the same sample: a loaned take and a best-effort write,
  // nothing allocated or locked here. As a listener this runs on Cyclone's receive thread;
  // the pong writer is best-effort keep-last 1, so the write never waits for an
  // acknowledgement or for room in its history, and no reader of this process reads the pong
  // topic, so the write cannot call back into a listener of ours.
  const auto answer = [&]() noexcept {
    echoes += ping_reader.take([&](const Sample& x, const dds_sample_info_t&) {
      if (pong_writer.write(x) < 0) ++write_errors;
    });
  };
  if (s.take == "listener") {
    dds::DataListener listener(ping_reader.handle(), answer);
    // This thread only watches for the end; 50 ms bounds how long a signal waits to be seen.
    while (running()) std::this_thread::sleep_for(50ms);
    listener.detach();  // waits for an answer under way: the counters are final after it
  } else {
    dds::WaitSet waitset(participant);
    waitset.attach(ping_reader.handle(), 1);
    // A 100 ms timeout bounds how long a signal waits to be seen; data wakes the waitset.
    while (running()) {
      waitset.wait(100ms);
      answer();
    }
  }
  if (!s.quiet) {
    std::cerr << "telehand-latency: echo stopped after " << echoes << " echoes, " << write_errors
              << " write errors\n";
  }
  return 0;
}

namespace {

/// Waits until the ping writer reaches a reader and the pong reader a writer.
bool awaitEcho(const dds::Writer<Sample>& ping, const dds::Reader<Sample>& pong,
               std::chrono::milliseconds timeout, app::Process* child) {
  const int64_t deadline = monoNs() + timeout.count() * kNsPerMs;
  while (monoNs() < deadline && !g_stop_requested.load()) {
    if (ping.matchedReaders() > 0 && pong.matchedWriters() > 0) return true;
    if (child && !child->alive()) {
      throw Error("the self echo (self echo) " + child->describeExit() + " before it matched");
    }
    std::this_thread::sleep_for(10ms);
  }
  return false;
}

}  // namespace

void finish(PingResult& r) {
  r.received = r.rtt_ns.size();
  r.seconds_count = r.seconds.size();
  r.per_second = aggregateSeconds(r.seconds);
  std::vector<int64_t> sorted = r.rtt_ns;
  r.pooled = summarize(sorted);
  r.wake_p99_us = r.wake_max_us = 0;
  if (!r.wake_late_ns.empty()) {
    std::vector<int64_t> wake = r.wake_late_ns;
    std::sort(wake.begin(), wake.end());
    r.wake_p99_us = static_cast<double>(wake[wake.size() - (wake.size() + 99) / 100]) / 1e3;
    r.wake_max_us = static_cast<double>(wake.back()) / 1e3;
  }
}

void merge(PingResult& into, const PingResult& round) {
  into.echo_desc = round.echo_desc;
  into.partition = round.partition;
  into.warmup_pings += round.warmup_pings;
  into.planned += round.planned;
  into.sent += round.sent;
  into.late += round.late;
  into.duplicates += round.duplicates;
  into.foreign += round.foreign;
  into.write_errors += round.write_errors;
  into.overruns += round.overruns;
  into.measured_s += round.measured_s;
  into.interrupted = into.interrupted || round.interrupted;
  into.rtt_ns.insert(into.rtt_ns.end(), round.rtt_ns.begin(), round.rtt_ns.end());
  into.seconds.insert(into.seconds.end(), round.seconds.begin(), round.seconds.end());
  into.wake_late_ns.insert(into.wake_late_ns.end(), round.wake_late_ns.begin(),
                           round.wake_late_ns.end());
  finish(into);
}

PingResult runPinger(const Settings& s, Progress& progress) {
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
  std::optional<app::Process> echo_child;

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
    if (g_stop_requested.load()) throw Error("interrupted");
    // A private partition keeps a server or another probe from answering or listening.
    dds::Options o = s.dds;
    o.partition = s.dds.partition + ".latency-" + std::to_string(getpid());
    std::vector<std::string> argv = {
        "/proc/self/exe", "--echo-only", "--quiet", "--domain", std::to_string(o.domain),
        "--partition",    o.partition,   "--take",  s.take};
    if (!s.dds_config.empty()) {
      argv.push_back("--dds-config");
      argv.push_back(s.dds_config);
    }
    if (s.dds.pki.empty()) {
      argv.push_back("--insecure");
    } else {
      for (const std::string& a :
           {std::string("--pki"), s.dds.pki, std::string("--identity"), s.dds.identity})
        argv.push_back(a);
    }
    echo_child.emplace(app::ProcessOptions{
        .argv = argv, .env = childEnv(""), .null_stdin = true, .die_with_parent = true});
    ep.emplace(o);
    if (!awaitEcho(ep->ping, ep->pong, kSelfEchoWait, &*echo_child)) {
      if (g_stop_requested.load()) throw Error("interrupted");
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
  // Takes every pong waiting and stores its RTT at its sequence number: a loaned take, stores
  // into preallocated slots and relaxed atomics, nothing allocated, locked or written. As a
  // listener it runs on Cyclone's receive thread; Cyclone never overlaps two calls for one
  // reader, and the waitset thread is the only caller otherwise.
  const auto take_pongs = [&]() noexcept {
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
  };
  std::optional<dds::DataListener<decltype(take_pongs)>> pong_listener;
  std::thread receiver;
  std::string receiver_error;  // read only after join
  if (s.take == "listener") {
    pong_listener.emplace(ep->pong.handle(), take_pongs);
  } else {
    receiver = std::thread([&] {
      pthread_setname_np(pthread_self(), "lat-recv");
      prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);
      try {
        dds::WaitSet ws(ep->participant);
        ws.attach(ep->pong.handle(), 1);
        ws.attach(wake_guard.handle(), 2);
        while (receiving.load(std::memory_order_acquire)) {
          ws.wait(100ms);
          take_pongs();
        }
      } catch (const std::exception& e) {
        receiver_error = e.what();
        g_stop_requested.store(true);  // ends the pinger; the error is reported after the join
      }
    });
  }

  std::atomic<bool> pinging{true};
  uint64_t write_errors = 0, overruns = 0;
  std::thread pinger([&] {
    pthread_setname_np(pthread_self(), "lat-ping");
    // The default 50 µs slack makes a 1 kHz sleep wake ~84 µs late on these VMs (docs/facts.md).
    prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);
    Sample x{};
    x.session_id = run_id;
    int64_t start = monoNs() + period_ns;
    for (uint64_t seq = 0; seq < total && !g_stop_requested.load(std::memory_order_relaxed);
         ++seq) {
      const int64_t due = start + static_cast<int64_t>(seq) * period_ns;
      const timespec ts{static_cast<time_t>(due / kNsPerS), static_cast<long>(due % kNsPerS)};
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
  int64_t next_report = t0 + kNsPerS;
  while (pinging.load(std::memory_order_acquire)) {
    std::this_thread::sleep_for(20ms);
    if (monoNs() < next_report) continue;
    next_report += kNsPerS;
    const uint64_t n = sent.load();
    const double t = static_cast<double>(monoNs() - t0) / 1e9;
    progress.line(fmt::format(
        "telehand-latency: {:5.1f}/{:.0f} s  {}  sent {}  pongs {}  max one-way {:.0f} us", t,
        total_s, n < r.warmup_pings ? "warm-up" : "measure",
        n > r.warmup_pings ? n - r.warmup_pings : 0, received.load(),
        static_cast<double>(window_max_rtt.exchange(0)) / 2e3));
  }
  pinger.join();
  r.measured_s = std::max(0.0, static_cast<double>(monoNs() - t0) / 1e9 - s.warmup_s);
  // Pongs still in flight get a bounded time to arrive; whatever is missing then is lost.
  const uint64_t sent_total = sent.load();
  r.sent = sent_total > r.warmup_pings ? sent_total - r.warmup_pings : 0;
  const int64_t drain_end = monoNs() + std::chrono::nanoseconds(kDrain).count();
  while (received.load() < r.sent && monoNs() < drain_end) std::this_thread::sleep_for(5ms);
  // After this no pong is taken, and every RTT stored is visible here.
  pong_listener.reset();
  if (receiver.joinable()) {
    receiving.store(false, std::memory_order_release);
    wake_guard.trigger();
    receiver.join();
  }
  progress.done();
  if (!receiver_error.empty()) throw Error("pong receiver failed: " + receiver_error);
  r.interrupted = g_stop_requested.load();
  r.write_errors = write_errors;
  r.overruns = overruns;
  r.duplicates = duplicates.load();
  r.foreign = foreign.load();

  if (echo_child) {
    stopChild(*echo_child, "self echo");
    if (!echo_child->exitedOk()) {
      std::cerr << "telehand-latency: warning: the self echo " << echo_child->describeExit()
                << "\n";
    }
  }

  r.rtt_ns.reserve(r.sent);
  const auto per_second_n = static_cast<std::size_t>(std::llround(s.rate_hz));
  std::vector<int64_t> bucket;
  bucket.reserve(per_second_n);
  for (std::size_t i = 0; i < r.sent; ++i) {
    if (rtt_ns[i] >= 0) {
      r.rtt_ns.push_back(rtt_ns[i]);
      bucket.push_back(rtt_ns[i]);
      if (rtt_ns[i] > period_ns) ++r.late;
    }
    // Seconds by send index, as ddsperf reports by wall second; a short last one is dropped.
    if ((i + 1) % per_second_n == 0) {
      r.seconds.push_back(summarize(bucket));
      bucket.clear();
    }
  }
  r.wake_late_ns.assign(wake_late_ns.begin(),
                        wake_late_ns.begin() + static_cast<std::ptrdiff_t>(sent_total));
  finish(r);
  return r;
}

}  // namespace telehand::latency
