// Emulated MF-2 round trips: how many state -> command cycles per second the driver runs
// against the umockdev emulation, and the command -> state latency (a command sent until
// the first state packet that echoes it). Run under umockdev-wrapper:
//   umockdev-wrapper build/release/tests/usb/telehand_bench_usb --seconds 10 [--pin-cpu 0]
#include <sched.h>
#include <sys/prctl.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <thread>
#include <vector>

#include "mf2_emulator.h"
#include "telehand/app/cli.h"
#include "telehand/client/usb/usb_mf2.h"

int main(int argc, char** argv) {
  using namespace telehand;
  using namespace std::chrono_literals;
  CLI::App app{
      "telehand_bench_usb: emulated MF-2 round-trip rate and latency (run under "
      "umockdev-wrapper)"};
  double seconds = 10.0;
  int pin_cpu = -1, in_flight = 2;
  int64_t pace_us = 0;
  bool default_slack = false;
  app.add_option("--seconds", seconds, "how long to stream")->capture_default_str();
  app.add_option("--pin-cpu", pin_cpu, "run every thread on this CPU");
  app.add_option("--pace-us", pace_us, "device packet period (0: as fast as asked)")
      ->capture_default_str();
  app.add_option("--in-flight", in_flight, "IN transfers queued")->capture_default_str();
  app.add_flag("--default-slack", default_slack,
               "leave the emulation's threads at the default timer slack");
  TELEHAND_CLI_PARSE(app, argc, argv)

  if (pin_cpu >= 0) {
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(pin_cpu, &set);
    if (sched_setaffinity(0, sizeof set, &set) != 0) std::perror("sched_setaffinity");
  }
  if (!default_slack)
    prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);  // inherited by umockdev's thread
  try {
    test::usb::EmulatorOptions opt;
    opt.pace_ns = pace_us * 1000;
    test::usb::Mf2Emulator emu(opt);
    emu.withFirmware([](test::usb::Mf2Firmware& fw) {
      fw.keepHistory(false);
      return 0;
    });
    SteadyClock clock;
    devices::Mf2ModelCalibration cal(mf2::defaultMf2());
    client::usb::UsbMf2Config cfg;
    cfg.in_flight = in_flight;
    client::usb::UsbMf2 dev(cfg, cal, clock);
    dev.start();
    if (!dev.waitReady(5s)) {
      std::fprintf(stderr, "no stream: %s\n", dev.statusText().c_str());
      return 1;
    }
    std::vector<int64_t> rtt;
    rtt.reserve(200000);
    int64_t v = 0;
    while (dev.roundTrips().tryPop(v)) {
    }
    const uint64_t in0 = dev.stats().packets_in.load(), out0 = dev.stats().commands_out.load();
    const auto t0 = std::chrono::steady_clock::now();
    devices::ForceCommand f;
    f.force_n[kThumb] = Vec3(0.5, 0.0, 0.0);
    while (std::chrono::steady_clock::now() - t0 < std::chrono::duration<double>(seconds)) {
      dev.write(f);  // the loop's side at about 2 kHz
      while (dev.roundTrips().tryPop(v)) rtt.push_back(v);
      std::this_thread::sleep_for(500us);
    }
    const double dt = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const uint64_t in = dev.stats().packets_in.load() - in0,
                   out = dev.stats().commands_out.load() - out0;
    dev.stop();
    std::sort(rtt.begin(), rtt.end());
    auto pct = [&](double p) {
      return rtt.empty()
                 ? 0.0
                 : static_cast<double>(
                       rtt[static_cast<std::size_t>(p * static_cast<double>(rtt.size() - 1))]) /
                       1e3;
    };
    std::printf(
        "emulated MF-2, %.1f s%s%s: %.0f state packets/s, %.0f commands/s (%.2f x the 1 kHz device "
        "rate)\n",
        dt, pin_cpu >= 0 ? ", pinned to one CPU" : "",
        default_slack ? ", default timer slack" : ", 1 ns timer slack",
        static_cast<double>(in) / dt, static_cast<double>(out) / dt,
        static_cast<double>(in) / dt / 1000.0);
    std::printf(
        "command -> echoing state, us: p50 %.0f  p90 %.0f  p99 %.0f  max %.0f  (%zu samples)\n",
        pct(0.5), pct(0.9), pct(0.99), pct(1.0), rtt.size());
    const auto c = emu.counters();
    std::printf("rejected %llu, lost %llu, unhandled ioctls %llu\n",
                static_cast<unsigned long long>(dev.stats().rejectedTotal()),
                static_cast<unsigned long long>(dev.stats().lost.load()),
                static_cast<unsigned long long>(c.unhandled_ioctls));
    return in > 0 && c.unhandled_ioctls == 0 ? 0 : 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "telehand_bench_usb: %s\n", e.what());
    return 1;
  }
}
