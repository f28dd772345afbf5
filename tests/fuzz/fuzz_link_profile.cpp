// libFuzzer target: link profile text (deploy/links/*.toml) into parseLinkProfile.
// Properties: a refusal is a ConfigError naming the file; an accepted profile has every
// value finite and in its documented range, and jitter within the one-way delay.
#include <cmath>

#include "telehand/netem/link_emulation.h"
#include "toml_input.h"

using namespace telehand;

namespace {
bool in(double v, double lo, double hi) { return std::isfinite(v) && v >= lo && v <= hi; }
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  LinkProfile p;
  if (!fuzz::parsesOrRefuses(
          data, size, "link.toml",
          [&](const std::string& t, const std::string& o) { p = parseLinkProfile(t, o); })) {
    return 0;
  }
  fuzz::check(in(p.rtt_ms, 0.0, 10000.0) && in(p.jitter_ms, 0.0, 5000.0));
  fuzz::check(in(p.jitter_corr_ms, 0.0, 60000.0) && in(p.loss_pct, 0.0, 90.0));
  fuzz::check(in(p.loss_burst, 1.0, 1000.0) && in(p.reorder_pct, 0.0, 100.0));
  fuzz::check(p.jitter_ms <= p.rtt_ms * 0.5);
  return 0;
}
