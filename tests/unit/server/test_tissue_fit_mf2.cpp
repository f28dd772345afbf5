// The web's tissue model fitted from a capture through the simulated MF-2 (its capture
// protocol: indentations, strokes, then the circles; the real web pushing on point-mass
// thimbles with the actuators off; the paper's 1.43 N on each thimble's normal and side
// force): what telehand-client --mode capture records and telehand-records fit fits, without
// the processes in between.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <string>

#include "massage_trial.h"
#include "telehand/server/estimate/tissue_fit.h"

namespace telehand::server::estimate {
namespace {

double relErr(double fit, double truth) { return (fit - truth) / truth; }

TissueParams nominalOf(const TissueParams& truth) { return tissueGeometry(truth); }

TissueFit captureAndFit(const TissueParams& web, double seconds, uint64_t seed) {
  test::MassageTrialOptions o;
  o.web = web;
  o.capture = true;
  o.protocol = true;
  o.protocol_seed = seed;
  o.op.seed = seed;
  o.seconds = seconds;
  o.force_noise_n = 1.43;
  const test::MassageTrial trial = test::runMassageTrial(o);
  EXPECT_TRUE(trial.complete);
  TissueFitter fitter(nominalOf(web));
  for (const Sample& s : trial.samples) fitter.add(s, true);
  return fitter.fit();
}

void expectWithin10(const std::string& what, const TissueParams& truth, const TissueFit& f) {
  SCOPED_TRACE(what);
  ASSERT_TRUE(f.ok) << f.why;
  const TissueParams& p = f.params;
  std::printf(
      "%-12s k %+5.1f%%  n %+5.1f%%  lambda %+5.1f%%  kt %+5.1f%%  mu_s %+5.1f%%  mu_k %+5.1f%%  "
      "b %+5.1f%%  mass %.3f kg  depths %.1f..%.1f mm  rms %.3f/%.3f N  offsets %.2f/%.2f mm\n",
      what.c_str(), 100 * relErr(p.stiffness_n_per_m_pow, truth.stiffness_n_per_m_pow),
      100 * relErr(p.exponent, truth.exponent),
      100 * relErr(p.damping_s_per_m, truth.damping_s_per_m),
      100 * relErr(p.lateral_stiffness_n_per_m, truth.lateral_stiffness_n_per_m),
      100 * relErr(p.mu_static, truth.mu_static), 100 * relErr(p.mu_kinetic, truth.mu_kinetic),
      100 * relErr(p.viscous_n_s_per_m, truth.viscous_n_s_per_m), f.thimble_mass_kg.value,
      f.depth_min_m * 1e3, f.depth_max_m * 1e3, f.normal_rms_n, f.tangential_rms_n,
      f.surface_offset_m[0].value * 1e3, f.surface_offset_m[1].value * 1e3);
  EXPECT_NEAR(relErr(p.stiffness_n_per_m_pow, truth.stiffness_n_per_m_pow), 0.0, 0.1);
  EXPECT_NEAR(relErr(p.exponent, truth.exponent), 0.0, 0.1);
  EXPECT_NEAR(relErr(p.damping_s_per_m, truth.damping_s_per_m), 0.0, 0.1);
  EXPECT_NEAR(relErr(p.lateral_stiffness_n_per_m, truth.lateral_stiffness_n_per_m), 0.0, 0.1);
  EXPECT_NEAR(relErr(p.mu_static, truth.mu_static), 0.0, 0.1);
  EXPECT_NEAR(relErr(p.mu_kinetic, truth.mu_kinetic), 0.0, 0.1);
  EXPECT_NEAR(relErr(p.viscous_n_s_per_m, truth.viscous_n_s_per_m), 0.0, 0.1);
  // The thimble's moving mass (0.05 kg in the simulated MF-2) is found with the rest.
  EXPECT_NEAR(f.thimble_mass_kg.value, 0.05, 0.01);
  EXPECT_GT(f.depth_max_m, 0.004);
}

TEST(TissueFitMf2, TheCaptureProtocolRecoversTheWeb) {
  for (const char* name : {"hypertonic", "healthy"}) {
    expectWithin10(name, tissueCase(name), captureAndFit(tissueCase(name), 40.0, 3));
  }
}

}  // namespace
}  // namespace telehand::server::estimate
