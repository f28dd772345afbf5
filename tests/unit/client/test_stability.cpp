// Every shipped patient case and a few random ones, rendered by the client's loop on the
// simulated MF-2 for 30 s of mobilization (1, 3 and 6 Hz) and 30 s of exploration: stable,
// passive, never clamped, never faulted. The sweep over more random cases is
// tests/bench/bench_stability.cpp (docs/manual.md "Tests").
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "../../stability/stability_run.h"
#include "telehand/config/config.h"

namespace telehand::client {
namespace {

using stability::Motion;

std::vector<std::string> shippedCases() { return listPatientCases(TELEHAND_DEPLOY_DIR "/cases"); }

void expectStable(const JointModelParams& m, Motion motion, double hz, uint64_t seed) {
  const stability::RunResult r = stability::runStability(m, motion, hz, 30.0, seed);
  EXPECT_EQ(stability::failures(r), "")
      << m.case_name.data()
      << (motion == Motion::kMobilization ? " mobilization " : " exploration ") << hz
      << " Hz: range excess " << r.range_excess_deg << " deg, request " << r.request_max_n
      << " N, lowest energy " << r.min_energy_j << " J, " << r.clamps << " clamps, fault "
      << loop::faultName(r.fault);
}

TEST(Stability, ShippedCasesAreStablePassiveAndUnclamped) {
  const auto names = shippedCases();
  ASSERT_GE(names.size(), 5u);
  for (const std::string& name : names) {
    const PatientCase pc = loadPatientCaseByName(TELEHAND_DEPLOY_DIR "/cases", name);
    for (double hz : {1.0, 3.0, 6.0}) expectStable(pc.model, Motion::kMobilization, hz, 1);
    expectStable(pc.model, Motion::kExploration, 3.0, 1);
  }
}

TEST(Stability, RandomCasesAreStablePassiveAndUnclamped) {
  // Seeds the sweep did not single out: the first few.
  for (uint64_t seed = 1; seed <= 3; ++seed) {
    const PatientCase pc = randomPatientCase(seed);
    for (double hz : {1.0, 3.0, 6.0}) expectStable(pc.model, Motion::kMobilization, hz, seed);
    expectStable(pc.model, Motion::kExploration, 3.0, seed);
  }
}

}  // namespace
}  // namespace telehand::client
