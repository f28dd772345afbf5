#include "report.h"

#include <dds/ddsi/ddsi_cdrstream.h>
#include <spdlog/fmt/fmt.h>
#include <unistd.h>

#include <cstdio>

namespace telehand::latency {

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
  std::printf("  take       %s\n",
              s.take == "listener"
                  ? "listener: pongs (and a self echo's pings) are taken inside Cyclone's "
                    "receive thread"
                  : "waitset: pongs (and a self echo's pings) are taken on threads a waitset "
                    "wakes");
  std::printf(
      "  host       %ld CPUs online, load average %.2f at start (other load inflates "
      "the tail)\n",
      sysconf(_SC_NPROCESSORS_ONLN), r.load_at_start);
  std::printf(
      "  schedule   %g Hz for %g s after %g s warm-up (discarded); clock_nanosleep "
      "TIMER_ABSTIME, 1 ns timer slack%s\n",
      s.rate_hz, s.seconds, s.warmup_s,
      r.interrupted ? fmt::format("; INTERRUPTED after {:.1f} s", r.measured_s).c_str() : "");
  if (s.rounds > 1) {
    std::printf(
        "  rounds     %d, taking turns with ddsperf: %g s measured each, after its own %g s "
        "warm-up\n",
        s.rounds, s.seconds / s.rounds, s.warmup_s);
  }
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
  std::printf("\nddsperf baseline (%s), run %s in the same domain and config:\n", path.c_str(),
              s.rounds > 1
                  ? fmt::format("in {} rounds taking turns with telehand", s.rounds).c_str()
                  : "after telehand");
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
      "             thread; %s\n",
      r.seconds_count,
      s.take == "listener"
          ? "so does telehand (--take listener; a server echo answers in one too)"
          : "telehand takes on waitset threads (--take waitset), one thread\n"
            "             wake-up more per direction (a server echo answers in a listener)");
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

namespace {

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
      out += fmt::format("\\u{:04x}", static_cast<unsigned>(c));
      continue;
    }
    out += c;
  }
  return out + "\"";
}

}  // namespace

void writeJson(std::ostream& o, const Settings& s, const PingResult& r, std::size_t size_of,
               uint32_t ser, const DdsperfResult* d, uint32_t ddsperf_size) {
  o.precision(6);
  o << "{\n  \"tool\": \"telehand-latency\",\n  \"definition\": \"one-way = RTT/2\",\n"
    << "  \"settings\": {\"seconds\": " << s.seconds << ", \"rate_hz\": " << s.rate_hz
    << ", \"warmup_s\": " << s.warmup_s << ", \"take\": " << jsonString(s.take)
    << ", \"rounds\": " << s.rounds << ", \"domain\": " << s.dds.domain
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

}  // namespace telehand::latency
