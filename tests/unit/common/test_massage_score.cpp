// Massage technique scoring: figures on synthetic circles with known answers, and scores of
// simulated students (the massage MF-2's operator with a skill) in a closed loop with the
// tissue proxy, against a simulated clinician's demonstration.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "../client/massage_trial.h"
#include "telehand/core/massage_score.h"
#include "telehand/core/tissue_model.h"

namespace telehand {
namespace {

using technique::MassageFigures;
using technique::MassageScore;
using technique::MassageSeries;
using technique::MassageTargets;

/// A web somewhere else than the device's origin, turned, so that the frames are exercised.
TissueParams tiltedWeb() {
  TissueParams w = tissueCase("healthy");
  w.origin_m = Vec3(0.01, -0.005, 0.002);
  w.orientation = Quat(Eigen::AngleAxisd(0.3, Vec3(1.0, 0.5, 0.2).normalized()));
  return w;
}

/// A contact point on an ellipse (semi-axes a along x, b along y, centre (cx, cy), web frame)
/// at `hz` laps per second (negative: clockwise), the thimbles above and below it; normal
/// force 10 + 0.5 sin(2 pi 0.3 t) N on both, tangential 3 sin(angle) N.
MassageSeries syntheticSeries(const TissueParams& web, double seconds, double hz, double a,
                              double b, double cx, double cy) {
  const TissueModel m(web);
  MassageSeries s;
  const int n = static_cast<int>(std::lround(seconds * 1000.0));
  for (int i = 0; i < n; ++i) {
    const double t = i * 1e-3;
    const double ang = 2.0 * kPi * hz * t;
    const Vec3 c(cx + a * std::cos(ang), cy + b * std::sin(ang), 0.0);
    s.t_s.push_back(t);
    for (int k = 0; k < 2; ++k) {
      const double z = (k == kThumb ? 1.0 : -1.0) * 0.013;
      s.position_m[k].push_back(m.fromWeb(c + Vec3(0.0, 0.0, z)));
      s.normal_ref_n[k].push_back(10.0 + 0.5 * std::sin(2.0 * kPi * 0.3 * t));
      s.tangential_ref_n[k].push_back(3.0 * std::sin(ang));
    }
  }
  return s;
}

TEST(MassageScore, FiguresOfAKnownCircle) {
  const TissueParams web = tiltedWeb();
  const MassageFigures f =
      technique::analyseMassage(syntheticSeries(web, 20.0, 1.5, 0.006, 0.006, 0.001, -0.0005), web);
  EXPECT_NEAR(f.radius_m, 0.006, 1e-9);
  EXPECT_NEAR(f.frequency_hz, 1.5, 1e-6);
  EXPECT_NEAR(f.circularity, 1.0, 1e-4);  // whole laps to the nearest sample
  EXPECT_NEAR(f.radial_rms_m, 0.0, 1e-9);
  EXPECT_NEAR(f.centre_w.x(), 0.001, 1e-9);
  EXPECT_NEAR(f.centre_w.y(), -0.0005, 1e-9);
  EXPECT_EQ(f.laps, 28.0);  // 19 s after settle at 1.5 Hz: 28.5 laps, 28 whole
  // 19 s of a 0.3 Hz sine are not whole periods: its mean is 0.018 N off 10.
  EXPECT_NEAR(f.normal_mean_n, 10.0, 0.03);
  EXPECT_NEAR(f.normal_sd_n, 0.5 / std::sqrt(2.0), 0.01);
  EXPECT_NEAR(f.time_in_band, 1.0, 1e-12);
  EXPECT_NEAR(f.tangential_ratio, 3.0 * 2.0 / kPi / 10.0, 0.002);  // mean |sin| = 2 / pi
  EXPECT_NEAR(f.duration_s, 19.999, 1e-9);
}

TEST(MassageScore, FiguresOfAnEllipseTurnedTheOtherWay) {
  const TissueParams web = tiltedWeb();
  const MassageFigures f =
      technique::analyseMassage(syntheticSeries(web, 12.0, -2.0, 0.006, 0.003, 0.0, 0.0), web);
  EXPECT_NEAR(f.frequency_hz, -2.0, 1e-3);  // clockwise seen from the dorsal side
  EXPECT_NEAR(f.circularity, 0.5, 1e-3);    // minor / major
  EXPECT_GT(f.radial_rms_m, 0.0005);
  EXPECT_GT(f.radius_m, 0.003);
  EXPECT_LT(f.radius_m, 0.006);
}

TEST(MassageScore, LessThanALapHasNoCircle) {
  const TissueParams web = tissueCase("healthy");
  const MassageSeries s = syntheticSeries(web, 1.5, 1.5, 0.006, 0.006, 0.0, 0.0);
  const MassageFigures f = technique::analyseMassage(s, web);
  EXPECT_EQ(f.laps, 0.0);
  EXPECT_EQ(f.radius_m, 0.0);
  EXPECT_NEAR(f.normal_mean_n, 10.0, 0.5);  // the press is still measured
  const MassageTargets t =
      technique::deriveMassageTargets(syntheticSeries(web, 10.0, 1.5, 0.006, 0.006, 0.0, 0.0), web);
  EXPECT_EQ(technique::scoreMassage(s, t, web).overall, 0.0);
  EXPECT_EQ(technique::analyseMassage(MassageSeries{}, web).laps, 0.0);
}

// A press without the circle: the contact point only jitters (0.1 mm, random, as encoder
// noise and tremor would), its angle round the jitter's centre spins at random, and still no
// lap is counted.
TEST(MassageScore, JitterIsNoCircle) {
  const TissueParams web = tissueCase("healthy");
  MassageSeries s = syntheticSeries(web, 10.0, 1.5, 0.0, 0.0, 0.0, 0.0);
  std::mt19937_64 rng(3);
  std::normal_distribution<double> jitter(0.0, 0.0001);
  const TissueModel m(web);
  for (std::size_t i = 0; i < s.t_s.size(); ++i) {
    const Vec3 d(jitter(rng), jitter(rng), 0.0);
    for (int k = 0; k < 2; ++k) s.position_m[k][i] += m.params().orientation * d;
  }
  const MassageFigures f = technique::analyseMassage(s, web);
  EXPECT_EQ(f.laps, 0.0);
  EXPECT_EQ(f.frequency_hz, 0.0);
  const MassageTargets t =
      technique::deriveMassageTargets(syntheticSeries(web, 10.0, 1.5, 0.006, 0.006, 0.0, 0.0), web);
  EXPECT_EQ(technique::scoreMassage(s, t, web).overall, 0.0);
}

/// `s` without its samples [from, to): a record that lacks them.
MassageSeries without(const MassageSeries& s, std::size_t from, std::size_t to) {
  MassageSeries out;
  for (std::size_t i = 0; i < s.t_s.size(); ++i) {
    if (i >= from && i < to) continue;
    out.t_s.push_back(s.t_s[i]);
    for (int k = 0; k < 2; ++k) {
      out.position_m[k].push_back(s.position_m[k][i]);
      out.normal_ref_n[k].push_back(s.normal_ref_n[k][i]);
      out.tangential_ref_n[k].push_back(s.tangential_ref_n[k][i]);
    }
  }
  return out;
}

// A massage whose record lacks a stretch in its middle is judged on the stretches either side:
// the laps made in the gap are not counted, and the angle is not unwrapped across it (that
// would read a slower circle), so the frequency and the score are the whole trial's. One with
// too little left to judge is not scored, and says why, rather than scoring 0.
TEST(MassageScore, ATrialWithAGapIsJudgedOnItsStretches) {
  const TissueParams web = tiltedWeb();
  const MassageTargets t =
      technique::deriveMassageTargets(syntheticSeries(web, 10.0, 1.5, 0.006, 0.006, 0.0, 0.0), web);
  for (const double seconds : {4.004, 10.0}) {
    // 0.2 Hz fast, a little elliptic and small: a score well under 100.
    const MassageSeries whole = syntheticSeries(web, seconds, 1.7, 0.0055, 0.0050, 0.0, 0.0);
    const std::size_t n = whole.t_s.size();
    const MassageScore all = technique::scoreMassage(whole, t, web);
    const MassageSeries gapped = without(whole, n / 2 - 500, n / 2 + 500);  // 1 s lost
    const MassageScore part = technique::scoreMassage(gapped, t, web);
    std::printf("%.1f s: whole %s\n  1 s lost: %s\n", seconds,
                technique::massageSummaryLine(all).c_str(),
                technique::massageSummaryLine(part).c_str());
    ASSERT_TRUE(all.not_scored.empty()) << all.not_scored;
    EXPECT_EQ(all.figures.stretches, 1u);
    EXPECT_GT(all.overall, 30.0);
    EXPECT_LT(all.overall, 90.0);
    EXPECT_TRUE(part.not_scored.empty()) << part.not_scored;
    EXPECT_EQ(part.figures.stretches, 2u);
    EXPECT_NEAR(part.figures.frequency_hz, 1.7, 0.01);
    EXPECT_NEAR(part.figures.radius_m, all.figures.radius_m, 0.0001);
    EXPECT_NEAR(part.figures.circularity, all.figures.circularity, 0.02);
    EXPECT_NEAR(part.figures.circling_share, 1.0, 0.01);
    EXPECT_LT(part.figures.laps, all.figures.laps);  // the laps in the gap are not there
    EXPECT_NEAR(part.overall, all.overall, 0.05 * all.overall);

    // Most of it lost: 1.2 s at the start and 0.3 s at the end are left, less than a lap
    // after the settle in either: not scored, saying why.
    const MassageScore none = technique::scoreMassage(without(whole, 1200, n - 300), t, web);
    EXPECT_EQ(none.overall, 0.0);
    EXPECT_NE(none.not_scored.find("none of its 2 stretches between gaps is long enough"),
              std::string::npos)
        << none.not_scored;
    EXPECT_EQ(technique::massageSummaryLine(none), "massage: not scored: " + none.not_scored);
  }
}

// --- Simulated students -------------------------------------------------------------------

MassageSeries simulated(const OperatorConfig& op, const TissueParams& web = tissueCase("healthy"),
                        bool capture = false, double seconds = 20.0) {
  test::MassageTrialOptions o;
  o.web = web;
  o.op = op;
  o.capture = capture;
  o.seconds = seconds;
  const test::MassageTrial trial = test::runMassageTrial(o);
  EXPECT_TRUE(trial.complete);
  return technique::massageSeriesFromSamples(trial.samples, capture ? 1.0 : o.force_scale);
}

OperatorConfig seeded(uint64_t seed) {
  OperatorConfig op;
  op.seed = seed;
  return op;
}

TEST(MassageScore, IdenticalAttemptScoresPerfect) {
  const TissueParams web = tissueCase("healthy");
  const MassageSeries demo = simulated(seeded(1));
  const MassageTargets t = technique::deriveMassageTargets(demo, web);
  std::printf(
      "demonstration: press %.2f N sd %.2f N, %.4f Hz, radius %.3f mm, circularity "
      "%.4f, tangential %.3f, %.0f laps\n",
      t.normal_mean_n, t.normal_sd_n, t.frequency_hz, t.radius_m * 1e3, t.circularity,
      t.tangential_ratio, t.laps);
  EXPECT_NEAR(t.normal_mean_n, 10.0, 0.1);
  EXPECT_NEAR(t.frequency_hz, 1.5, 0.005);
  EXPECT_NEAR(t.radius_m, 0.006, 0.0002);
  EXPECT_GT(t.circularity, 0.98);
  const MassageScore s = technique::scoreMassage(demo, t, web);
  EXPECT_DOUBLE_EQ(s.overall, 100.0);
  EXPECT_EQ(s.normal_error_n, 0.0);
  EXPECT_EQ(s.frequency_error_hz, 0.0);
  EXPECT_EQ(s.radius_ratio, 1.0);
  std::printf("%s\n", technique::massageSummaryLine(s).c_str());
}

// One good lap and the rest of the trial held still, or the demonstration's circles traced off
// the web, are not the technique: the score is scaled by the share of the trial spent circling
// and pressing the web, and the summary says why.
TEST(MassageScore, OneLapThenStillOrCirclesOffTheWebScoreLow) {
  const TissueParams web = tissueCase("healthy");
  const MassageTargets t =
      technique::deriveMassageTargets(syntheticSeries(web, 10.0, 1.5, 0.006, 0.006, 0.0, 0.0), web);
  const MassageSeries full = syntheticSeries(web, 10.0, 1.5, 0.006, 0.006, 0.0, 0.0);
  const MassageScore whole = technique::scoreMassage(full, t, web);
  EXPECT_NEAR(whole.figures.circling_share, 1.0, 1e-9);
  EXPECT_NEAR(whole.figures.contact_share, 1.0, 1e-9);
  EXPECT_GT(whole.overall, 95.0);

  // One lap and a half after the settling, then held where it was for the rest of 10 s.
  MassageSeries still = full;
  const std::size_t stop = 2700;
  for (std::size_t i = stop; i < still.t_s.size(); ++i) {
    for (int k = 0; k < 2; ++k) still.position_m[k][i] = still.position_m[k][stop];
  }
  const MassageScore held = technique::scoreMassage(still, t, web);
  EXPECT_LE(held.figures.laps, 2.0);
  EXPECT_LT(held.figures.circling_share, 0.3);
  EXPECT_LT(held.overall, 30.0) << technique::massageSummaryLine(held);
  EXPECT_NE(technique::massageSummaryLine(held).find("circling"), std::string::npos);

  // The same circles with no press: off the web.
  MassageSeries air = full;
  for (int k = 0; k < 2; ++k) {
    std::fill(air.normal_ref_n[k].begin(), air.normal_ref_n[k].end(), 0.0);
    std::fill(air.tangential_ref_n[k].begin(), air.tangential_ref_n[k].end(), 0.0);
  }
  const MassageScore off = technique::scoreMassage(air, t, web);
  EXPECT_EQ(off.figures.contact_share, 0.0);
  EXPECT_EQ(off.overall, 0.0) << technique::massageSummaryLine(off);
  std::printf("held still: %s\noff the web: %s\n", technique::massageSummaryLine(held).c_str(),
              technique::massageSummaryLine(off).c_str());
}

// Each error the student is configured with reads back as itself against the clinician's
// demonstration (another seed: another wander, other noise).
TEST(MassageScore, KnownErrorsAreRecovered) {
  const TissueParams web = tissueCase("healthy");
  const MassageTargets t = technique::deriveMassageTargets(simulated(seeded(1)), web);
  const MassageScore clean = technique::scoreMassage(simulated(seeded(2)), t, web);

  OperatorConfig bias = seeded(2);
  bias.force_bias_n = 2.0;
  const MassageScore b = technique::scoreMassage(simulated(bias), t, web);
  OperatorConfig freq = seeded(2);
  freq.frequency_error_hz = 0.5;
  const MassageScore f = technique::scoreMassage(simulated(freq), t, web);
  OperatorConfig small = seeded(2);
  small.amplitude_scale = 0.7;
  const MassageScore r = technique::scoreMassage(simulated(small), t, web);
  std::printf("clean  %s\nbias   %s\nfreq   %s\nradius %s\n",
              technique::massageSummaryLine(clean).c_str(),
              technique::massageSummaryLine(b).c_str(), technique::massageSummaryLine(f).c_str(),
              technique::massageSummaryLine(r).c_str());

  std::printf("recovered: bias %+.3f N, frequency %+.4f Hz, radius x%.4f\n", b.normal_error_n,
              f.frequency_error_hz, r.radius_ratio);
  EXPECT_NEAR(clean.normal_error_n, 0.0, 0.2);
  EXPECT_NEAR(clean.frequency_error_hz, 0.0, 0.05);
  EXPECT_NEAR(clean.radius_ratio, 1.0, 0.05);
  EXPECT_GT(clean.overall, 90.0);

  EXPECT_NEAR(b.normal_error_n, 2.0, 0.2);
  EXPECT_NEAR(f.frequency_error_hz, 0.5, 0.05);
  EXPECT_NEAR(r.radius_ratio, 0.7, 0.05 * 0.7);
  // Only the configured error moves.
  EXPECT_NEAR(b.frequency_error_hz, 0.0, 0.05);
  EXPECT_NEAR(f.normal_error_n, 0.0, 0.2);
  EXPECT_NEAR(r.normal_error_n, 0.0, 0.2);
  for (const MassageScore* s : {&b, &f, &r}) EXPECT_LT(s->overall, clean.overall - 10.0);
}

// A better student (smaller bias, frequency error, tremor, a truer circle) scores above a
// worse one with every one of 10 seeds.
TEST(MassageScore, BetterStudentScoresAboveWorse) {
  const TissueParams web = tissueCase("healthy");
  const MassageTargets t = technique::deriveMassageTargets(simulated(seeded(1)), web);
  double better_sum = 0, worse_sum = 0;
  for (uint64_t seed = 11; seed <= 20; ++seed) {
    OperatorConfig better = seeded(seed), worse = seeded(seed);
    better.force_bias_n = 0.5;
    better.frequency_error_hz = 0.1;
    better.tremor_n = 0.3;
    better.amplitude_scale = 0.95;
    worse.force_bias_n = 1.5;
    worse.frequency_error_hz = 0.3;
    worse.tremor_n = 1.5;
    worse.amplitude_scale = 0.8;
    const MassageScore sb = technique::scoreMassage(simulated(better, web, false, 12.0), t, web);
    const MassageScore sw = technique::scoreMassage(simulated(worse, web, false, 12.0), t, web);
    EXPECT_GT(sb.overall, sw.overall) << "seed " << seed;
    better_sum += sb.overall;
    worse_sum += sw.overall;
    if (seed == 11) {
      std::printf("better %s\nworse  %s\n", technique::massageSummaryLine(sb).c_str(),
                  technique::massageSummaryLine(sw).c_str());
    }
  }
  std::printf("mean over 10 seeds: better %.1f, worse %.1f\n", better_sum / 10, worse_sum / 10);
}

// A demonstration captured on the real web (reference scale, the paper's 1.43 N thimble
// error) sets targets that the clinician's rendered massage meets.
TEST(MassageScore, CapturedDemonstrationScoresTheRenderedClinician) {
  const TissueParams web = tissueCase("hypertonic");
  test::MassageTrialOptions o;
  o.web = web;
  o.op = seeded(4);
  o.capture = true;
  o.force_noise_n = 1.43;
  const test::MassageTrial capture = test::runMassageTrial(o);
  ASSERT_TRUE(capture.complete);
  const MassageTargets t = technique::deriveMassageTargets(
      technique::massageSeriesFromSamples(capture.samples, 1.0), web);
  const MassageScore s = technique::scoreMassage(simulated(seeded(5), web), t, web);
  std::printf("captured sd %.2f N; rendered %s\n", t.normal_sd_n,
              technique::massageSummaryLine(s).c_str());
  EXPECT_NEAR(t.normal_mean_n, 10.0, 0.1);
  EXPECT_NEAR(t.normal_sd_n, std::hypot(0.7, 1.43), 0.15);  // the wander and the thimble error
  EXPECT_NEAR(s.normal_error_n, 0.0, 0.2);
  EXPECT_NEAR(s.radius_ratio, 1.0, 0.05);
  EXPECT_GT(s.overall, 85.0);
}

}  // namespace
}  // namespace telehand
