// telehand-web under load: a live session (telehand-server and a simulated telehand-client),
// the gateway, and N WebSocket clients (simulated browsers) watching the session, plus
// stalled ones that never read. Three phases in one session: "before" (no browsers),
// "browsers" and "after" (the browsers closed). Per phase it reports the gateway's CPU,
// HandState and DeviceState as a separate subscriber (this program) takes them, the
// DeviceState latency there (the device sample's source time to the take, both
// CLOCK_REALTIME on this machine) and the client's haptic-loop overruns (from its progress
// line); then what each browser received and, per figure, whether the browsers phase lies
// within the before/after spread (the noise), widened by a stated floor. The verdicts are
// figures, not a pass/fail: the exit code is non-zero only when a process fails.
//
//   telehand-bench-web [--clients 20] [--stalled 1] [--seconds 60] [--baseline 15]
#include <spdlog/fmt/fmt.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <numeric>
#include <regex>
#include <thread>
#include <vector>

#include "process.h"
#include "telehand/core/clock.h"
#include "telehand/protocol/dds.h"
#include "ws_client.h"

namespace {

using namespace telehand;
using namespace std::chrono_literals;

double cpuSeconds(pid_t pid) {  // user + system time of a process so far
  std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
  std::string s((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const auto close = s.rfind(')');
  if (close == std::string::npos) return 0;
  std::istringstream rest(s.substr(close + 2));
  std::string f;
  std::vector<std::string> fields;
  while (rest >> f) fields.push_back(f);
  if (fields.size() < 13) return 0;
  return static_cast<double>(std::stoull(fields[11]) + std::stoull(fields[12])) /
         static_cast<double>(sysconf(_SC_CLK_TCK));
}

uint64_t statOf(const std::string& json, const std::string& key) {
  std::smatch m;
  if (!std::regex_search(json, m, std::regex("\"" + key + "\":(\\d+)"))) return 0;
  return std::stoull(m[1]);
}

constexpr int kPhases = 3;  // before, browsers, after

/// HandState and DeviceState as a subscriber beside the gateway and the server sees them,
/// each reader on its own thread. DeviceState is taken best-effort with a deep history, as
/// the server's live reader takes it; while a phase is open (`phase` >= 0) the latency of each
/// DeviceState of the session goes into that phase's vector, reserved beforehand (a full
/// vector counts the rest as `overflow` instead of growing).
struct Tap {
  Tap(const dds::Options& o, const std::array<std::size_t, kPhases>& capacity)
      : p(o),
        t(p),
        r(p, t.hand_state, dds::qos::handStateReader(64)),
        dr(p, t.device_state, dds::qos::deviceStateReader(256)),
        ws(p),
        dws(p) {
    for (int i = 0; i < kPhases; ++i) latency_ns[i].reserve(capacity[i]);
    ws.attach(r.handle(), 1);
    dws.attach(dr.handle(), 1);
    th = std::thread([this] {
      while (!stop.load()) {
        ws.wait(50ms);
        r.take([this](const telehand_msg_HandState& h, const dds_sample_info_t&) {
          if (have && h.seq > last + 1) gaps += h.seq - last - 1;
          if (!have || h.seq > last) last = h.seq;
          have = true;
          session = h.session_id;
          ++count;
        });
      }
    });
    dth = std::thread([this] {
      while (!stop.load()) {
        dws.wait(50ms);
        dr.take(
            [this](const telehand_msg_DeviceState& d, const dds_sample_info_t&) {
              const int64_t now = wallNs();
              const int ph = phase.load(std::memory_order_acquire);
              if (ph < 0 || d.session_id != session.load(std::memory_order_relaxed)) return;
              device_count[ph].fetch_add(1, std::memory_order_relaxed);
              auto& v = latency_ns[ph];
              if (v.size() < v.capacity()) {
                v.push_back(now - d.source_time_ns);
              } else {
                overflow.fetch_add(1, std::memory_order_relaxed);
              }
            },
            256);
      }
    });
  }
  ~Tap() { halt(); }
  /// Stops both threads; the latency vectors may be read after this.
  void halt() {
    stop = true;
    if (th.joinable()) th.join();
    if (dth.joinable()) dth.join();
  }
  dds::Participant p;
  dds::Topics t;
  dds::Reader<telehand_msg_HandState> r;
  dds::Reader<telehand_msg_DeviceState> dr;
  dds::WaitSet ws, dws;
  std::atomic<bool> stop{false};
  std::atomic<uint64_t> count{0}, gaps{0}, session{0}, overflow{0};
  uint64_t last = 0;
  bool have = false;
  std::atomic<int> phase{-1};
  std::array<std::atomic<uint64_t>, kPhases> device_count{};
  std::array<std::vector<int64_t>, kPhases> latency_ns;
  std::thread th, dth;
};

/// The client's last progress line: its time and its loop's overruns so far.
struct LoopMark {
  double t = -1;
  uint64_t overruns = 0;
};

LoopMark lastProgress(const std::string& log) {
  static const std::regex line(R"(t=\s*([\d.]+)s .*overruns (\d+))");
  LoopMark m;
  std::size_t end = log.size();
  while (end > 0) {
    const std::size_t begin = log.rfind('\n', end - 1);
    const std::size_t from = begin == std::string::npos ? 0 : begin + 1;
    std::smatch sm;
    const std::string text = log.substr(from, end - from);
    if (std::regex_search(text, sm, line)) {
      m.t = std::stod(sm[1]);
      m.overruns = std::stoull(sm[2]);
      return m;
    }
    if (begin == std::string::npos) break;
    end = begin;
  }
  return m;
}

struct Phase {
  double seconds = 0, gateway_cpu = 0, tap_hz = 0, gateway_take_hz = 0, device_hz = 0;
  uint64_t tap_gaps = 0;
  LoopMark loop0, loop1;  // the client's progress at the phase's start and end
  double p50_ms = 0, p99_ms = 0, max_ms = 0;
  std::size_t latency_samples = 0;
  std::vector<double> window_max_ms;  // the browsers phase in stretches as long as the others

  uint64_t overruns() const { return loop1.overruns - loop0.overruns; }
  double overrunsPerMin() const {
    const double dt = loop1.t - loop0.t;
    return dt > 0 ? 60.0 * static_cast<double>(overruns()) / dt : 0.0;
  }
  double gapsPerMin() const {
    return seconds > 0 ? 60.0 * static_cast<double>(tap_gaps) / seconds : 0.0;
  }
};

/// p50, p99 and max of `ns` (nearest rank), in ms; with `windows` > 1 also the max of each of
/// that many equal runs of consecutive samples (about equal stretches of time at a steady
/// rate), so that a long phase's max can be set beside a short one's.
void percentiles(std::vector<int64_t> ns, Phase& p, std::size_t windows) {
  p.latency_samples = ns.size();
  if (ns.empty()) return;
  for (std::size_t w = 0; windows > 1 && w < windows; ++w) {
    const auto from = ns.begin() + static_cast<std::ptrdiff_t>(w * ns.size() / windows);
    const auto to = ns.begin() + static_cast<std::ptrdiff_t>((w + 1) * ns.size() / windows);
    if (from != to)
      p.window_max_ms.push_back(static_cast<double>(*std::max_element(from, to)) / 1e6);
  }
  std::sort(ns.begin(), ns.end());
  auto at = [&](double q) {
    const auto rank = static_cast<std::size_t>(std::ceil(q * static_cast<double>(ns.size())));
    return static_cast<double>(ns[std::clamp<std::size_t>(rank, 1, ns.size()) - 1]) / 1e6;
  };
  p.p50_ms = at(0.50);
  p.p99_ms = at(0.99);
  p.max_ms = static_cast<double>(ns.back()) / 1e6;
}

/// The median of the window maxima, or the max when there are none.
double typicalMax(const Phase& p) {
  if (p.window_max_ms.empty()) return p.max_ms;
  std::vector<double> w = p.window_max_ms;
  std::sort(w.begin(), w.end());
  return 0.5 * (w[(w.size() - 1) / 2] + w[w.size() / 2]);
}

/// Whether `load` lies within [min(before, after) - floor, max(before, after) + floor]; if
/// not, by how much it is worse or better (`higher_is_worse` says which way is which).
std::string verdict(double before, double load, double after, double floor, bool higher_is_worse,
                    const char* unit) {
  const double lo = std::min(before, after) - floor, hi = std::max(before, after) + floor;
  if (load >= lo && load <= hi) return "within the noise";
  const bool above = load > hi;
  return fmt::format("{} than the noise by {:.3g} {}",
                     above == higher_is_worse ? "WORSE" : "better", above ? load - hi : lo - load,
                     unit);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"telehand-bench-web: the web gateway under N simulated browsers"};
  int clients = 20, stalled = 1;
  double seconds = 60, baseline = 15;
  std::string build = TELEHAND_BUILD_DIR;
  app.add_option("--clients", clients, "WebSocket clients watching the session")
      ->capture_default_str();
  app.add_option("--stalled", stalled, "clients that upgrade and never read")
      ->capture_default_str();
  app.add_option("--seconds", seconds, "seconds with the clients")->capture_default_str();
  app.add_option("--baseline", baseline,
                 "seconds without clients before them, and again after them")
      ->capture_default_str();
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : 2;
  }
  std::string tmpl = "/tmp/telehand-bench-web-XXXXXX";
  const std::string dir = mkdtemp(tmpl.data());
  const std::string partition = "benchweb-" + std::to_string(getpid());
  const std::vector<std::string> d = {"--dds-config", TELEHAND_LOOPBACK_XML, "--partition",
                                      partition, "--insecure"};
  auto with = [&](std::vector<std::string> v) {
    v.insert(v.end(), d.begin(), d.end());
    return v;
  };
  // The client runs until it is stopped after the last phase; both get a generous margin.
  const double span = 2 * baseline + seconds;
  test::Process server(with({build + "/server/telehand-server", "--db", dir + "/records.db",
                             "--seconds", fmt::format("{:.0f}", span + 60)}),
                       dir + "/server.log");
  test::Process web(with({build + "/server/telehand-web", "--bind", "127.0.0.1:0", "--max-clients",
                          std::to_string(clients + stalled + 4), "--log-level", "warn"}),
                    dir + "/web.log");
  int port = 0;  // the system chose it; the gateway says which
  for (int i = 0; i < 200 && port == 0; ++i) {
    std::this_thread::sleep_for(50ms);
    std::smatch pm;
    const std::string out = web.output();
    if (std::regex_search(out, pm, std::regex(R"(serving http://127\.0\.0\.1:(\d+)/)")))
      port = std::stoi(pm[1]);
  }
  if (port == 0) {
    std::cerr << "telehand-web did not start: " << web.output() << "\n";
    return 1;
  }
  // Without -q the client prints a progress line every second, with its loop's overruns.
  test::Process client(with({build + "/client/telehand-client", "--seconds",
                             fmt::format("{:.0f}", span + 45), "--no-fault-stop"}),
                       dir + "/client.log");
  dds::Options o;
  o.config = TELEHAND_LOOPBACK_XML;
  o.partition = partition;
  // DeviceState runs at up to 1 kHz: room for twice that and a second more per phase.
  auto room = [](double s) { return static_cast<std::size_t>(2000.0 * (s + 1.0)); };
  Tap tap(o, {room(baseline), room(seconds), room(baseline)});
  for (int i = 0; i < 100 && tap.session.load() == 0; ++i) std::this_thread::sleep_for(100ms);
  if (tap.session.load() == 0) {
    std::cerr << "no session appeared; logs in " << dir << "\n";
    return 1;
  }
  const uint64_t session = tap.session.load();
  for (int i = 0; i < 50 && lastProgress(client.output()).t < 0; ++i)
    std::this_thread::sleep_for(100ms);

  std::array<Phase, kPhases> phases;
  auto measure = [&](int k, double s, const std::function<void()>& during) {
    Phase& p = phases[k];
    const double cpu0 = cpuSeconds(web.pid());
    const uint64_t tap0 = tap.count.load(), gaps0 = tap.gaps.load();
    const uint64_t take0 = statOf(test::httpGet(port, "/api/stats"), "hand_states");
    p.loop0 = lastProgress(client.output());
    const auto t0 = std::chrono::steady_clock::now();
    tap.phase.store(k, std::memory_order_release);
    std::this_thread::sleep_for(std::chrono::duration<double>(s));
    tap.phase.store(-1, std::memory_order_release);
    p.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (during) during();
    p.gateway_cpu = (cpuSeconds(web.pid()) - cpu0) / p.seconds;
    p.tap_hz = static_cast<double>(tap.count.load() - tap0) / p.seconds;
    p.tap_gaps = tap.gaps.load() - gaps0;
    p.gateway_take_hz =
        static_cast<double>(statOf(test::httpGet(port, "/api/stats"), "hand_states") - take0) /
        p.seconds;
    p.device_hz = static_cast<double>(tap.device_count[k].load()) / p.seconds;
    p.loop1 = lastProgress(client.output());
  };

  std::printf(
      "session %llu; %.0f s without browsers, %d browsers (+%d stalled) for %.0f s, %.0f s "
      "without them again\n",
      static_cast<unsigned long long>(session), baseline, clients, stalled, seconds, baseline);
  std::fflush(stdout);
  measure(0, baseline, nullptr);

  std::vector<std::unique_ptr<test::WsClient>> ws;
  for (int i = 0; i < clients; ++i) {
    ws.push_back(std::make_unique<test::WsClient>(port, false));
    if (!ws.back()->ok()) {
      std::cerr << "client " << i << ": " << ws.back()->error() << "\n";
      return 1;
    }
    ws.back()->send(fmt::format(R"({{"op":"watch","session":{}}})", session));
  }
  std::vector<int> raw;
  for (int i = 0; i < stalled; ++i) {
    raw.push_back(test::rawUpgrade(port));
    // A stalled browser asks for the stream and then never reads (masked text frame).
    const std::string msg = fmt::format(R"({{"op":"watch","session":{}}})", session);
    std::string frame{static_cast<char>(0x81), static_cast<char>(0x80 | msg.size())};
    frame.append(4, '\0');  // mask key 0: the payload goes as it is
    frame += msg;
    if (raw.back() >= 0 && ::write(raw.back(), frame.data(), frame.size()) < 0) return 1;
  }
  std::this_thread::sleep_for(1s);
  std::vector<uint64_t> hands0, bytes0;
  for (auto& c : ws) {
    hands0.push_back(c->hands());
    bytes0.push_back(c->bytes());
  }
  const std::string stats0 = test::httpGet(port, "/api/stats");
  std::vector<double> rates, kbps;
  measure(1, seconds, [&] {
    for (std::size_t i = 0; i < ws.size(); ++i) {
      rates.push_back(static_cast<double>(ws[i]->hands() - hands0[i]));
      kbps.push_back(static_cast<double>(ws[i]->bytes() - bytes0[i]));
    }
  });
  for (auto& r : rates) r /= phases[1].seconds;
  for (auto& k : kbps) k /= phases[1].seconds * 1000.0;
  const std::string stats1 = test::httpGet(port, "/api/stats");
  ws.clear();
  for (int fd : raw) ::close(fd);
  std::this_thread::sleep_for(1s);
  measure(2, baseline, nullptr);

  // The client stops on SIGTERM as on Ctrl-C: it closes the session and prints its summary.
  const int client_rc = client.stop(30s);
  tap.halt();
  // The browsers phase is longer: its max is also taken per stretch as long as the others.
  const auto windows =
      static_cast<std::size_t>(std::max(1.0, std::round(seconds / std::max(baseline, 1e-3))));
  for (int k = 0; k < kPhases; ++k)
    percentiles(std::move(tap.latency_ns[k]), phases[k], k == 1 ? windows : 1);
  const std::string client_log = client.output();
  std::smatch m;
  std::string live = "?", record = "?", loop_total = "?";
  if (std::regex_search(client_log, m, std::regex(R"(DeviceState live ([\d.]+) packets/s)")))
    live = m[1];
  if (std::regex_search(client_log, m,
                        std::regex(R"(record: (\d+ samples recorded, \d+ missing))")))
    record = m[1];
  if (std::regex_search(client_log, m, std::regex(R"(loop: (\d+) overruns)"))) loop_total = m[1];
  std::sort(rates.begin(), rates.end());
  const double mean = std::accumulate(rates.begin(), rates.end(), 0.0) /
                      static_cast<double>(std::max<std::size_t>(1, rates.size()));
  const double kb = std::accumulate(kbps.begin(), kbps.end(), 0.0);

  const Phase &b = phases[0], &l = phases[1], &a = phases[2];
  auto row = [&](const char* name, const char* f, auto get) {
    std::printf("%-38s", name);
    for (const Phase& p : phases)
      std::printf(" %14s", fmt::format(fmt::runtime(f), get(p)).c_str());
    std::printf("\n");
  };
  std::printf("\n%-38s %14s %14s %14s\n", "", "before", fmt::format("{} browsers", clients).c_str(),
              "after");
  row("seconds", "{:.1f}", [](const Phase& p) { return p.seconds; });
  row("gateway CPU (of one core)", "{:.1f} %", [](const Phase& p) { return 100 * p.gateway_cpu; });
  row("HandState/s at a separate subscriber", "{:.1f}", [](const Phase& p) { return p.tap_hz; });
  row("HandState gaps there", "{}", [](const Phase& p) { return p.tap_gaps; });
  row("HandState/s the gateway took", "{:.1f}", [](const Phase& p) { return p.gateway_take_hz; });
  row("DeviceState/s at a separate subscriber", "{:.1f}",
      [](const Phase& p) { return p.device_hz; });
  row("DeviceState latency p50 (ms)", "{:.3f}", [](const Phase& p) { return p.p50_ms; });
  row("DeviceState latency p99 (ms)", "{:.3f}", [](const Phase& p) { return p.p99_ms; });
  row("DeviceState latency max (ms)", "{:.3f}", [](const Phase& p) { return p.max_ms; });
  row("client loop overruns", "{}", [](const Phase& p) { return p.overruns(); });
  row("client loop overruns/min", "{:.1f}", [](const Phase& p) { return p.overrunsPerMin(); });
  row("  (client time, s)", "{:.0f}", [](const Phase& p) { return p.loop1.t - p.loop0.t; });
  if (tap.overflow.load() > 0) {
    std::printf("(%llu DeviceState latencies did not fit the reserved room and were left out)\n",
                static_cast<unsigned long long>(tap.overflow.load()));
  }

  // Noise: the before/after spread, widened by a floor each side for figures whose spread
  // can be zero by chance.
  auto rel = [](double x, double y) { return 0.01 * 0.5 * (x + y); };  // 1 % of their mean
  std::printf("\nverdicts (%s phase against [min, max] of before and after, +- the floor):\n",
              "browsers");
  std::printf("  %-32s %.1f %% of one core: %s\n", "gateway CPU", 100 * l.gateway_cpu,
              l.gateway_cpu < 1.0 ? "under one core" : "NOT under one core");
  auto line = [&](const char* name, double vb, double vl, double va, double floor,
                  bool higher_is_worse, const char* unit, const char* floor_text) {
    std::printf("  %-32s %.4g %s (before %.4g, after %.4g; floor %s): %s\n", name, vl, unit, vb, va,
                floor_text, verdict(vb, vl, va, floor, higher_is_worse, unit).c_str());
  };
  line("HandState/s at the subscriber", b.tap_hz, l.tap_hz, a.tap_hz, rel(b.tap_hz, a.tap_hz),
       false, "/s", "1 %");
  line("HandState gaps there", b.gapsPerMin(), l.gapsPerMin(), a.gapsPerMin(), 1.0, true, "/min",
       "1/min");
  line("DeviceState/s at the subscriber", b.device_hz, l.device_hz, a.device_hz,
       rel(b.device_hz, a.device_hz), false, "/s", "1 %");
  line("DeviceState latency p50", b.p50_ms, l.p50_ms, a.p50_ms, 0.1, true, "ms", "0.1 ms");
  line("DeviceState latency p99", b.p99_ms, l.p99_ms, a.p99_ms, 0.1, true, "ms", "0.1 ms");
  if (l.window_max_ms.empty()) {
    line("DeviceState latency max", b.max_ms, l.max_ms, a.max_ms, 0.1, true, "ms", "0.1 ms");
  } else {
    std::string each;
    for (double w : l.window_max_ms) each += fmt::format("{}{:.3g}", each.empty() ? "" : ", ", w);
    std::printf("  %-32s per %.0f s: %s ms; their median:\n", "DeviceState latency max",
                l.seconds / static_cast<double>(l.window_max_ms.size()), each.c_str());
    line("", b.max_ms, typicalMax(l), a.max_ms, 0.1, true, "ms", "0.1 ms");
  }
  line("client loop overruns", b.overrunsPerMin(), l.overrunsPerMin(), a.overrunsPerMin(), 1.0,
       true, "/min", "1/min");

  std::printf(
      "\nper browser: hand frames/s min %.1f, median %.1f, mean %.1f, max %.1f; %.1f kB/s "
      "in all (%.1f each)\n",
      rates.empty() ? 0 : rates.front(), rates.empty() ? 0 : rates[rates.size() / 2], mean,
      rates.empty() ? 0 : rates.back(), kb,
      kb / static_cast<double>(std::max<std::size_t>(1, kbps.size())));
  std::printf(
      "gateway: frames serialized %llu, sent %llu, replaced before sending %llu, "
      "dropped slow browsers %llu\n",
      static_cast<unsigned long long>(statOf(stats1, "hand_frames") -
                                      statOf(stats0, "hand_frames")),
      static_cast<unsigned long long>(statOf(stats1, "hand_sent") - statOf(stats0, "hand_sent")),
      static_cast<unsigned long long>(statOf(stats1, "hand_coalesced") -
                                      statOf(stats0, "hand_coalesced")),
      static_cast<unsigned long long>(statOf(stats1, "dropped_slow")));
  std::printf("client: exit %d, DeviceState live %s/s, loop %s overruns in all, record %s\n",
              client_rc, live.c_str(), loop_total.c_str(), record.c_str());
  web.stop();
  server.stop();
  if (client_rc != 0) {
    std::fprintf(stderr, "telehand-client %s; logs kept in %s\n", client.describeExit().c_str(),
                 dir.c_str());
    return 1;
  }
  std::filesystem::remove_all(dir);
  return 0;
}
