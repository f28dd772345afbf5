// libFuzzer target: a JointModel from the network (CDR through Cyclone's deserializer, as
// the client's reader takes it) into fromWire, the client's only check before rendering it.
// Properties: a refusal names a reason; an accepted model satisfies what fromWire documents
// (every field finite, non-empty ranges within a patient case's bounds, curves whose force rises
// over their range and stays within kMaxHoldingForceN there, neutral zones, gains and the lever
// arm in range, a unit joint orientation, grip offsets within ±30 deg, a terminated case name)
// and goes back to the wire and in again unchanged.
#include <cmath>
#include <cstdlib>
#include <string>

#include "cdr_input.h"
#include "telehand/protocol/wire.h"

using namespace telehand;

using fuzz::check;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size) {
  fuzz::CdrSample<telehand_msg_JointModel> in(telehand_msg_JointModel_desc);
  if (!in.read(data, size)) return 0;
  std::string why;
  const auto p = fromWire(in.get(), &why);
  if (!p) {
    check(!why.empty());
    return 0;
  }
  for (const auto& a : p->axes) {
    for (double c : a.coeffs) check(std::isfinite(c));
    check(std::isfinite(a.min_deg) && std::isfinite(a.max_deg) && a.min_deg < a.max_deg);
    check(kRangeMinDegBounds.contains(a.min_deg) && kRangeMaxDegBounds.contains(a.max_deg));
    check(!passiveCurveProblem(a).has_value());
    // Rising, so bounded by its ends; and rising at both.
    for (double deg : {a.min_deg, a.max_deg}) {
      check(std::abs(a.eval(deg)) <= kMaxHoldingForceN);
      check(a.slope(deg) > 0.0);
    }
  }
  for (double z : p->neutral_zone_deg) check(z >= 0.0 && z <= 30.0);
  check(p->speed_gain_s_per_rad >= 0.0 && p->speed_gain_s_per_rad <= 20.0);
  check(p->lever_arm_m > 0.0 && p->lever_arm_m < 0.2);
  check(p->force_scale > 0.0 && p->force_scale <= 1.0);
  check(p->damping_nms_per_rad >= 0.0 && p->damping_nms_per_rad < 1.0);
  check(allFinite(p->joint_origin_m));
  check(std::abs(p->joint_orientation.norm() - 1.0) < 1e-12);
  for (int i = 0; i < kAxes; ++i) {
    check(std::abs(p->grip_offset_rad[i]) <= degToRad(JointModelParams::kMaxGripOffsetDeg));
  }
  check(p->case_name.back() == '\0');
  check(p->knn == nullptr);

  telehand_msg_JointModel again{};
  toWire(*p, in.get().session_id, again);
  std::string why2;
  const auto q = fromWire(again, &why2);
  check(q.has_value() && why2.empty() && *q == *p);
  return 0;
}
