#include "ddsperf.h"

#include <fcntl.h>
#include <poll.h>
#include <spdlog/fmt/fmt.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <optional>
#include <sstream>

#include "echo.h"
#include "telehand/app/signals.h"

namespace telehand::latency {

namespace {

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

}  // namespace

void merge(DdsperfResult& into, const DdsperfResult& round) {
  into.pong_cmd = round.pong_cmd;
  into.ping_cmd = round.ping_cmd;
  into.seconds.insert(into.seconds.end(), round.seconds.begin(), round.seconds.end());
  into.warmup_lines += round.warmup_lines;
  into.foreign_lines += round.foreign_lines;
  into.timeouts += round.timeouts;
  into.interrupted = into.interrupted || round.interrupted;
  into.aggregate = aggregateSeconds(into.seconds);
}

DdsperfResult runDdsperf(const Settings& s, const std::string& path, uint32_t size,
                         Progress& progress) {
  DdsperfResult r;
  const std::string domain = std::to_string(s.dds.domain);
  const double ping_s = s.warmup_s + s.seconds;
  // The pong outlives the ping (which first waits for it to match); it is stopped by PID.
  const std::vector<std::string> pong_argv = {
      path, "-i", domain, "-u", "-D", fmt::format("{:g}", ping_s + kDdsperfInitWaitS + 5), "pong"};
  const std::vector<std::string> ping_argv = {
      path,           "-i",
      domain,         "-u",
      "-Qminmatch:1", "-Qinitwait:" + fmt::format("{:g}", kDdsperfInitWaitS),
      "-D",           fmt::format("{:g}", ping_s),
      "ping",         fmt::format("{:g}", s.rate_hz) + "Hz",
      "size",         std::to_string(size)};
  r.pong_cmd = joinArgs(pong_argv);
  r.ping_cmd = joinArgs(ping_argv);
  const auto env = childEnv(dds::configUri(s.dds_config));

  int pong_pipe[2], ping_pipe[2];
  if (pipe2(pong_pipe, O_CLOEXEC) != 0 || pipe2(ping_pipe, O_CLOEXEC) != 0) {
    throw Error(std::string("pipe: ") + std::strerror(errno));
  }
  std::string pong_out, ping_out;
  std::optional<app::Process> pong, ping;
  try {
    const auto start = [&](const std::vector<std::string>& argv, int out_fd) {
      return app::ProcessOptions{
          .argv = argv, .env = env, .out_fd = out_fd, .null_stdin = true, .die_with_parent = true};
    };
    pong.emplace(start(pong_argv, pong_pipe[1]));
    ping.emplace(start(ping_argv, ping_pipe[1]));
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
  int64_t next_report = t0 + kNsPerS;
  int open_fds = 2;
  while (open_fds > 0) {
    if (g_stop_requested.load() || monoNs() > deadline) break;
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
      next_report += kNsPerS;
      const double t = static_cast<double>(monoNs() - t0) / 1e9;
      progress.line(
          fmt::format("telehand-latency: ddsperf ping-pong running, {:5.1f} s of about {:.0f} s", t,
                      ping_s + 1));
    }
  }
  progress.done();
  r.interrupted = g_stop_requested.load();
  const bool timed_out = monoNs() > deadline;
  const pid_t pong_pid = pong->pid();
  stopChild(*ping, "ddsperf ping");
  stopChild(*pong, "ddsperf pong");
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

}  // namespace telehand::latency
