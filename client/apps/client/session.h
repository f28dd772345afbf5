#pragma once
// The running session: the loop and the link until --seconds or Ctrl-C, with a progress
// line once a second; then its summary.
#include <cstdint>
#include <functional>
#include <optional>
#include <string>

#include "options.h"
#include "telehand/client/link/client_link.h"
#include "telehand/client/loop/haptic_loop.h"
#include "telehand/client/usb/usb_mf2.h"

namespace telehand::client::app {

struct RunTotals {
  double duration_s = 0.0;
  /// Force applied at reference scale after the ramp (min > max: none seen).
  double applied_min = 1e9, applied_max = 0.0;
};

/// Starts the link and the loop, runs them and stops them (the session stays open).
/// With `step` (a lesson run), it is called every 5 ms with the elapsed seconds and ends the
/// run by returning false; --seconds does not apply.
RunTotals runSession(const ClientOptions& o, loop::HapticLoop& loop, link::ClientLink& link,
                     usb::UsbMf2* usb, const std::function<bool(double)>& step = {});

/// What went wrong when the loop latched a rendering fault (which, when, the clamps and the
/// peak force), or nothing.
std::optional<std::string> faultMessage(const loop::LoopHealth& h, const SafetyLimits& limits);

/// Exit code of a session that ended on a rendering fault (docs/manual.md "Exit codes").
constexpr int kExitRenderingFault = 4;

/// Prints the summary; returns the exit code (0: every sample recorded, 3: the record is not
/// confirmed complete).
int printSummary(const ClientOptions& o, uint64_t session, bool capture, double force_scale,
                 const RunTotals& t, const loop::LoopHealth& h, link::ClientLink& link,
                 usb::UsbMf2* usb, const link::CloseResult& closed);

}  // namespace telehand::client::app
