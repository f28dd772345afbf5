#pragma once
// The sample's fields as the record keeps them, one column each: the order and names the
// SQLite and PostgreSQL tables, their inserts and reads, and the CSV export all follow.
#include <string>
#include <vector>

#include "telehand/core/sample.h"

namespace telehand::server::store::detail {

/// Calls f(field) for every field of a sample except session_id, in sampleColumns() order.
/// The one place that order is written down.
template <class S, class F>
void visitFields(S& s, F&& f) {
  f(s.seq);
  f(s.source_time_ns);
  f(s.model_version);
  f(s.flags);
  for (auto& v : s.mcp_angles_rad) f(v);
  for (auto& v : s.mcp_torque_nm) f(v);
  for (auto& finger : s.fingers) {
    for (auto& v : finger.position_m) f(v);
    for (auto& v : finger.orientation_q) f(v);
    for (auto& v : finger.fsr_n) f(v);
    f(finger.tangential_n);
    f(finger.normal_n);
    for (auto& v : finger.command_n) f(v);
  }
  f(s.passivity_energy_j);
  f(s.passivity_damping);
}

/// The names visitFields() goes through, in its order (sampleColumns() without "valid").
const std::vector<std::string>& fieldNames();

}  // namespace telehand::server::store::detail
