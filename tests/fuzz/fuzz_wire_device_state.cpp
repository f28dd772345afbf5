// libFuzzer target: a DeviceState from the network (CDR through Cyclone's deserializer, as
// the server's reader takes it) into fromWire and firstInvalid, the server's plausibility
// check (core/sample.h, docs/security.md "Bounds").
// Properties: fromWire copies every field (back to the wire gives the same struct);
// firstInvalid names a field exactly when one is not finite or out of sample_bounds (checked
// here independently), and firstNonFinite agrees on finiteness.
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <string>

#include "cdr_input.h"
#include "telehand/protocol/wire.h"

using namespace telehand;

using fuzz::check;

namespace {
bool within(double v, double bound) { return std::isfinite(v) && std::abs(v) <= bound; }

// sample_bounds, restated.
bool plausible(const Sample& s, bool* all_finite) {
  namespace b = sample_bounds;
  bool finite = true;
  bool ok = s.seq < b::kMaxSeq;
  for (const auto& f : s.fingers) {
    double q2 = 0.0;
    for (int i = 0; i < 3; ++i) {
      finite = finite && std::isfinite(f.position_m[i]) && std::isfinite(f.command_n[i]);
      ok = ok && within(f.position_m[i], b::kPositionM) && within(f.command_n[i], b::kCommandN);
    }
    for (int i = 0; i < 4; ++i) {
      finite = finite && std::isfinite(f.orientation_q[i]) && std::isfinite(f.fsr_n[i]);
      ok = ok && within(f.fsr_n[i], b::kFsrN);
      q2 += f.orientation_q[i] * f.orientation_q[i];
    }
    finite = finite && std::isfinite(f.tangential_n) && std::isfinite(f.normal_n);
    ok = ok && std::abs(std::sqrt(q2) - 1.0) <= b::kQuatNormTolerance;
    ok = ok && within(f.tangential_n, b::kThimbleForceN) && within(f.normal_n, b::kThimbleForceN);
  }
  for (int i = 0; i < 3; ++i) {
    finite = finite && std::isfinite(s.mcp_angles_rad[i]) && std::isfinite(s.mcp_torque_nm[i]);
    ok =
        ok && within(s.mcp_angles_rad[i], b::kAngleRad) && within(s.mcp_torque_nm[i], b::kTorqueNm);
  }
  *all_finite = finite;
  return ok && finite;
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  fuzz::CdrSample<telehand_msg_DeviceState> in(telehand_msg_DeviceState_desc);
  if (!in.read(data, size)) return 0;
  const Sample s = fromWire(in.get());

  telehand_msg_DeviceState again;
  std::memset(&again, 0, sizeof again);
  toWire(s, again);
  check(std::memcmp(&again, &in.get(), sizeof again) == 0);

  bool all_finite = false;
  const bool ok = plausible(s, &all_finite);
  const auto bad = firstInvalid(s);
  check(bad.has_value() != ok);
  if (bad) check(!bad->empty());
  const auto nonfinite = firstNonFinite(s);
  check(nonfinite.has_value() != all_finite);
  return 0;
}
