// The simulated student: the MF-2's built-in operator with a skill (force bias, frequency
// error, tremor, amplitude scale), run through the client's real loop (HapticLoop on the
// simulated MF-2, ManualClock, offline) on the healthy case, and scored against a
// demonstration by the clinician (skill 0).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "telehand/client/loop/haptic_loop.h"
#include "telehand/config/config.h"
#include "telehand/core/clock.h"
#include "telehand/core/error.h"
#include "telehand/core/technique_score.h"
#include "telehand/devices/simulated_mf2.h"

namespace telehand {
namespace {

constexpr double kTrialS = 10.0;
constexpr double kSettleS = 2.0;  // the operator's 1.5 s build-up and half a second

JointModelParams healthy() {
  return loadPatientCaseByName(TELEHAND_DEPLOY_DIR "/cases", "healthy").model;
}

/// One trial through the client's loop: the samples it records, as a scoring series.
technique::Series runTrial(const JointModelParams& patient, const OperatorConfig& op,
                           double seconds = kTrialS) {
  ManualClock clock(kNsPerS);
  devices::SimulatedMf2 dev(patient, op, clock);
  const JointModel model(patient);
  dev.setPose(Vec3(model.restAngleRad(kFlexion), model.restAngleRad(kAbduction),
                   model.restAngleRad(kAxial)));
  client::loop::HapticLoop hl(dev, clock, patient, SafetyLimits{});
  std::vector<Sample> samples;
  const int ticks = static_cast<int>(std::lround(seconds * 1000.0));
  samples.reserve(static_cast<std::size_t>(ticks));
  Sample s;
  for (int i = 0; i < ticks; ++i) {
    clock.advance(kNsPerMs);
    hl.step();
    while (hl.samples().tryPop(s)) samples.push_back(s);
  }
  EXPECT_EQ(hl.fault(), client::loop::LoopFault::kNone);
  return technique::seriesFromSamples(samples, patient.force_scale);
}

TEST(StudentSkill, ConfigReadsTheSkillKeys) {
  const ClientConfig c = parseClientConfig(
      "[operator]\nforce_bias_n = -1.5\nfrequency_error_hz = 0.4\ntremor_n = 0.8\n"
      "amplitude_scale = 0.7\n",
      "test");
  EXPECT_DOUBLE_EQ(c.op.force_bias_n, -1.5);
  EXPECT_DOUBLE_EQ(c.op.frequency_error_hz, 0.4);
  EXPECT_DOUBLE_EQ(c.op.tremor_n, 0.8);
  EXPECT_DOUBLE_EQ(c.op.amplitude_scale, 0.7);
  const ClientConfig d = parseClientConfig("", "test");  // the clinician
  EXPECT_EQ(d.op.force_bias_n, 0.0);
  EXPECT_EQ(d.op.frequency_error_hz, 0.0);
  EXPECT_EQ(d.op.tremor_n, 0.0);
  EXPECT_EQ(d.op.amplitude_scale, 1.0);
}

TEST(StudentSkill, ConfigErrorsNameTheBadKey) {
  const std::pair<const char*, const char*> cases[] = {
      {"[operator]\nforce_bias_n = 30.0\n", "operator.force_bias_n"},
      {"[operator]\nforce_bias_n = \"high\"\n", "operator.force_bias_n"},
      // 3 Hz - 3 Hz: no oscillation left.
      {"[operator]\nfrequency_error_hz = -3.0\n", "operator.frequency_error_hz"},
      {"[operator]\nfrequency_error_hz = nan\n", "operator.frequency_error_hz"},
      {"[operator]\ntremor_n = -0.1\n", "operator.tremor_n"},
      {"[operator]\namplitude_scale = 9.0\n", "operator.amplitude_scale"},
      {"[operator]\ntremor = 1.0\n", "tremor"},
  };
  for (const auto& [text, key] : cases) {
    try {
      parseClientConfig(text, "test");
      ADD_FAILURE() << "accepted: " << text;
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find(key), std::string::npos) << e.what();
    }
  }
}

TEST(StudentSkill, TremorIsBandLimitedWithTheSetRms) {
  for (uint64_t seed : {3u, 11u}) {
    ManualClock clock(kNsPerS);
    OperatorConfig op;
    op.tremor_n = 0.8;
    op.seed = seed;
    devices::SimulatedMf2 dev(healthy(), op, clock);
    devices::DeviceSample ds;
    double ss = 0.0, prev = 0.0;
    int n = 0, crossings = 0;
    for (int i = 0; i < 20000; ++i) {
      clock.advance(kNsPerMs);
      ASSERT_TRUE(dev.read(ds));
      if (i < 2000) continue;  // after the build-up
      const double x = dev.tremorN();
      ss += x * x;
      if (n > 0 && prev < 0.0 && x >= 0.0) ++crossings;
      prev = x;
      ++n;
    }
    const double rms = std::sqrt(ss / n), rate_hz = crossings / (n * 1e-3);
    std::printf("seed %llu: tremor RMS %.3f N, %.1f upward crossings per s\n",
                static_cast<unsigned long long>(seed), rms, rate_hz);
    EXPECT_NEAR(rms, 0.8, 0.08);
    EXPECT_GT(rate_hz, 8.0);
    EXPECT_LT(rate_hz, 12.0);
  }
}

TEST(StudentSkill, TheScoreRecoversTheStudentsSkill) {
  const JointModelParams patient = healthy();
  OperatorConfig clinician;
  const technique::Targets t = deriveTargets(runTrial(patient, clinician), kSettleS);
  std::printf("targets: band %.2f-%.2f N, %.3f Hz, amplitude %.2f deg, jerk %.2f, in band %.2f\n",
              t.band_min_n, t.band_max_n, t.frequency_hz, t.amplitude_deg, t.jerk, t.time_in_band);
  EXPECT_NEAR(t.band_min_n, 12.0, 0.3);
  EXPECT_NEAR(t.band_max_n, 16.0, 0.3);
  EXPECT_NEAR(t.frequency_hz, 3.0, 0.02);

  // The clinician again (other sensor noise) is near perfect.
  clinician.seed = 99;
  const technique::TrialScore again = score(runTrial(patient, clinician), t, kSettleS);
  std::printf("clinician again: %s\n", technique::summaryLine(again).c_str());
  EXPECT_GT(again.overall, 95.0);

  struct Skill {
    double bias_n, freq_hz, amp_scale;
  };
  for (const Skill& k : {Skill{1.0, 0.4, 1.0}, Skill{-1.3, -0.6, 0.7}, Skill{0.5, 1.2, 1.3}}) {
    OperatorConfig op;
    op.force_bias_n = k.bias_n;
    op.frequency_error_hz = k.freq_hz;
    op.amplitude_scale = k.amp_scale;
    op.seed = 5;
    const technique::TrialScore s = score(runTrial(patient, op), t, kSettleS);
    std::printf("bias %+.1f N, frequency %+.1f Hz, amplitude x%.1f: %s\n", k.bias_n, k.freq_hz,
                k.amp_scale, technique::summaryLine(s).c_str());
    EXPECT_NEAR(s.mean_error_n, k.bias_n, 0.2);
    EXPECT_NEAR(s.frequency_error_hz, k.freq_hz, 0.05);
    const double half = 2.0 * k.amp_scale;  // half the 12-16 N band, scaled
    EXPECT_NEAR(s.peak_error_n, k.bias_n + half - 2.0, 0.25);
    EXPECT_NEAR(s.trough_error_n, k.bias_n - half + 2.0, 0.25);
    EXPECT_LT(s.overall, again.overall);
  }

  OperatorConfig shaky;
  shaky.tremor_n = 1.0;
  shaky.seed = 5;
  const technique::TrialScore s = score(runTrial(patient, shaky), t, kSettleS);
  std::printf("tremor 1.0 N: %s\n", technique::summaryLine(s).c_str());
  EXPECT_GT(s.jerk_delta, 0.5);
  EXPECT_NEAR(s.mean_error_n, 0.0, 0.1);
  EXPECT_LT(s.overall, again.overall);
}

/// A better and a worse student, random skills: the worse is further from the clinician on
/// every axis (force bias, frequency error, tremor, amplitude) by a random margin.
TEST(StudentSkill, ABetterStudentScoresAboveAWorseOne) {
  const JointModelParams patient = healthy();
  const technique::Targets t = deriveTargets(runTrial(patient, OperatorConfig{}), kSettleS);
  int wins = 0;
  double margin_min = 1e9, margin_sum = 0.0;
  constexpr int kSeeds = 20;
  for (int seed = 1; seed <= kSeeds; ++seed) {
    std::mt19937_64 rng(static_cast<uint64_t>(seed) * 7919u);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    auto sign = [&] { return u(rng) < 0.5 ? -1.0 : 1.0; };
    // Magnitudes: the better student's, then the worse one's strictly larger.
    const double bias = 0.5 * u(rng), freq = 0.15 * u(rng), tremor = 0.3 * u(rng),
                 amp = 0.05 * u(rng);
    const double bias_w = bias + 0.3 + 1.2 * u(rng), freq_w = freq + 0.1 + 0.5 * u(rng),
                 tremor_w = tremor + 0.2 + 0.8 * u(rng), amp_w = amp + 0.05 + 0.25 * u(rng);
    OperatorConfig better, worse;
    better.force_bias_n = sign() * bias;
    better.frequency_error_hz = sign() * freq;
    better.tremor_n = tremor;
    better.amplitude_scale = 1.0 + sign() * amp;
    better.seed = static_cast<uint64_t>(seed);
    worse.force_bias_n = sign() * bias_w;
    worse.frequency_error_hz = sign() * freq_w;
    worse.tremor_n = tremor_w;
    worse.amplitude_scale = 1.0 + sign() * amp_w;
    worse.seed = static_cast<uint64_t>(seed) + 1000u;
    const double sb = score(runTrial(patient, better), t, kSettleS).overall;
    const double sw = score(runTrial(patient, worse), t, kSettleS).overall;
    std::printf(
        "seed %2d: better (bias %+.2f N, %+.2f Hz, tremor %.2f N, amp x%.2f) %.1f; worse "
        "(bias %+.2f N, %+.2f Hz, tremor %.2f N, amp x%.2f) %.1f\n",
        seed, better.force_bias_n, better.frequency_error_hz, better.tremor_n,
        better.amplitude_scale, sb, worse.force_bias_n, worse.frequency_error_hz, worse.tremor_n,
        worse.amplitude_scale, sw);
    if (sb > sw) ++wins;
    margin_min = std::min(margin_min, sb - sw);
    margin_sum += sb - sw;
  }
  std::printf("better above worse in %d of %d, margin min %.1f mean %.1f points\n", wins, kSeeds,
              margin_min, margin_sum / kSeeds);
  EXPECT_EQ(wins, kSeeds);
}

}  // namespace
}  // namespace telehand
