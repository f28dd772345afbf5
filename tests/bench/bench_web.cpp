// telehand-web under load: a live session (telehand-server and a simulated telehand-client),
// the gateway, and N WebSocket clients (simulated browsers) watching the session, plus
// stalled ones that never read. Reports the gateway's CPU, what each browser received, and
// whether DDS delivery changed: HandState as a separate subscriber (this program) takes it,
// and the client's DeviceState rate and the record, first without browsers, then with them.
//
//   telehand-bench-web [--clients 20] [--stalled 1] [--seconds 60] [--baseline 10]
#include <spdlog/fmt/fmt.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
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

/// HandState as a subscriber beside the gateway sees it.
struct Tap {
  explicit Tap(const dds::Options& o)
      : p(o), t(p), r(p, t.hand_state, dds::qos::handStateReader(64)), ws(p) {
    ws.attach(r.handle(), 1);
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
  }
  ~Tap() {
    stop = true;
    th.join();
  }
  dds::Participant p;
  dds::Topics t;
  dds::Reader<telehand_msg_HandState> r;
  dds::WaitSet ws;
  std::atomic<bool> stop{false};
  std::atomic<uint64_t> count{0}, gaps{0}, session{0};
  uint64_t last = 0;
  bool have = false;
  std::thread th;
};

struct Phase {
  double seconds = 0, gateway_cpu = 0, tap_hz = 0, gateway_take_hz = 0;
  uint64_t tap_gaps = 0;
};

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"telehand-bench-web: the web gateway under N simulated browsers"};
  int clients = 20, stalled = 1;
  double seconds = 60, baseline = 10;
  std::string build = TELEHAND_BUILD_DIR;
  app.add_option("--clients", clients, "WebSocket clients watching the session")
      ->capture_default_str();
  app.add_option("--stalled", stalled, "clients that upgrade and never read")
      ->capture_default_str();
  app.add_option("--seconds", seconds, "seconds with the clients")->capture_default_str();
  app.add_option("--baseline", baseline, "seconds without clients first")->capture_default_str();
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
  const std::string total = fmt::format("{:.0f}", baseline + seconds + 15);
  test::Process server(
      with({build + "/server/telehand-server", "--db", dir + "/records.db", "--seconds", total}),
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
  test::Process client(
      with({build + "/client/telehand-client", "--seconds",
            fmt::format("{:.0f}", baseline + seconds + 6), "-q", "--no-fault-stop"}),
      dir + "/client.log");
  dds::Options o;
  o.config = TELEHAND_LOOPBACK_XML;
  o.partition = partition;
  Tap tap(o);
  for (int i = 0; i < 100 && tap.session.load() == 0; ++i) std::this_thread::sleep_for(100ms);
  if (tap.session.load() == 0) {
    std::cerr << "no session appeared; logs in " << dir << "\n";
    return 1;
  }
  const uint64_t session = tap.session.load();

  auto measure = [&](double s, const std::function<void()>& during) {
    Phase p;
    const double cpu0 = cpuSeconds(web.pid());
    const uint64_t tap0 = tap.count.load(), gaps0 = tap.gaps.load();
    const uint64_t take0 = statOf(test::httpGet(port, "/api/stats"), "hand_states");
    const auto t0 = std::chrono::steady_clock::now();
    std::this_thread::sleep_for(std::chrono::duration<double>(s));
    if (during) during();
    p.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    p.gateway_cpu = (cpuSeconds(web.pid()) - cpu0) / p.seconds;
    p.tap_hz = static_cast<double>(tap.count.load() - tap0) / p.seconds;
    p.tap_gaps = tap.gaps.load() - gaps0;
    p.gateway_take_hz =
        static_cast<double>(statOf(test::httpGet(port, "/api/stats"), "hand_states") - take0) /
        p.seconds;
    return p;
  };

  std::printf("session %llu; %.0f s without browsers, then %d browsers (+%d stalled) for %.0f s\n",
              static_cast<unsigned long long>(session), baseline, clients, stalled, seconds);
  const Phase base = measure(baseline, nullptr);

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
  const Phase load = measure(seconds, [&] {
    for (std::size_t i = 0; i < ws.size(); ++i) {
      rates.push_back(static_cast<double>(ws[i]->hands() - hands0[i]));
      kbps.push_back(static_cast<double>(ws[i]->bytes() - bytes0[i]));
    }
  });
  for (auto& r : rates) r /= load.seconds;
  for (auto& k : kbps) k /= load.seconds * 1000.0;
  const std::string stats1 = test::httpGet(port, "/api/stats");
  ws.clear();
  for (int fd : raw) ::close(fd);

  const auto client_rc = client.wait(60s);
  std::this_thread::sleep_for(500ms);
  const std::string client_log = client.output();
  std::smatch m;
  std::string live = "?", record = "?";
  if (std::regex_search(client_log, m, std::regex(R"(DeviceState live ([\d.]+) packets/s)")))
    live = m[1];
  if (std::regex_search(client_log, m,
                        std::regex(R"(record: (\d+ samples recorded, \d+ missing))")))
    record = m[1];
  std::sort(rates.begin(), rates.end());
  const double mean = std::accumulate(rates.begin(), rates.end(), 0.0) /
                      static_cast<double>(std::max<std::size_t>(1, rates.size()));
  const double kb = std::accumulate(kbps.begin(), kbps.end(), 0.0);

  std::printf("\n%-34s %14s %14s\n", "", "no browsers",
              fmt::format("{} browsers", clients).c_str());
  std::printf("%-34s %14.1f %14.1f\n", "seconds", base.seconds, load.seconds);
  std::printf("%-34s %13.1f%% %13.1f%%\n", "gateway CPU (of one core)", 100 * base.gateway_cpu,
              100 * load.gateway_cpu);
  std::printf("%-34s %14.1f %14.1f\n", "HandState/s at another subscriber", base.tap_hz,
              load.tap_hz);
  std::printf("%-34s %14llu %14llu\n", "HandState gaps there",
              static_cast<unsigned long long>(base.tap_gaps),
              static_cast<unsigned long long>(load.tap_gaps));
  std::printf("%-34s %14.1f %14.1f\n", "HandState/s the gateway took", base.gateway_take_hz,
              load.gateway_take_hz);
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
  std::printf("client: exit %d, DeviceState live %s/s, record %s\n", client_rc.value_or(-1),
              live.c_str(), record.c_str());
  web.stop();
  server.stop();
  std::filesystem::remove_all(dir);
  return client_rc.has_value() ? 0 : 1;
}
