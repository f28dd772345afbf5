#include "session.h"

#include <spdlog/fmt/fmt.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <string>
#include <thread>

#include "telehand/app/signals.h"
#include "telehand/protocol/dds.h"

namespace telehand::client::app {

using namespace std::chrono_literals;

RunTotals runSession(const ClientOptions& o, loop::HapticLoop& loop, link::ClientLink& link,
                     usb::UsbMf2* usb, const std::function<bool(double)>& step) {
  const ClientConfig& cfg = o.cfg;
  RunTotals r;
  installStopSignals();
  link.start();
  loop.start();
  if (cfg.loop.rt_priority > 0) {
    std::this_thread::sleep_for(10ms);
    if (const int err = loop.realtimeError()) {
      std::cerr << "telehand-client: SCHED_FIFO priority " << cfg.loop.rt_priority << " refused ("
                << std::strerror(err) << "): the loop runs at normal priority\n";
    }
  }
  const auto t0 = std::chrono::steady_clock::now();
  const bool tty = isatty(STDOUT_FILENO) != 0;
  auto next_print = t0 + 1s;
  uint64_t live_prev = 0;
  while (!g_stop_requested.load()) {
    std::this_thread::sleep_for(step ? 5ms : 50ms);
    const auto now = std::chrono::steady_clock::now();
    const double t = std::chrono::duration<double>(now - t0).count();
    const auto& h = loop.health();
    if (t > cfg.op.ramp_s + 0.5) {
      r.applied_min = std::min(r.applied_min, h.applied_ref_n.load());
      r.applied_max = std::max(r.applied_max, h.applied_ref_n.load());
    }
    for (const auto& m : link.takeMessages()) std::cerr << "server: " << m << "\n";
    if (usb != nullptr) {
      for (const auto& m : usb->takeMessages()) std::cerr << "device: " << m << "\n";
    }
    if (step ? !step(t) : t >= o.seconds) break;
    // A rendering fault ends the session (the loop already commands zero force).
    if (loop.fault() != loop::LoopFault::kNone) break;
    if (!o.quiet && !step && now >= next_print) {
      next_print += 1s;
      const uint64_t live = link.stats().live_sent.load();
      const std::string line = fmt::format(
          "{} t={:5.1f}s  sent {:7}  live {:4}/s  overruns {}  force {:.2f} N  applied {:5.1f} N "
          "ref  model v{}  PO {:.3f} J",
          tty ? "\r" : "", t, link.stats().samples_sent.load(), live - live_prev, h.overruns.load(),
          h.last_force_n.load(), h.applied_ref_n.load(), h.model_version.load(),
          h.passivity_energy_j.load());
      live_prev = live;
      std::cout << line << (tty ? "" : "\n") << std::flush;
    }
  }
  loop.stop();
  if (usb != nullptr) {
    usb->stop();
    for (const auto& m : usb->takeMessages()) std::cerr << "device: " << m << "\n";
  }
  r.duration_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  link.stop();
  if (!o.quiet && tty) std::cout << "\n";
  return r;
}

std::optional<std::string> faultMessage(const loop::LoopHealth& h, const SafetyLimits& limits) {
  const auto f = static_cast<loop::LoopFault>(h.fault.load());
  if (f == loop::LoopFault::kNone) return std::nullopt;
  return fmt::format(
      "rendering fault ({}) at t={:.3f} s after {} clamps: peak requested force {:.2f} N per "
      "finger (limit {:.1f} N), rendered angles up to {:.1f} deg past the range; the session was "
      "ended and the force set to zero",
      loop::faultName(f), static_cast<double>(h.fault_time_ns.load()) * 1e-9,
      static_cast<unsigned long long>(h.fault_clamps.load()), h.fault_peak_force_n.load(),
      limits.max_force_n, h.range_excess_max_deg.load());
}

int printSummary(const ClientOptions& o, uint64_t session, bool capture, double force_scale,
                 const RunTotals& t, const loop::LoopHealth& h, link::ClientLink& link,
                 usb::UsbMf2* usb, const link::CloseResult& closed) {
  const ClientConfig& cfg = o.cfg;
  const double duration = t.duration_s, applied_min = t.applied_min, applied_max = t.applied_max;
  const std::string& render = o.render;
  const double deadband = o.deadband;
  const uint64_t sent = link.stats().samples_sent.load();
  std::printf(
      "summary: session %llu, %.1f s, %llu ticks, %llu samples sent (%llu in %llu record chunks)\n",
      static_cast<unsigned long long>(session), duration,
      static_cast<unsigned long long>(h.ticks.load()), static_cast<unsigned long long>(sent),
      static_cast<unsigned long long>(link.stats().samples_chunked.load()),
      static_cast<unsigned long long>(link.stats().chunks_sent.load()));
  std::printf(
      "  loop: %llu overruns, worst wake-up %.0f us late, %llu watchdog trips, "
      "%llu clamps, %llu rate-limited, %llu samples dropped, %llu non-finite forces zeroed, "
      "%llu device writes failed, %llu device samples with a position not finite\n",
      static_cast<unsigned long long>(h.overruns.load()),
      static_cast<double>(h.max_lateness_ns.load()) / 1e3,
      static_cast<unsigned long long>(h.watchdog_trips.load()),
      static_cast<unsigned long long>(h.clamped.load()),
      static_cast<unsigned long long>(h.rate_limited.load()),
      static_cast<unsigned long long>(h.samples_dropped.load()),
      static_cast<unsigned long long>(h.nonfinite.load()),
      static_cast<unsigned long long>(h.device_write_failures.load()),
      static_cast<unsigned long long>(h.device_nonfinite.load()));
  if (h.massage.load() && h.massage_ticks.load() > 0) {
    std::printf(
        "  massage: both thimbles within 10 ± 2 N (reference) on %.1f %% of %llu ticks, largest "
        "device force %.2f N\n",
        100.0 * static_cast<double>(h.massage_in_band.load()) /
            static_cast<double>(h.massage_ticks.load()),
        static_cast<unsigned long long>(h.massage_ticks.load()), h.force_max_n.load());
  }
  if (h.clamp_holds.load() > 0) {
    std::printf(
        "  warning: %llu pushes held beyond the device's limit (force clamped >= 250 ms, "
        "longest %.2f s)\n",
        static_cast<unsigned long long>(h.clamp_holds.load()),
        static_cast<double>(h.clamp_hold_max_ns.load()) * 1e-9);
  }
  if (capture) {
    // The loop scales what the thimbles measure by the rendering scale; a capture has none.
    const double scale = force_scale;
    std::printf("  force: commanded %.2f N (actuators off); the thimbles measured %.1f..%.1f N\n",
                h.force_max_n.load(), applied_min > applied_max ? 0.0 : applied_min * scale,
                applied_max * scale);
  } else if (h.massage.load()) {  // the band is the massage's, on the line above
    std::printf(
        "  force: commanded up to %.2f N per finger; applied %.1f..%.1f N at reference "
        "scale\n",
        h.force_max_n.load(), applied_min > applied_max ? 0.0 : applied_min, applied_max);
  } else {
    std::printf(
        "  force: commanded up to %.2f N per finger; applied %.1f..%.1f N at reference scale "
        "(band %.0f-%.0f N)\n",
        h.force_max_n.load(), applied_min > applied_max ? 0.0 : applied_min, applied_max,
        cfg.op.band_min_n, cfg.op.band_max_n);
  }
  // The bounds at the nominal tick; late ticks lower them for a second after each.
  std::string lowered;
  if (h.passivity_bound_lowest_ns_per_m.load() < h.passivity_bound_nominal_ns_per_m.load() ||
      h.joint_damping_cap_lowest_ns_per_m.load() < h.joint_damping_cap_nominal_ns_per_m.load()) {
    char buf[96];
    std::snprintf(buf, sizeof buf, "; after late ticks as low as %.1f and %.1f",
                  h.passivity_bound_lowest_ns_per_m.load(),
                  h.joint_damping_cap_lowest_ns_per_m.load());
    lowered = buf;
  }
  std::printf(
      "  teleop: render %s; DeviceState live %.1f packets/s (%llu of %llu samples%s)%s; "
      "passivity energy %.4f J (lowest %.4f J), controller active %llu ticks (damping up to "
      "%.1f N*s/m, the joint's %.1f%s); "
      "%llu model updates, largest update step %.3f N (%.2f of the bound)\n",
      render.c_str(), static_cast<double>(link.stats().live_sent.load()) / std::max(duration, 1e-3),
      static_cast<unsigned long long>(link.stats().live_sent.load()),
      static_cast<unsigned long long>(sent), deadband > 0.0 ? ", deadband" : "",
      render == "direct"
          ? (", " + std::to_string(link.stats().direct_forces.load()) + " server forces received")
                .c_str()
          : "",
      h.passivity_energy_j.load(), h.passivity_min_energy_j.load(),
      static_cast<unsigned long long>(h.passivity_activations.load()),
      h.passivity_bound_nominal_ns_per_m.load(), h.joint_damping_cap_nominal_ns_per_m.load(),
      lowered.c_str(), static_cast<unsigned long long>(h.models_applied.load()),
      h.update_step_max_n.load(), h.update_step_max_ratio.load());
  if (render == "direct") {
    // A server force past its age limit is not rendered (HapticLoop: a server that stopped
    // sending, or a failover); one for a sample not sent yet is refused.
    std::printf(
        "  direct: %llu server forces taken; none fresh (older than %.0f ms) on %llu ticks in "
        "%llu gaps, nothing rendered then; %llu refused (for samples not sent yet), %llu "
        "refused as not finite\n",
        static_cast<unsigned long long>(h.direct_forces.load()),
        static_cast<double>(loop::TeleopOptions{}.direct_max_age_ns) * 1e-6,
        static_cast<unsigned long long>(h.direct_stale_ticks.load()),
        static_cast<unsigned long long>(h.direct_stale_gaps.load()),
        static_cast<unsigned long long>(h.direct_forces_ahead.load()),
        static_cast<unsigned long long>(link.stats().direct_rejected.load()));
  }
  if (const auto crypto = dds::cryptoCounts()) {
    std::printf("  security: %s\n", dds::cryptoSummary(*crypto).c_str());
  }
  if (usb != nullptr) {
    const auto& u = usb->stats();
    const uint64_t rtts = u.rtt_count.load();
    std::printf(
        "  usb: %llu state packets, %llu commands, %llu rejected (%llu stale, %llu out of "
        "order), %llu lost, %llu stalls, %llu timeouts, %llu overflows, %llu disconnects; "
        "command round trip mean %.0f us, max %.0f us\n",
        static_cast<unsigned long long>(u.packets_in.load()),
        static_cast<unsigned long long>(u.commands_out.load()),
        static_cast<unsigned long long>(u.rejectedTotal()),
        static_cast<unsigned long long>(u.stale.load()),
        static_cast<unsigned long long>(u.out_of_order.load()),
        static_cast<unsigned long long>(u.lost.load()),
        static_cast<unsigned long long>(u.stalls.load()),
        static_cast<unsigned long long>(u.timeouts.load()),
        static_cast<unsigned long long>(u.overflows.load()),
        static_cast<unsigned long long>(u.disconnects.load()),
        rtts ? static_cast<double>(u.rtt_sum_ns.load()) / static_cast<double>(rtts) / 1e3 : 0.0,
        static_cast<double>(u.rtt_max_ns.load()) / 1e3);
    if (u.bad_pose.load() > 0 || u.device_rx_errors.load() > 0) {
      std::printf(
          "  usb warning: %llu state packets gave a pose outside the linkage's range (no force "
          "then: an encoder that lost count, or the device file's zero_counts off), the device "
          "refused %llu commands\n",
          static_cast<unsigned long long>(u.bad_pose.load()),
          static_cast<unsigned long long>(u.device_rx_errors.load()));
    }
  }
  const auto& ls = link.stats();
  if (ls.resumes.load() > 0 || ls.retained_dropped.load() > 0) {
    std::printf(
        "  recovery: resumed %llu time(s) on a server after the server went away, %llu record "
        "chunks sent again, %llu samples dropped unacknowledged (spill file full)\n",
        static_cast<unsigned long long>(ls.resumes.load()),
        static_cast<unsigned long long>(ls.chunks_resent.load()),
        static_cast<unsigned long long>(ls.retained_dropped.load()));
  }
  if (!closed.confirmed) {
    std::printf(
        "  record: no server confirmed the close (waited %.1f s, the last of them without "
        "progress); %llu samples were not acknowledged as stored\n",
        closed.waited_s, static_cast<unsigned long long>(ls.retained_samples.load()));
    return 3;
  }
  std::printf("  record: %llu samples recorded, %llu missing, in %s; sent %s\n",
              static_cast<unsigned long long>(closed.samples_recorded),
              static_cast<unsigned long long>(closed.samples_missing), closed.record.c_str(),
              link.recordDigest().text().c_str());
  if (ls.acks_rejected.load() > 0) {
    std::printf("  warning: %llu statuses said more was stored than was sent; not believed\n",
                static_cast<unsigned long long>(ls.acks_rejected.load()));
  }
  if (const uint64_t dropped = h.samples_dropped.load(); dropped > 0) {
    // Never sent (the loop's ring to the link was full), so the server saw no gap: the record
    // is whole for what was sent, and the session is not.
    std::printf(
        "  record: %llu samples were dropped before they were sent (the link fell "
        "behind the loop); the session is not recorded whole\n",
        static_cast<unsigned long long>(dropped));
    return 3;
  }
  return closed.samples_missing == 0 && closed.samples_recorded == sent ? 0 : 3;
}

}  // namespace telehand::client::app
