#include "frames.h"

#include <spdlog/fmt/fmt.h>

#include <algorithm>
#include <cmath>
#include <iterator>
#include <nlohmann/json.hpp>

#include "telehand/protocol/wire.h"

namespace telehand::web {

namespace {

void appendNumber(std::string& out, double v) {
  if (std::isfinite(v)) {
    fmt::format_to(std::back_inserter(out), "{:.6g}", v);
  } else {
    out += "null";
  }
}

template <std::size_t N>
void appendArray(std::string& out, const double (&a)[N], std::size_t n = N) {
  out += '[';
  for (std::size_t i = 0; i < std::min(n, N); ++i) {
    if (i) out += ',';
    appendNumber(out, a[i]);
  }
  out += ']';
}

template <std::size_t N>
void appendPair(std::string& out, const double (&a)[2][N]) {
  out += '[';
  appendArray(out, a[0]);
  out += ',';
  appendArray(out, a[1]);
  out += ']';
}

double ms(int64_t ns) { return static_cast<double>(ns) * 1e-6; }

}  // namespace

std::string jsonString(std::string_view s) {
  return nlohmann::json(std::string(s))
      .dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

std::string jsonNumber(double v) {
  std::string out;
  appendNumber(out, v);
  return out;
}

std::string handFrame(const telehand_msg_HandState& h, int64_t rx_wall_ns) {
  std::string out;
  out.reserve(1400);
  fmt::format_to(std::back_inserter(out),
                 R"({{"type":"hand","session":{},"seq":{},"t_ms":{:.3f},"rx_ms":{:.3f},)"
                 R"("source":"{}","dev_seq":{},"dev_t_ms":{:.3f},"dev_hz":)",
                 h.session_id, h.seq, ms(h.source_time_ns), ms(rx_wall_ns),
                 h.source == telehand_msg_HAND_SOURCE_BULLET ? "bullet" : "joint_model",
                 h.device_seq, ms(h.device_time_ns));
  appendNumber(out, h.device_rate_hz);
  fmt::format_to(std::back_inserter(out), R"(,"dev_lost":{},"overruns":{},"model":{},"mcp":)",
                 h.device_lost, h.device_overruns, h.model_version);
  appendArray(out, h.mcp_angles_rad);
  out += R"(,"torque":)";
  appendArray(out, h.mcp_torque_nm);
  out += R"(,"tip":)";
  appendPair(out, h.fingertip_m);
  out += R"(,"tip_f":)";
  appendPair(out, h.fingertip_force_n);
  out += R"(,"force":)";
  appendNumber(out, h.applied_force_ref_n);
  if (h.technique == telehand_msg_TECHNIQUE_MASSAGE) {
    // The web: each pad's depth and the web's force on it (reference scale), and the
    // surface's 8x8 deflection, rows along the web's x.
    out += R"(,"web":{"depth":)";
    appendArray(out, h.web_depth_m);
    out += R"(,"force":)";
    appendPair(out, h.web_force_n);
    out += R"(,"grid":[)";
    for (std::size_t r = 0; r < std::size(h.web_grid_m); ++r) {
      if (r) out += ',';
      appendArray(out, h.web_grid_m[r]);
    }
    out += "]}";
  }
  if (h.source == telehand_msg_HAND_SOURCE_BULLET) {
    out += R"(,"joints":)";
    appendArray(out, h.joint_angles_rad, h.dof_count);
    out += R"(,"sphere":)";
    appendPair(out, h.sphere_m);
    out += R"(,"contact":)";
    appendPair(out, h.contact_force_n);
    if (h.bone_count > 0) {  // the first bone's pose places the hand in the device frame
      out += R"(,"bone0":)";
      appendArray(out, h.bone_pose[0]);
    }
  }
  out += '}';
  return out;
}

std::string eventFrame(const telehand_msg_SessionEvent& e) {
  return fmt::format(R"({{"type":"event","session":{},"seq":{},"t_ms":{:.3f},"kind":"{}",)"
                     R"("text":{}}})",
                     e.session_id, e.seq, ms(e.source_time_ns), eventKindName(e.kind),
                     jsonString(e.text));
}

std::string errorFrame(std::string_view code, std::string_view message) {
  return fmt::format(R"({{"type":"error","code":{},"message":{}}})", jsonString(code),
                     jsonString(message));
}

}  // namespace telehand::web
