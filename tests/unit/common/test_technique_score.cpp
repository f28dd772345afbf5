// Technique scoring against synthetic ground truth: a demonstration whose force band,
// frequency and flexion path are known, and attempts made from it with known errors.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "../client/alloc_guard.h"  // replaces operator new: this executable only
#include "telehand/core/joint_model.h"
#include "telehand/core/technique_score.h"
#include "telehand/core/thimble.h"

namespace telehand::technique {
namespace {

/// A mobilization as a clean formula: the force builds up over `ramp_s` (smoothstep) to
/// mid + bias and oscillates +-amp at `freq_hz`; the flexion follows the force through a
/// joint compliance with a lag; abduction and axial move a little with it.
struct Synth {
  double freq_hz = 3.0;
  double mid_n = 14.0, amp_n = 2.0, bias_n = 0.0;
  double ramp_s = 1.0;
  double seconds = 10.0;
  double noise_n = 0.0;  ///< white force noise, 1 sigma (a trial's sensors)
  double deg_per_n = 1.5, lag_s = 0.02, flexion0_deg = 10.0;
  double dt = 1e-3;
  uint64_t seed = 1;
};

double cleanForce(const Synth& p, double t) {
  return smoothRamp(t, p.ramp_s) *
         (p.mid_n + p.bias_n + p.amp_n * std::sin(2.0 * kPi * p.freq_hz * t));
}

Series make(const Synth& p) {
  Series s;
  std::mt19937_64 rng(p.seed);
  std::normal_distribution<double> noise(0.0, 1.0);
  const int n = static_cast<int>(std::lround(p.seconds / p.dt));
  for (int i = 0; i < n; ++i) {
    const double t = i * p.dt;
    s.t_s.push_back(100.0 + t);  // series need not start at 0
    s.force_ref_n.push_back(cleanForce(p, t) + p.noise_n * noise(rng));
    const double flex = p.flexion0_deg + p.deg_per_n * cleanForce(p, t - p.lag_s);
    s.angles_rad.emplace_back(degToRad(flex), degToRad(0.1 * flex), degToRad(-2.0));
  }
  return s;
}

TEST(TechniqueScore, IdenticalAttemptScoresPerfect) {
  for (double f : {1.5, 3.0, 4.5}) {
    Synth p;
    p.freq_hz = f;
    const Series demo = make(p);
    const Targets t = deriveTargets(demo);
    ASSERT_GT(t.oscillations, 10);
    EXPECT_NEAR(t.band_min_n, 12.0, 0.1);
    EXPECT_NEAR(t.band_max_n, 16.0, 0.1);
    EXPECT_NEAR(t.frequency_hz, f, 0.01);
    ASSERT_EQ(t.path_rad.size(), static_cast<std::size_t>(kPathPoints));
    const TrialScore s = score(demo, t);
    EXPECT_EQ(s.peak_error_n, 0.0);
    EXPECT_EQ(s.mean_error_n, 0.0);
    EXPECT_EQ(s.frequency_error_hz, 0.0);
    EXPECT_EQ(s.amplitude_error_deg, 0.0);
    EXPECT_EQ(s.jerk_delta, 0.0);
    EXPECT_NEAR(s.path_error_deg, 0.0, 0.05);
    EXPECT_DOUBLE_EQ(s.overall, 100.0);
    EXPECT_NE(summaryLine(s).find("score 100"), std::string::npos) << summaryLine(s);
  }
}

struct Case {
  double demo_hz, bias_n, freq_error_hz, noise_n;
};

TEST(TechniqueScore, RecoversKnownForceBiasAndFrequencyError) {
  const Case cases[] = {
      {3.0, +2.0, +0.5, 0.0},  {3.0, -1.3, -0.7, 0.0},  {1.5, +2.0, +0.5, 0.0},
      {4.5, -1.3, -0.7, 0.0},  {1.5, -1.3, +0.3, 0.0},  {4.5, +0.7, +1.1, 0.0},
      {3.0, +2.0, +0.5, 1.43}, {1.5, -1.3, -0.7, 1.43}, {4.5, +2.0, +0.5, 1.43},
  };
  for (const Case& c : cases) {
    Synth demo_p;
    demo_p.freq_hz = c.demo_hz;
    const Targets t = deriveTargets(make(demo_p));
    // Noisy attempts on three noise sequences each.
    for (uint64_t seed :
         c.noise_n > 0.0 ? std::vector<uint64_t>{7, 8, 9} : std::vector<uint64_t>{7}) {
      Synth att_p = demo_p;
      att_p.bias_n = c.bias_n;
      att_p.freq_hz = c.demo_hz + c.freq_error_hz;
      att_p.noise_n = c.noise_n;
      att_p.seed = seed;
      const TrialScore s = score(make(att_p), t);
      std::printf(
          "demo %.1f Hz, bias %+.1f N, freq %+.1f Hz, noise %.2f N: peak %+.3f trough %+.3f "
          "mean %+.3f N, freq %+.4f Hz (zc %.4f), %zu oscillations, score %.1f\n",
          c.demo_hz, c.bias_n, c.freq_error_hz, c.noise_n, s.peak_error_n, s.trough_error_n,
          s.mean_error_n, s.frequency_error_hz, s.figures.frequency_zc_hz,
          s.figures.oscillations.size(), s.overall);
      // With 1.43 N of white noise the extremes of a slow oscillation (a long flat top the
      // noise rides on) are found less exactly than the mean.
      const double extreme_tol = c.noise_n > 0.0 ? 0.3 : 0.2;
      EXPECT_NEAR(s.peak_error_n, c.bias_n, extreme_tol);
      EXPECT_NEAR(s.trough_error_n, c.bias_n, extreme_tol);
      EXPECT_NEAR(s.mean_error_n, c.bias_n, c.noise_n > 0.0 ? 0.1 : 0.2);
      EXPECT_NEAR(s.frequency_error_hz, c.freq_error_hz, 0.05);
      EXPECT_NEAR(s.figures.frequency_zc_hz, att_p.freq_hz, 0.05);
      // Every oscillation that starts after the settle and ends in the trial is found, none
      // invented.
      const double expected = (10.0 - 1.0) * att_p.freq_hz - 1.0;
      EXPECT_NEAR(static_cast<double>(s.figures.oscillations.size()), expected, 1.5);
      EXPECT_LT(s.overall, 90.0);  // a 0.3 Hz or 0.7 N error is not a good trial
    }
  }
}

TEST(TechniqueScore, LargerErrorsScoreLower) {
  Synth demo_p;
  const Targets t = deriveTargets(make(demo_p));
  double last = 100.0;
  for (double k : {0.1, 0.3, 0.6, 1.0, 2.0}) {
    Synth a = demo_p;
    a.bias_n = k;
    a.freq_hz = demo_p.freq_hz + 0.2 * k;
    a.amp_n = demo_p.amp_n * (1.0 + 0.2 * k);
    const double s = score(make(a), t).overall;
    EXPECT_LT(s, last) << k;
    last = s;
  }
}

TEST(TechniqueScore, StreamingTrackerAgreesWithBatch) {
  for (double f : {1.5, 3.0, 4.5}) {
    Synth p;
    p.freq_hz = f;
    p.noise_n = 1.43;
    const Series s = make(p);
    const TrialFigures fig = analyse(s, 12.0, 16.0);
    OscillationTracker tracker;
    std::vector<Oscillation> live;
    Oscillation o;
    for (std::size_t i = 0; i < s.t_s.size(); ++i) {
      if (tracker.add(s.t_s[i] - s.t_s[0], s.force_ref_n[i], s.angles_rad[i], o) &&
          o.t_start_s >= 1.0) {
        live.push_back(o);
      }
    }
    ASSERT_EQ(live.size(), fig.oscillations.size());
    double mean_f = 0.0, peak = 0.0, trough = 0.0, mean = 0.0, amp = 0.0;
    for (std::size_t k = 0; k < live.size(); ++k) {
      EXPECT_EQ(live[k].t_start_s, fig.oscillations[k].t_start_s);
      EXPECT_EQ(live[k].peak_n, fig.oscillations[k].peak_n);
      mean_f += live[k].frequency_hz;
      peak += live[k].peak_n;
      trough += live[k].trough_n;
      mean += live[k].mean_n;
      amp += live[k].amplitude_deg;
    }
    const double n = static_cast<double>(live.size());
    std::printf(
        "%.1f Hz, noise 1.43 N: tracker %.4f Hz, spectrum %.4f, zc %.4f; peak %.3f trough "
        "%.3f mean %.3f N, amplitude %.3f deg, in band %.2f\n",
        f, mean_f / n, fig.frequency_spectrum_hz, fig.frequency_zc_hz, peak / n, trough / n,
        mean / n, amp / n, fig.time_in_band);
    // The oscillation-by-oscillation figures agree with the whole-trial ones and the truth.
    EXPECT_NEAR(mean_f / n, fig.frequency_spectrum_hz, 0.03);
    EXPECT_NEAR(mean_f / n, fig.frequency_zc_hz, 0.03);
    EXPECT_NEAR(fig.frequency_spectrum_hz, f, 0.02);
    EXPECT_NEAR(mean / n, fig.force_mean_n, 0.1);
    // The first oscillations are still in the build-up; the others peak at 16 N.
    EXPECT_NEAR(peak / n, 16.0, 0.4);
    EXPECT_NEAR(trough / n, 12.0, 0.4);
    EXPECT_NEAR(amp / n, 1.5 * 4.0, 0.4);
  }
}

TEST(TechniqueScore, TrackerStartsAfterAResetAsNew) {
  Synth p;
  const Series s = make(p);
  OscillationTracker a, b;
  Oscillation oa, ob;
  for (std::size_t i = 0; i < 3000; ++i) a.add(s.t_s[i], s.force_ref_n[i], s.angles_rad[i], oa);
  a.reset();
  for (std::size_t i = 0; i < s.t_s.size(); ++i) {
    const bool da = a.add(s.t_s[i], s.force_ref_n[i], s.angles_rad[i], oa);
    const bool db = b.add(s.t_s[i], s.force_ref_n[i], s.angles_rad[i], ob);
    ASSERT_EQ(da, db);
    if (da) {
      ASSERT_EQ(oa.t_end_s, ob.t_end_s);
    }
  }
}

TEST(TechniqueScore, TrackerAllocatesNothing) {
  Synth p;
  p.noise_n = 1.43;
  p.seconds = 20.0;
  const Series s = make(p);
  OscillationTracker tracker;
  Oscillation o;
  int completed = 0;
  {
    test::AllocationGuard guard;
    for (std::size_t i = 0; i < s.t_s.size(); ++i) {
      if (tracker.add(s.t_s[i], s.force_ref_n[i], s.angles_rad[i], o)) ++completed;
    }
    tracker.reset();
    EXPECT_EQ(guard.allocations(), 0u);
    EXPECT_EQ(guard.deallocations(), 0u);
  }
  EXPECT_GT(completed, 50);
}

TEST(TechniqueScore, JerkOfASinusoidIsItsDimensionlessConstant) {
  // ln((2 pi)^6 / 8) for any frequency and amplitude; a tremor makes it larger.
  const double expected = std::log(std::pow(2.0 * kPi, 6) / 8.0);
  for (double f : {1.5, 3.0, 4.5}) {
    Synth p;
    p.freq_hz = f;
    p.lag_s = 0.0;
    const TrialFigures fig = analyse(make(p), 12.0, 16.0);
    EXPECT_NEAR(fig.jerk, expected, 0.1) << f;
  }
  Synth p;
  Series s = make(p);
  for (std::size_t i = 0; i < s.t_s.size(); ++i) {
    s.angles_rad[i][kFlexion] += degToRad(0.3) * std::sin(2.0 * kPi * 10.0 * s.t_s[i]);
  }
  EXPECT_GT(analyse(s, 12.0, 16.0).jerk, expected + 1.0);
}

TEST(TechniqueScore, PathErrorGrowsWithAnOffsetAndForgivesATimeWarp) {
  Synth p;
  const Series demo = make(p);
  const Targets t = deriveTargets(demo);
  // Same force, the joint further flexed: the warp absorbs part of an offset (it may pair
  // points up to 1/8 period apart), never more than all of it.
  double last = 0.0;
  for (double offset : {0.5, 1.0, 3.0, 6.0}) {
    Synth a = p;
    a.flexion0_deg += offset;
    const TrialScore s = score(make(a), t);
    std::printf("flexion offset %.1f deg: path error %.3f deg\n", offset, s.path_error_deg);
    EXPECT_GT(s.path_error_deg, last);
    EXPECT_LE(s.path_error_deg, offset * std::sqrt(1.01) + 1e-6);  // abduction moves 0.1x
    EXPECT_GT(s.path_error_deg, 0.3 * offset);
    EXPECT_NEAR(s.peak_error_n, 0.0, 1e-9);
    last = s.path_error_deg;
  }
  // The angles lag the force by 20 ms more (a softer joint): at 3 Hz that is 1.1 deg
  // between the paths at equal phase, but the same path, so DTW finds almost nothing.
  Synth a = p;
  a.lag_s += 0.02;
  const TrialScore s = score(make(a), t);
  std::printf("angles lagging 20 ms more: path error %.3f deg\n", s.path_error_deg);
  EXPECT_LT(s.path_error_deg, 0.25);
}

TEST(TechniqueScore, NoOscillationScoresZero) {
  Series s;
  for (int i = 0; i < 5000; ++i) {
    s.t_s.push_back(i * 1e-3);
    s.force_ref_n.push_back(14.0);
    s.angles_rad.emplace_back(0.2, 0.0, 0.0);
  }
  Synth p;
  const TrialScore r = score(s, deriveTargets(make(p)));
  EXPECT_TRUE(r.figures.oscillations.empty());
  EXPECT_EQ(r.overall, 0.0);
  EXPECT_TRUE(deriveTargets(s).path_rad.empty());
}

/// `s` without its samples [from, to): a record that lacks them.
Series without(const Series& s, std::size_t from, std::size_t to) {
  Series out;
  for (std::size_t i = 0; i < s.t_s.size(); ++i) {
    if (i >= from && i < to) continue;
    out.t_s.push_back(s.t_s[i]);
    out.force_ref_n.push_back(s.force_ref_n[i]);
    out.angles_rad.push_back(s.angles_rad[i]);
  }
  return out;
}

// A loop that stalls records fewer samples than the time that passed: each tick reads the
// device once, however many of its steps went by, so the record's times jump a few
// milliseconds where the loop was late. The frequency is read at the samples' times; read as
// if they came a millisecond apart, the oscillation runs faster than it did (a take-over's
// guide read a leader's 2.0 Hz as 2.32-2.40 Hz on a loaded machine).
TEST(TechniqueScore, TheFrequencyIsReadAtTheSamplesTimesWhereTicksWereSkipped) {
  Synth p;
  p.freq_hz = 2.0;
  p.noise_n = 1.43;
  p.seconds = 12.0;
  const Series full = make(p);
  Series late, as_if_regular;
  for (std::size_t i = 0; i < full.t_s.size(); ++i) {
    if (i % 10 == 3 || i % 10 == 4) continue;  // two ticks in ten skipped: 3 ms between samples
    late.t_s.push_back(full.t_s[i]);
    late.force_ref_n.push_back(full.force_ref_n[i]);
    late.angles_rad.push_back(full.angles_rad[i]);
  }
  as_if_regular = late;
  for (std::size_t i = 0; i < late.t_s.size(); ++i)
    as_if_regular.t_s[i] = 100.0 + 1e-3 * static_cast<double>(i);
  const TrialFigures read = analyse(late, 12.0, 16.0);
  const TrialFigures regular = analyse(as_if_regular, 12.0, 16.0);
  std::printf(
      "2.0 Hz with 20 %% of ticks skipped: %.3f Hz at the samples' times, %.3f Hz read "
      "a millisecond apart; the guide's %.3f Hz\n",
      read.frequency_spectrum_hz, regular.frequency_spectrum_hz, deriveTargets(late).frequency_hz);
  EXPECT_EQ(read.stretches, 1u);
  EXPECT_NEAR(read.frequency_spectrum_hz, 2.0, 0.03);
  EXPECT_NEAR(deriveTargets(late).frequency_hz, 2.0, 0.03);
  EXPECT_GT(regular.frequency_spectrum_hz, 2.4) << "the samples counted as time";
  // Times that cannot be read as time (a sender's clock stepped back, or on by 0.2 s every
  // tenth sample: no gap, but most of the time unread) are read by samples, as before:
  // finite figures, and no grid many times the record's length to transform.
  Series back = late, far_back = late, sparse = late;
  for (std::size_t i = back.t_s.size() / 2; i < back.t_s.size(); ++i) {
    back.t_s[i] -= 3.0;
    far_back.t_s[i] -= 30.0;  // before the record's first sample
  }
  for (std::size_t i = 0; i < sparse.t_s.size(); ++i)
    sparse.t_s[i] += 0.2 * static_cast<double>(i / 10);
  EXPECT_NEAR(analyse(back, 12.0, 16.0).frequency_spectrum_hz, regular.frequency_spectrum_hz, 0.05);
  EXPECT_TRUE(std::isfinite(analyse(far_back, 12.0, 16.0).frequency_spectrum_hz));
  EXPECT_TRUE(std::isfinite(analyse(sparse, 12.0, 16.0).frequency_spectrum_hz));
  // A record without skipped ticks reads as before, sample for sample.
  const TrialFigures whole = analyse(full, 12.0, 16.0);
  EXPECT_NEAR(whole.frequency_spectrum_hz, 2.0, 0.02);
}

TEST(TechniqueScore, StretchesSplitWhereTheSamplesJumpMoreThanAFewPeriods) {
  std::vector<double> t;
  for (int i = 0; i < 1000; ++i) t.push_back(5.0 + i * 1e-3 + 0.4e-3 * std::sin(0.9 * i));
  EXPECT_EQ(stretchesOf(t).size(), 1u) << "jitter is no gap";
  std::vector<double> late = t;
  for (std::size_t i = 500; i < late.size(); ++i) late[i] += 3e-3;  // 4 samples' time
  EXPECT_EQ(stretchesOf(late).size(), 1u) << "a late sample or a few lost are no gap";
  std::vector<double> stall = t;
  for (std::size_t i = 500; i < stall.size(); ++i) stall[i] += 0.2;
  EXPECT_EQ(stretchesOf(stall).size(), 1u) << "a loop's 200 ms stall is no gap";
  std::vector<double> gap = t;
  for (std::size_t i = 500; i < gap.size(); ++i) gap[i] += 1.0;
  for (std::size_t i = 800; i < gap.size(); ++i) gap[i] += 0.3;
  const std::vector<Stretch> parts = stretchesOf(gap);
  ASSERT_EQ(parts.size(), 3u);
  EXPECT_EQ(parts[0].begin, 0u);
  EXPECT_EQ(parts[0].end, 500u);
  EXPECT_EQ(parts[1].begin, 500u);
  EXPECT_EQ(parts[1].end, 800u);
  EXPECT_EQ(parts[2].end, 1000u);
  EXPECT_TRUE(stretchesOf(std::vector<double>{}).empty());
}

// A trial whose record lacks a stretch in its middle (samples lost on the way, a damaged
// record) is judged on the stretches either side: the detector starts afresh after the gap and
// nothing is taken across it, so it scores about what the whole trial does, not 0. One with
// too little left to judge is not scored, and says why, rather than scoring 0.
TEST(TechniqueScore, ATrialWithAGapIsJudgedOnItsStretches) {
  constexpr double kSettle = 2.0;  // a lesson's (server/lesson/lesson.h kSettleS)
  Synth demo_p;
  demo_p.ramp_s = 1.5;
  const Targets t = deriveTargets(make(demo_p), kSettle);
  Synth att_p = demo_p;
  att_p.bias_n = 1.0;
  att_p.freq_hz = 3.3;
  att_p.noise_n = 0.5;
  for (const double seconds : {4.004, 10.0}) {
    att_p.seconds = seconds;
    const Series whole = make(att_p);
    const std::size_t n = whole.t_s.size();
    const TrialScore all = score(whole, t, kSettle);
    // 1000 samples (1 s) from the middle.
    const Series gapped = without(whole, n / 2 - 500, n / 2 + 500);
    const TrialScore part = score(gapped, t, kSettle);
    std::printf("%.1f s: whole %s\n  1 s lost: %s\n", seconds, summaryLine(all).c_str(),
                summaryLine(part).c_str());
    ASSERT_TRUE(all.not_scored.empty()) << all.not_scored;
    EXPECT_EQ(all.figures.stretches, 1u);
    EXPECT_GT(all.overall, 30.0);
    EXPECT_TRUE(part.not_scored.empty()) << part.not_scored;
    EXPECT_EQ(part.figures.stretches, 2u);
    // The judged time lacks the gap's part after the settle.
    const double gap_from = whole.t_s[n / 2 - 501] - whole.t_s[0];
    const double gap_to = whole.t_s[n / 2 + 500] - whole.t_s[0];
    EXPECT_NEAR(part.figures.judged_s,
                all.figures.judged_s - (gap_to - std::max(gap_from, kSettle)), 0.002);
    EXPECT_FALSE(part.figures.oscillations.empty());
    EXPECT_NEAR(part.overall, all.overall, 0.1 * all.overall);
    EXPECT_NEAR(part.frequency_error_hz, all.frequency_error_hz, 0.05);
    EXPECT_NEAR(part.peak_error_n, all.peak_error_n, 0.2);
    EXPECT_NEAR(part.mean_error_n, all.mean_error_n, 0.2);
    EXPECT_NEAR(part.figures.frequency_zc_hz, att_p.freq_hz, 0.05);
    EXPECT_NEAR(part.figures.jerk, all.figures.jerk, 0.3);
    // No oscillation runs over the gap.
    for (const Oscillation& o : part.figures.oscillations) {
      EXPECT_TRUE(o.t_end_s <= gap_from || o.t_start_s >= gap_to - 0.05)
          << o.t_start_s << ".." << o.t_end_s;
    }

    // Most of it lost: 1 s at the start and 0.3 s at the end are left. Nothing after the
    // settle long enough to find an oscillation in: not scored, saying why.
    const Series scraps = without(whole, 1000, n - 300);
    const TrialScore none = score(scraps, t, kSettle);
    EXPECT_EQ(none.overall, 0.0);
    EXPECT_NE(none.not_scored.find("none of its 2 stretches between gaps is long enough"),
              std::string::npos)
        << none.not_scored;
    EXPECT_NE(none.not_scored.find("the longest spans 1.0 s"), std::string::npos)
        << none.not_scored;
    EXPECT_EQ(summaryLine(none), "trial: not scored: " + none.not_scored);
  }
  // A whole trial shorter than the settle and a period: the server's rule, said the same way.
  att_p.seconds = 2.2;
  const TrialScore short_trial = score(make(att_p), t, kSettle);
  EXPECT_EQ(short_trial.overall, 0.0);
  EXPECT_EQ(short_trial.not_scored,
            "its samples span 2.2 s (2.3 s needed: 2.0 s to settle and a 0.3 s period)");
}

TEST(TechniqueScore, AppliedForceIsTheNetPushAtReferenceScale) {
  Sample s;
  // Both pads facing +z: the forces add.
  s.fingers[0].normal_n = 1.0f;
  s.fingers[1].normal_n = 3.0f;
  EXPECT_NEAR(appliedForceRefN(s, 0.25), 16.0, 1e-6);
  // The index turned over (pads facing each other): a squeeze of 3 N cancels.
  const Quat flip(Eigen::AngleAxisd(kPi, Vec3::UnitX()));
  s.fingers[1].orientation_q[0] = flip.w();
  s.fingers[1].orientation_q[1] = flip.x();
  s.fingers[1].orientation_q[2] = flip.y();
  s.fingers[1].orientation_q[3] = flip.z();
  s.fingers[0].normal_n = 3.0f;
  EXPECT_NEAR(appliedForceRefN(s, 0.25), 0.0, 1e-6);
  s.fingers[0].normal_n = 4.0f;
  EXPECT_NEAR(appliedForceRefN(s, 0.25), 4.0, 1e-6);

  Sample samples[4] = {s, s, s, s};
  samples[0].source_time_ns = 5'000'000;
  samples[1].source_time_ns = 6'000'000;
  samples[2].source_time_ns = 6'000'000;  // the same device sample again (a faster loop)
  samples[3].source_time_ns = 5'500'000;  // a time going back is placed 1 ms later
  const Series series = seriesFromSamples(std::span<const Sample>(samples), 0.25);
  ASSERT_EQ(series.t_s.size(), 3u);
  EXPECT_DOUBLE_EQ(series.t_s[1], 1e-3);
  EXPECT_DOUBLE_EQ(series.t_s[2], 2e-3);
  EXPECT_NEAR(series.force_ref_n[0], 4.0, 1e-6);
  // A 4 kHz loop on a 1 kHz device: each sample four times, the series as at 1 kHz.
  std::vector<Sample> once, four;
  for (int i = 0; i < 50; ++i) {
    Sample x = s;
    x.source_time_ns = int64_t{1'000'000} * i;
    once.push_back(x);
    for (int k = 0; k < 4; ++k) four.push_back(x);
  }
  EXPECT_EQ(seriesFromSamples(four, 0.25).t_s, seriesFromSamples(once, 0.25).t_s);
}

TEST(TechniqueScore, LinesNameTheFigures) {
  Synth p;
  const Targets t = deriveTargets(make(p));
  Synth a = p;
  a.bias_n = 1.0;
  const TrialScore s = score(make(a), t);
  const std::string line = summaryLine(s);
  EXPECT_NE(line.find("peak 17.0 N (+1.0)"), std::string::npos) << line;
  EXPECT_NE(line.find("3.00 Hz (+0.00)"), std::string::npos) << line;
  const std::string osc = oscillationLine(s.figures.oscillations.back(), t);
  EXPECT_NE(osc.find("peak 17.0 N (+1.0)"), std::string::npos) << osc;
}

}  // namespace
}  // namespace telehand::technique
