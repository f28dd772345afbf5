// telehand-probe: lists the MF-2s attached over USB and, with --live, streams one of them
// and prints its readings (raw counts, FSR forces, status, link health). It never commands
// force: the driver sends zero current with the actuators disabled.
#include <chrono>
#include <cstdio>
#include <iostream>
#include <thread>

#include "telehand/app/cli.h"
#include "telehand/client/usb/usb_mf2.h"
#include "telehand/core/error.h"

int main(int argc, char** argv) {
  using namespace telehand;
  using namespace telehand::client::usb;
  using namespace telehand::devices;
  using namespace std::chrono_literals;
  CLI::App app{
      "telehand-probe: list the MF-2 haptic devices attached over USB; --live streams "
      "one and prints its readings. Exit code 0 when an MF-2 is usable, 1 when none "
      "is, 2 on bad options."};
  std::string vid = "1209", pid = "4d32", serial, device_file;
  double live_s = 0.0, rate_hz = 10.0;
  app.add_option("--usb-vid", vid, "USB vendor ID, hex")->capture_default_str();
  app.add_option("--usb-pid", pid, "USB product ID, hex")->capture_default_str();
  app.add_option("--serial", serial, "pick the MF-2 with this serial number");
  app.add_option("--device-file", device_file, "MF-2 device file for --live (default: built in)")
      ->check(CLI::ExistingFile);
  app.add_option("--live", live_s, "stream for this many seconds and print readings")
      ->check(CLI::PositiveNumber);
  app.add_option("--rate", rate_hz, "lines per second with --live")
      ->check(CLI::Range(0.5, 100.0))
      ->capture_default_str();
  TELEHAND_CLI_PARSE(app, argc, argv)

  try {
    UsbMf2Config cfg;
    cfg.vendor_id = parseUsbId(vid, "--usb-vid");
    cfg.product_id = parseUsbId(pid, "--usb-pid");
    cfg.serial = serial;
    const auto devices = listUsbMf2(cfg.vendor_id, cfg.product_id);
    std::cout << formatUsbMf2List(devices, cfg.vendor_id, cfg.product_id);
    bool usable = false;
    for (const auto& d : devices) usable |= d.problem.empty();
    if (live_s <= 0.0) return usable ? 0 : 1;

    SteadyClock clock;
    Mf2ModelCalibration cal(device_file.empty() ? mf2::defaultMf2()
                                                : mf2::loadMf2Description(device_file));
    UsbMf2 dev(cfg, cal, clock);
    dev.start();
    if (!dev.waitReady(2s)) {
      std::cerr << "telehand-probe: " << dev.statusText() << "\n";
      return 1;
    }
    const auto t0 = std::chrono::steady_clock::now();
    const auto period = std::chrono::duration<double>(1.0 / rate_hz);
    auto next = t0;
    uint64_t last_packets = 0;
    auto last_t = t0;
    while (std::chrono::steady_clock::now() - t0 < std::chrono::duration<double>(live_s)) {
      next += std::chrono::duration_cast<std::chrono::steady_clock::duration>(period);
      std::this_thread::sleep_until(next);
      for (const auto& m : dev.takeMessages()) std::cout << "# " << m << "\n";
      proto::StatePacket s;
      DeviceSample ds;
      const bool have_raw = dev.latestRaw(s);
      dev.read(ds);
      if (!have_raw) continue;
      const auto now = std::chrono::steady_clock::now();
      const uint64_t packets = dev.stats().packets_in.load();
      const double hz = static_cast<double>(packets - last_packets) /
                        std::chrono::duration<double>(now - last_t).count();
      last_packets = packets;
      last_t = now;
      std::printf("seq %u t %.3f s status 0x%02x | act", s.seq,
                  static_cast<double>(s.device_time_us) * 1e-6, s.status);
      for (const int32_t c : s.actuator_counts) std::printf(" %d", c);
      std::printf(" | gimbal");
      for (const int32_t c : s.gimbal_counts) std::printf(" %d", c);
      std::printf(" | thumb %.1f %.1f %.1f mm, index %.1f %.1f %.1f mm |",
                  ds.fingers[0].position_m.x() * 1e3, ds.fingers[0].position_m.y() * 1e3,
                  ds.fingers[0].position_m.z() * 1e3, ds.fingers[1].position_m.x() * 1e3,
                  ds.fingers[1].position_m.y() * 1e3, ds.fingers[1].position_m.z() * 1e3);
      std::printf(" fsr N");
      for (int k = 0; k < 2; ++k) {
        for (const float f : ds.fingers[k].fsr_n) std::printf(" %.2f", static_cast<double>(f));
      }
      const auto& st = dev.stats();
      const uint64_t rtts = st.rtt_count.load();
      std::printf(
          " | %.0f Hz, rejected %llu, lost %llu, rtt mean %.0f us\n", hz,
          static_cast<unsigned long long>(st.rejectedTotal() + st.stale.load() +
                                          st.out_of_order.load()),
          static_cast<unsigned long long>(st.lost.load()),
          rtts ? static_cast<double>(st.rtt_sum_ns.load()) / static_cast<double>(rtts) / 1e3 : 0.0);
      std::fflush(stdout);
    }
    dev.stop();
    for (const auto& m : dev.takeMessages()) std::cout << "# " << m << "\n";
    return 0;
  } catch (const ConfigError& e) {
    std::cerr << "telehand-probe: " << e.what() << "\n";
    return 2;
  } catch (const Error& e) {
    std::cerr << "telehand-probe: " << e.what() << "\n";
    return 1;
  }
}
