#pragma once
// Samples, sessions and comparisons the record store tests share (SQLite and PostgreSQL).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <random>
#include <string>
#include <type_traits>
#include <vector>

#include "telehand/server/store/store.h"

namespace telehand::server::store::store_test {

/// A sample whose every field follows from its session and sequence number.
inline Sample sample(uint64_t session, uint64_t seq) {
  Sample s{};
  s.session_id = session;
  s.seq = seq;
  s.source_time_ns = 1'000'000'000 + static_cast<int64_t>(seq) * 1'000'000;
  s.model_version = 1;
  s.flags = static_cast<uint32_t>(seq % 4);
  for (int a = 0; a < 3; ++a) {
    s.mcp_angles_rad[a] = 0.1 * a + 0.001 * static_cast<double>(seq);
    s.mcp_torque_nm[a] = -0.01 * a;
  }
  for (int k = 0; k < 2; ++k) {
    for (int i = 0; i < 3; ++i) {
      s.fingers[k].position_m[i] = 0.01 * (k + 1) + 0.001 * i;
      s.fingers[k].command_n[i] = 0.5 * i - k;
    }
    s.fingers[k].orientation_q[0] = 1.0;
    for (int i = 0; i < 4; ++i)
      s.fingers[k].fsr_n[i] = static_cast<float>(seq % 7) + 0.25f * static_cast<float>(i);
    s.fingers[k].tangential_n = 0.5f;
    s.fingers[k].normal_n = 2.0f;
  }
  return s;
}

/// sample(session, seq) for from <= seq < to.
inline std::vector<Sample> samples(uint64_t session, uint64_t from, uint64_t to) {
  std::vector<Sample> v;
  for (uint64_t i = from; i < to; ++i) v.push_back(sample(session, i));
  return v;
}

inline SessionInfo info(const std::string& user) {
  SessionInfo i;
  i.user = user;
  i.case_name = "healthy";
  i.mode = "mobilization";
  i.started_ns = 1'700'000'000'000'000'000;
  return i;
}

inline std::vector<uint64_t> seqsOf(SessionStore& store, uint64_t id) {
  std::vector<uint64_t> out;
  store.forEachSample(id, [&](const Sample& s, bool) { out.push_back(s.seq); });
  return out;
}

/// Every field of a sample, random, with magnitudes over many decades.
inline Sample randomSample(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> mant(-1.0, 1.0);
  std::uniform_int_distribution<int> exp64(-300, 300);
  std::uniform_int_distribution<int> exp32(-30, 30);
  auto d = [&] { return mant(rng) * std::pow(10.0, exp64(rng)); };
  auto f = [&] { return static_cast<float>(mant(rng) * std::pow(10.0, exp32(rng))); };
  Sample s{};
  s.seq = rng();
  s.source_time_ns = static_cast<int64_t>(rng());
  s.model_version = static_cast<uint32_t>(rng());
  s.flags = static_cast<uint32_t>(rng());
  for (auto& finger : s.fingers) {
    for (auto& v : finger.position_m) v = d();
    for (auto& v : finger.orientation_q) v = d();
    for (auto& v : finger.fsr_n) v = f();
    finger.tangential_n = f();
    finger.normal_n = f();
    for (auto& v : finger.command_n) v = d();
  }
  for (auto& v : s.mcp_angles_rad) v = d();
  for (auto& v : s.mcp_torque_nm) v = d();
  s.passivity_energy_j = f();
  s.passivity_damping = f();
  return s;
}

/// Field-by-field equality; NaN equals NaN.
template <class T>
void expectSame(T got, T want, const char* what) {
  if constexpr (std::is_floating_point_v<T>) {
    if (std::isnan(want)) {
      EXPECT_TRUE(std::isnan(got)) << what;
      return;
    }
  }
  EXPECT_EQ(got, want) << what;
}

inline void expectSameSample(const Sample& got, const Sample& want) {
  expectSame(got.session_id, want.session_id, "session_id");
  expectSame(got.seq, want.seq, "seq");
  expectSame(got.source_time_ns, want.source_time_ns, "source_time_ns");
  expectSame(got.model_version, want.model_version, "model_version");
  expectSame(got.flags, want.flags, "flags");
  for (int k = 0; k < 2; ++k) {
    SCOPED_TRACE("finger " + std::to_string(k));
    const auto& g = got.fingers[k];
    const auto& w = want.fingers[k];
    for (int i = 0; i < 3; ++i) expectSame(g.position_m[i], w.position_m[i], "position_m");
    for (int i = 0; i < 4; ++i) expectSame(g.orientation_q[i], w.orientation_q[i], "orientation_q");
    for (int i = 0; i < 4; ++i) expectSame(g.fsr_n[i], w.fsr_n[i], "fsr_n");
    expectSame(g.tangential_n, w.tangential_n, "tangential_n");
    expectSame(g.normal_n, w.normal_n, "normal_n");
    for (int i = 0; i < 3; ++i) expectSame(g.command_n[i], w.command_n[i], "command_n");
  }
  for (int i = 0; i < 3; ++i)
    expectSame(got.mcp_angles_rad[i], want.mcp_angles_rad[i], "mcp_angles_rad");
  for (int i = 0; i < 3; ++i)
    expectSame(got.mcp_torque_nm[i], want.mcp_torque_nm[i], "mcp_torque_nm");
  expectSame(got.passivity_energy_j, want.passivity_energy_j, "passivity_energy_j");
  expectSame(got.passivity_damping, want.passivity_damping, "passivity_damping");
}

}  // namespace telehand::server::store::store_test
