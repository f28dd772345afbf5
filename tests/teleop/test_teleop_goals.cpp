// The teleoperation goals, asserted on the deterministic harness (simulated time, emulated
// link, the real loop and server code): these are properties of the design, not timings.
#include <gtest/gtest.h>

#include <optional>

#include "telehand/netem/teleop_harness.h"

namespace telehand::teleop {
namespace {

using client::loop::RenderMode;

const server::sim::HandModel& hand() {
  static const server::sim::HandModel h =
      server::sim::HandModel::load(std::string(TELEHAND_DEPLOY_DIR) + "/hand/hand24.urdf");
  return h;
}

LinkProfile link(double rtt_ms, double jitter_ms, double loss_pct, double burst) {
  LinkProfile p;
  p.name = "test";
  p.rtt_ms = rtt_ms;
  p.jitter_ms = jitter_ms;
  p.loss_pct = loss_pct;
  p.loss_burst = burst;
  p.reorder_pct = rtt_ms > 0 ? 0.5 : 0.0;
  return p;
}

CellSpec cell(const LinkProfile& l, RenderMode mode) {
  CellSpec s;
  s.link = l;
  s.render = mode;
  s.seconds = 12.0;
  s.steady_from_s = 3.0;
  return s;
}

const CellResult& reference() {
  static const CellResult r = runCell(cell(link(0, 0, 0, 1), RenderMode::kModel), &hand());
  return r;
}

TEST(TeleopGoals, ReferenceRunAppliesModelUpdatesAndRecordsEverySample) {
  const CellResult& r = reference();
  EXPECT_GT(r.models_applied, 5u) << "the case must publish updates during the run";
  EXPECT_EQ(r.samples_recorded, r.ticks);
  EXPECT_TRUE(stable(r)) << r.oscillation;
  EXPECT_TRUE(passive(r)) << r.po_min_j;
}

TEST(TeleopGoals, ModelMediatedStableAndPassiveAtOneSecondWithBurstyLoss) {
  const CellSpec s = cell(link(1000, 250, 10, 8), RenderMode::kModel);
  const CellResult r = runCell(s, &hand());
  EXPECT_TRUE(stable(r)) << "force above 15 Hz: " << r.oscillation;
  EXPECT_TRUE(passive(r)) << "lowest observer energy " << r.po_min_j << " J";
  EXPECT_GT(r.models_applied, 3u);
  EXPECT_LE(r.update_step_ratio, 1.0);
  EXPECT_EQ(r.samples_recorded, r.ticks) << "the record travels reliably";
}

TEST(TeleopGoals, ModelMediatedForceErrorUnderTheJndAtSpainAustralia) {
  const CellSpec s = cell(link(300, 20, 2, 4), RenderMode::kModel);
  const CellResult r = runCell(s, &hand());
  EXPECT_LT(forceError(r, reference(), s), 0.07);
  EXPECT_TRUE(stable(r));
  EXPECT_TRUE(passive(r));
  EXPECT_LE(r.update_step_ratio, 1.0) << r.update_step_max_n << " N";
}

TEST(TeleopGoals, DirectIsUnstableOrFarOffAt300Ms) {
  const CellSpec s = cell(link(300, 20, 2, 4), RenderMode::kDirect);
  const CellResult r = runCell(s, &hand());
  const double err = forceError(r, reference(), s);
  EXPECT_TRUE(!stable(r) || err > 0.30) << "oscillation " << r.oscillation << ", error " << err;
}

TEST(TeleopGoals, DirectWithoutDelayTracksTheModel) {
  // The baseline is a fair one: with no delay and no loss it renders what the model does.
  const CellSpec s = cell(link(0, 0, 0, 1), RenderMode::kDirect);
  const CellResult r = runCell(s, &hand());
  EXPECT_TRUE(stable(r));
  EXPECT_LT(forceError(r, reference(), s), 0.07);
}

TEST(TeleopGoals, DeadbandSendsAtLeastNinetyPercentFewerDeviceStates) {
  CellSpec full = cell(link(300, 20, 2, 4), RenderMode::kModel);
  CellSpec coded = full;
  coded.deadband.weber = 0.05;
  const CellResult a = runCell(full, &hand());
  const CellResult b = runCell(coded, &hand());
  EXPECT_LE(b.device_state_pps, 0.10 * a.device_state_pps)
      << b.device_state_pps << " of " << a.device_state_pps << " per second";
  EXPECT_LT(b.reconstruction_error, 0.07);
  EXPECT_LT(forceError(b, a, coded), 0.07);
  EXPECT_LT(b.hand_state_pps, a.hand_state_pps);
  EXPECT_EQ(b.samples_recorded, b.ticks) << "the record still holds every sample";
}

TEST(TeleopGoals, ModelMediatedForceErrorUnderTheJndWithAServoClinician) {
  // The clinician moves the joint along a set path: the force is whatever the proxy renders
  // there, so a stale or wrong model would show in full.
  CellSpec ref_spec = cell(link(0, 0, 0, 1), RenderMode::kModel);
  ref_spec.clinician = Clinician::kServo;
  CellSpec s = cell(link(300, 20, 2, 4), RenderMode::kModel);
  s.clinician = Clinician::kServo;
  const CellResult ref = runCell(ref_spec, &hand());
  const CellResult r = runCell(s, &hand());
  EXPECT_GT(r.models_applied, 5u);
  EXPECT_LT(forceError(r, ref, s), 0.07);
  EXPECT_TRUE(stable(r));
  EXPECT_TRUE(passive(r));
}

TEST(TeleopGoals, TheServerKeepsTheProxyWhereItsHandIs) {
  // On the healthy joint the mobilization stays inside the range, so the drift measured here
  // (hand minus proxy, unclamped) is the drift the server corrects. On the regain case the
  // grip presses on the end-of-range wall, whose give the server rightly leaves alone but this
  // measure counts: there the persistent drift sits at the threshold (0.56° uncorrected at
  // 0 ms), and whether a correction fires turns on details of the first second.
  CellSpec on_spec = cell(link(0, 0, 0, 1), RenderMode::kModel);
  on_spec.case_name = "healthy";
  CellSpec off = on_spec;
  off.drift_correction = false;
  const CellResult on = runCell(on_spec, &hand());
  const CellResult r_off = runCell(off, &hand());
  EXPECT_EQ(r_off.drift_corrections, 0u);
  // The hand holds the grip to 0.2 deg here uncorrected (the MCP's centre no longer gives
  // under the pads' load): then there is nothing to correct. Slips that do need correcting:
  // DriftTest in test_session_manager.cpp.
  if (r_off.drift_mean_deg >= 0.5) {
    EXPECT_GE(on.drift_corrections, 1u);
    EXPECT_LT(on.drift_mean_deg, r_off.drift_mean_deg);
  } else {
    EXPECT_EQ(on.drift_corrections, 0u) << "no correction for drift under the threshold";
  }
  EXPECT_LT(on.drift_mean_deg, 0.5) << "persistent drift within the correction threshold";
  EXPECT_LE(on.update_step_ratio, 1.0) << "corrections fade in under the step bound";
  EXPECT_EQ(on.fade_unpaid_j, 0.0) << "and are paid for by dissipated energy";
}

/// The massage of the web (the clinician circling with 10 ± 2 N) through the model-mediated
/// loop over a shipped link profile: the loop renders to the end without a fault, the
/// passivity observer stays above its bound, the clinician's press stays in the band, every
/// sample reaches the record, and the server's web, stepped across the samples lost or late
/// on the way, holds the force the client rendered (it takes the skin's stretch back from the
/// client's recorded force, docs/massage.md "The server").
class TeleopMassageGoals : public ::testing::TestWithParam<const char*> {};

TEST_P(TeleopMassageGoals, StableAndPassiveOverTheProfile) {
  const LinkProfile l =
      loadLinkProfile(std::string(TELEHAND_DEPLOY_DIR) + "/links/" + GetParam() + ".toml");
  CellSpec s = cell(l, RenderMode::kModel);
  s.technique = Technique::kMassage;
  s.case_name = "healthy";
  const CellResult r = runCell(s, &hand());
  EXPECT_TRUE(massageStable(r)) << "fault "
                                << client::loop::faultName(
                                       static_cast<client::loop::LoopFault>(r.fault));
  EXPECT_TRUE(passive(r)) << "lowest observer energy " << r.po_min_j << " J";
  EXPECT_GT(r.massage_in_band, 0.8) << "both pads within 10 ± 2 N";
  EXPECT_GT(r.web_compared, 500u) << "the server published its web";
  EXPECT_LE(r.web_error_max, 1e-6) << "RMS " << r.web_error_rms;
  EXPECT_EQ(r.samples_recorded, r.ticks) << "the record travels reliably";
}

INSTANTIATE_TEST_SUITE_P(Profiles, TeleopMassageGoals,
                         ::testing::Values("loopback", "lan", "spain-australia", "extreme"),
                         [](const ::testing::TestParamInfo<const char*>& p) {
                           std::string n = p.param;
                           std::erase(n, '-');
                           return n;
                         });

TEST(TeleopGoals, MassageServerWebMatchesTheProxyWithoutDelay) {
  // At zero delay and loss the server steps its web on every sample the client rendered: the
  // same forces (the loss-free half of MassageProxyServer in the unit tests, here through the
  // wire, the session and HandState).
  CellSpec s = cell(link(0, 0, 0, 1), RenderMode::kModel);
  s.technique = Technique::kMassage;
  s.case_name = "healthy";
  const CellResult r = runCell(s, &hand());
  EXPECT_GT(r.web_compared, 500u);
  EXPECT_LE(r.web_error_max, 0.02) << "RMS " << r.web_error_rms;
}

}  // namespace
}  // namespace telehand::teleop
