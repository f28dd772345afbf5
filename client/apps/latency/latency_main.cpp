// telehand-latency: the loopback latency probe. Sends DeviceState-sized samples at a fixed
// rate through an echo (the server's, or a child process of its own), reports one-way
// latency as RTT/2 the way ddsperf does, and can run Cyclone's ddsperf ping-pong at the same
// size and rate afterwards so that the README's figures come with their baseline.
//
// options: the command line; echo: the echo and the pinger; stats: the percentiles;
// ddsperf: the baseline; report: text and JSON.
#include <spdlog/fmt/fmt.h>

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <optional>

#include "ddsperf.h"
#include "echo.h"
#include "options.h"
#include "report.h"
#include "telehand/app/dds_cli.h"
#include "telehand/app/process.h"
#include "telehand/app/signals.h"

namespace {
constexpr int kExitError = 2;
constexpr int kExitInterrupted = 130;
}  // namespace

int main(int argc, char** argv) {
  using namespace telehand;
  using namespace telehand::latency;
  Settings s;
  bool seconds_given = false;
  if (const auto done = parseOptions(argc, argv, s, seconds_given)) return *done;

  installStopSignals();
  try {
    app::resolveDdsSecurity(s.dds, s.insecure, "engineer", "telehand-latency");
    if (s.echo_only) return runEcho(s, seconds_given);

    const auto samples = (s.warmup_s + s.seconds) * s.rate_hz;
    if (samples > 1e7) {  // two int64 per ping are preallocated
      throw ConfigError(
          fmt::format("--seconds x --rate asks for {:.0f} pings; keep it under 1e7", samples));
    }
    if (s.seconds * s.rate_hz < 1) throw ConfigError("--seconds x --rate is less than one ping");
    if (s.rounds > 1 && s.seconds / s.rounds < 1) {
      throw ConfigError(fmt::format(
          "--seconds {:g} / --rounds {} is under 1 s: each round needs whole seconds for the "
          "per-second figures",
          s.seconds, s.rounds));
    }
    std::string ddsperf_path;
    if (s.compare) {
      const auto found = app::findProgram(s.ddsperf);
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
    // --rounds: telehand and ddsperf take turns, each round measuring seconds / rounds.
    Settings round = s;
    round.seconds = s.seconds / s.rounds;
    PingResult r;
    std::optional<DdsperfResult> d;
    bool printed = false;
    const auto print_ping = [&] {
      printPing(s, r, sizeof(Sample), ser, xcdr);
      std::fflush(stdout);
      printed = true;
    };
    for (int i = 0; i < s.rounds; ++i) {
      const PingResult ri = runPinger(round, progress);
      if (i == 0) {
        r = ri;
      } else {
        merge(r, ri);
      }
      if (ri.received == 0 && !ri.interrupted) {
        print_ping();
        throw Error("no pong came back: the echo matched but did not answer");
      }
      // With one round telehand's figures are out before ddsperf starts.
      if (i + 1 == s.rounds || r.interrupted) print_ping();
      if (!s.compare || r.interrupted) break;
      const DdsperfResult di = runDdsperf(round, ddsperf_path, ddsperf_size, progress);
      if (d) {
        merge(*d, di);
      } else {
        d = di;
      }
      if (d->interrupted) break;
    }
    if (!printed) print_ping();
    if (d) {
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
    return g_stop_requested.load() ? kExitInterrupted : 0;
  } catch (const std::exception& e) {
    std::cerr << "telehand-latency: " << e.what() << "\n";
    return kExitError;
  }
}
