// Capture and fitting end to end: synthetic captures of known joints through the simulated
// MF-2 and the client's loop in capture mode, fitted per axis (paper section IV.B).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <numbers>
#include <random>
#include <utility>

#include "telehand/config/config.h"
#include "telehand/core/clock.h"
#include "telehand/core/fit.h"
#include "telehand/core/knn_model.h"
#include "telehand/server/estimate/capture_fit.h"
#include "telehand/server/estimate/live_refit.h"
#include "telehand/server/estimate/synthetic_capture.h"
#include "telehand/server/store/sqlite_store.h"

namespace telehand::server::estimate {
namespace {

constexpr double kPaperNoiseN = 1.43;  // thimble accuracy, docs/facts.md "The paper"
/// The rig's finger integrated as captures are by default (its continuous motion sampled),
/// and once a sample: a record whose force goes with the angle a sample before and the rate
/// half a sample before that, as a device whose force channel is read a sample late and
/// whose motion turns within a sample. The fit's lag search and its reading of the turns
/// were built against such records; the tests of those keep them.
const int kContinuousRig = SyntheticCaptureOptions{}.rig_substeps;
constexpr int kSteppedRig = 1;

TEST(FitCubic, RecoversAnExactCubicOverAWideRange) {
  // Raw powers of ±90 deg span 1..7e5: the centred, scaled QR keeps full precision.
  std::vector<double> x, y;
  const std::array<double, 4> c = {1.834e-5, 0.0010338, 0.046382, 0.59057};
  for (double a = -45.0; a <= 90.0; a += 0.05) {
    x.push_back(a);
    y.push_back(((c[0] * a + c[1]) * a + c[2]) * a + c[3]);
  }
  const CubicFitResult r = fitCubic(x, y);
  ASSERT_TRUE(r.ok);
  for (int i = 0; i < 4; ++i) EXPECT_NEAR(r.coeffs[i], c[i], 1e-10 * (1 + std::abs(c[i]))) << i;
  EXPECT_LT(r.rms, 1e-10);
  EXPECT_DOUBLE_EQ(r.x_min, -45.0);
}

TEST(FitCubic, ExtraRegressorAndDegenerateInput) {
  std::vector<double> x, y, v;
  std::mt19937_64 rng(2);
  std::normal_distribution<double> n;
  for (int i = 0; i < 2000; ++i) {
    const double a = 20.0 * std::sin(i * 0.01), rate = 3.0 * n(rng);
    x.push_back(a);
    v.push_back(rate);
    y.push_back(0.13 * a - 0.49 + 0.25 * rate);
  }
  const CubicFitResult r = fitCubic(x, y, v);
  ASSERT_TRUE(r.ok);
  EXPECT_NEAR(r.extra, 0.25, 1e-9);
  EXPECT_NEAR(r.coeffs[2], 0.13, 1e-9);
  EXPECT_FALSE(fitCubic(std::vector<double>(50, 3.0), std::vector<double>(50, 1.0)).ok)
      << "a single angle cannot determine a curve";
  EXPECT_FALSE(fitCubic(std::vector<double>{1, 2, 3}, std::vector<double>{1, 2, 3}).ok);
}

TEST(FitCubic, ExpandScaledCubic) {
  // p(t) = 1 + 2t + 3t^2 + 4t^3 with t = (x - 5) / 2, checked at a few points.
  const auto c = expandScaledCubic({1, 2, 3, 4}, 5.0, 2.0);
  for (double xv : {-3.0, 0.0, 5.0, 11.0}) {
    const double t = (xv - 5.0) / 2.0;
    EXPECT_NEAR(((c[0] * xv + c[1]) * xv + c[2]) * xv + c[3], 1 + 2 * t + 3 * t * t + 4 * t * t * t,
                1e-9);
  }
}

struct AxisCheck {
  double max_error_n = 0.0;
  double rms_n = 0.0;
};

/// Fit a synthetic capture of `truth` and compare with it over the range each axis reached.
std::array<AxisCheck, kAxes> fitAndCompare(const JointModelParams& truth, uint64_t seed,
                                           double seconds_per_axis, CaptureFit* fit_out = nullptr) {
  SyntheticCaptureOptions o;
  o.truth = truth;
  o.noise_n = kPaperNoiseN;
  o.seed = seed;
  o.seconds_per_axis = seconds_per_axis;
  const SyntheticCapture cap = synthesizeCapture(o);
  CaptureFitter fitter(cap.geometry);
  for (const auto& s : cap.samples) fitter.add(s, true);
  const CaptureFit fit = fitter.fit();
  EXPECT_TRUE(fit.ok());
  // The clinician stays under the FSRs' saturation; a noise peak may touch it now and then.
  EXPECT_LT(fit.counts.fsr_fault, cap.samples.size() / 1000);
  EXPECT_EQ(fit.counts.not_capture, 0u);
  const JointModel m(truth);
  std::array<AxisCheck, kAxes> out{};
  for (int i = 0; i < kAxes; ++i) {
    const auto ax = static_cast<std::size_t>(i);
    const AxisFit& a = fit.axes[ax];
    out[ax].rms_n = a.rms_n;
    // The range reached covers what the clinician planned (the servo lags by a few degrees
    // where the joint is stiff).
    EXPECT_LT(a.reached_min_deg, cap.plan.lo_deg[ax] + 3.0) << kAxisNames[ax];
    EXPECT_GT(a.reached_max_deg, cap.plan.hi_deg[ax] - 3.0) << kAxisNames[ax];
    // Eqs. 3-5 hold inside the joint's range; past its ends the truth is the wall (kWallNPerDeg,
    // 1 N/deg), which a capture that pressed a few tenths of a degree into it cannot
    // tell from the curve. The walls the capture did feel are checked by their own tests.
    const double lo = std::max(a.reached_min_deg, truth.axes[ax].min_deg);
    const double hi = std::min(a.reached_max_deg, truth.axes[ax].max_deg);
    for (double d = lo; d <= hi; d += 0.1) {
      const double err = std::abs(a.holdingForceN(d) - m.holdingForceN(i, degToRad(d)));
      out[ax].max_error_n = std::max(out[ax].max_error_n, err);
    }
    // The lax zone holds the rest angle.
    const double rest = radToDeg(m.restAngleRad(i));
    EXPECT_LE(a.neutral_min_deg, rest + 0.5) << kAxisNames[ax];
    EXPECT_GE(a.neutral_max_deg, rest - 0.5) << kAxisNames[ax];
  }
  if (fit_out) *fit_out = fit;
  return out;
}

/// Angular rates (windowedRates, FitOptions::rate_half_window 4): the least-squares slope
/// over ±4 ms reads a 6 Hz sweep at most 0.3 % slow, where the central difference over
/// ±5 ms used before read it 0.59 % slow (sin(ωh)/(ωh)); against the angle's noise it is
/// the quieter of the two (1/√60 against 1/√50); and where samples are missing (FSR faults)
/// it fits the samples that are there, by their times (a quadratic, so that a window short
/// on one side is not tilted by the curvature as a straight line would be).
TEST(CaptureFit, RatesReadAFastSweepWithLessBiasAndNoise) {
  constexpr double kHz = 6.0, kAmp = 1.0;  // rad
  const double w = 2.0 * std::numbers::pi * kHz;
  std::vector<int64_t> t;
  std::vector<double> x, truth;
  for (int64_t k = 0; k < 2000; ++k) {
    if (k % 7 == 3) continue;  // samples left out
    t.push_back(k * 1'000'000);
    x.push_back(kAmp * std::sin(w * static_cast<double>(k) * 1e-3));
    truth.push_back(kAmp * w * std::cos(w * static_cast<double>(k) * 1e-3));
  }
  const std::vector<double> r = windowedRates(t, x, 4);
  ASSERT_EQ(r.size(), x.size());
  double worst = 0.0;
  for (std::size_t i = 10; i + 10 < r.size(); ++i)
    worst = std::max(worst, std::abs(r[i] - truth[i]));
  std::printf("6 Hz sweep, samples missing: rate off by at most %.3f %% of its peak\n",
              100.0 * worst / (kAmp * w));
  EXPECT_LT(worst, 0.004 * kAmp * w);
  // Every sample present: the bias alone, against the central difference's.
  std::vector<int64_t> tf;
  std::vector<double> xf;
  for (int64_t k = 0; k < 2000; ++k) {
    tf.push_back(k * 1'000'000);
    xf.push_back(kAmp * std::sin(w * static_cast<double>(k) * 1e-3));
  }
  const std::vector<double> rf = windowedRates(tf, xf, 4);
  double slope_bias = 0.0, central_bias = 0.0;
  for (std::size_t i = 10; i + 10 < rf.size(); ++i) {
    const double v = kAmp * w * std::cos(w * static_cast<double>(i) * 1e-3);
    slope_bias = std::max(slope_bias, std::abs(rf[i] - v));
    central_bias = std::max(central_bias, std::abs((xf[i + 5] - xf[i - 5]) / 10e-3 - v));
  }
  std::printf("bias at 6 Hz: %.3f %% (least-squares slope, ±4 ms), %.3f %% (central, ±5 ms)\n",
              100.0 * slope_bias / (kAmp * w), 100.0 * central_bias / (kAmp * w));
  EXPECT_LT(slope_bias, 0.003 * kAmp * w);
  EXPECT_GT(central_bias, 0.0055 * kAmp * w);
  // White noise on the angle alone: the slope's noise against the central difference's.
  std::mt19937 gen(3);
  std::normal_distribution<double> noise(0.0, 1e-3);
  std::vector<double> xn(tf.size());
  for (double& v : xn) v = noise(gen);
  const std::vector<double> rn = windowedRates(tf, xn, 4);
  double ss_slope = 0.0, ss_central = 0.0;
  for (std::size_t i = 10; i + 10 < rn.size(); ++i) {
    ss_slope += rn[i] * rn[i];
    const double c = (xn[i + 5] - xn[i - 5]) / 10e-3;
    ss_central += c * c;
  }
  const double ratio = std::sqrt(ss_slope / ss_central);
  std::printf("rate noise, slope / central: %.3f (expected %.3f)\n", ratio, std::sqrt(50.0 / 60.0));
  EXPECT_LT(ratio, 0.97);
}

/// The capture rig's finger integrated once a sample (semi-implicit Euler) records a force
/// that goes with the angle a sample before and the rate half a sample before that; with
/// more steps a sample (CaptureRigOptions::substeps) the record samples the continuous
/// motion: force = curve(angle) + damping · rate + inertia · acceleration at the same instant,
/// the rate and acceleration the central differences. A noise-free 6 Hz capture of a random
/// patient whose sweep turns hard at its walls: the worst mean residual of a 5 deg bin of
/// flexion (the bias a fit takes up; the acceleration's quantization noise averages out).
TEST(CaptureFit, ASubsteppedRigRecordsTheContinuousMotion) {
  const JointModelParams truth = randomPatientCase(172).model;
  ASSERT_EQ(truth.speed_gain_s_per_rad, 0.0);
  auto worstBin = [&](int substeps, int lag) {
    SyntheticCaptureOptions o;
    o.truth = truth;
    o.noise_n = 0.0;
    o.frequency_hz = 6.0;
    o.seed = 10;
    o.rig_substeps = substeps;
    const SyntheticCapture cap = synthesizeCapture(o);
    CaptureFitter fitter(cap.geometry);
    for (const auto& smp : cap.samples) fitter.add(smp, true);
    const auto& p = fitter.points();
    const JointModel m(truth);
    const double lever = cap.geometry.lever_arm_m, dt = 1e-3;
    const double inertia = FitOptions{}.inertia_kgm2;
    std::array<double, 40> sum{}, count{};
    for (std::size_t k = 3; k + 2 < p.size(); ++k) {
      const std::size_t q = k - static_cast<std::size_t>(lag);
      if (p[k + 1].seq - p[q - 1].seq != static_cast<uint64_t>(lag) + 2) continue;
      const double a = p[q].angles_rad[kFlexion];
      const double before = p[q - 1].angles_rad[kFlexion], after = p[q + 1].angles_rad[kFlexion];
      const double rate = (after - before) / (2 * dt), acc = (after - 2 * a + before) / (dt * dt);
      if (std::abs(rate) < 0.05) continue;
      const double model = m.holdingForceN(kFlexion, a) + truth.damping_nms_per_rad * rate / lever +
                           inertia * acc / lever;
      const auto bin = static_cast<std::size_t>(std::clamp((radToDeg(a) + 60.0) / 5.0, 0.0, 39.0));
      sum[bin] += p[k].axis_force_n[kFlexion] - model;
      count[bin] += 1.0;
    }
    double worst = 0.0;
    for (std::size_t b = 0; b < sum.size(); ++b)
      if (count[b] >= 100.0) worst = std::max(worst, std::abs(sum[b] / count[b]));
    return worst;
  };
  const double once = worstBin(1, 0), once_lagged = worstBin(1, 1), fine = worstBin(10, 0);
  std::printf(
      "worst 5-deg bin of the continuous relation's residual, N: 1 step %.3f (a sample "
      "later %.3f), 10 steps %.3f\n",
      once, once_lagged, fine);
  EXPECT_LT(fine, 0.6 * std::min(once, once_lagged));
}

TEST(CaptureFit, PaperJointWithThimbleNoise) {
  CaptureFit fit;
  const auto checks = fitAndCompare(healthyIndexMcp(), 1, 20.0, &fit);
  for (std::size_t i = 0; i < kAxes; ++i) {
    SCOPED_TRACE(std::string(kAxisNames[i]));
    EXPECT_LT(checks[i].max_error_n, 0.3) << "fitted curve vs eqs. 3-5 over the captured range";
    EXPECT_NEAR(checks[i].rms_n, kPaperNoiseN, 0.2 * kPaperNoiseN)
        << "RMS residual vs injected noise";
    RecordProperty(std::string(kAxisNames[i]) + "_max_error_n",
                   std::to_string(checks[i].max_error_n));
    RecordProperty(std::string(kAxisNames[i]) + "_rms_n", std::to_string(checks[i].rms_n));
    std::printf("%-9s max |fit - truth| %.3f N, RMS residual %.3f N\n", kAxisNames[i].data(),
                checks[i].max_error_n, checks[i].rms_n);
  }
  // The viscous term is found too (truth 0.002 N·m·s/rad), roughly.
  EXPECT_NEAR(fit.model(healthyIndexMcp()).damping_nms_per_rad, 0.002, 0.001);
}

/// A joint drawn at random within physiological limits (docs/facts.md "Index MCP biomechanics"):
/// ranges around flexion -60..100, abduction about ±20, axial -12..18 deg; monotonic
/// cubics holding 6-20 N at the range ends, the rest angle near neutral.
JointModelParams randomJoint(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  auto in = [&](double lo, double hi) { return lo + (hi - lo) * u(rng); };
  JointModelParams p = healthyIndexMcp();
  const std::array<std::array<double, 4>, kAxes> ranges = {
      {{-60, -30, 70, 100}, {-25, -12, 12, 25}, {-12, -6, 8, 18}}};
  for (std::size_t i = 0; i < kAxes; ++i) {
    CubicCurve& c = p.axes[i];
    c.min_deg = in(ranges[i][0], ranges[i][1]);
    c.max_deg = in(ranges[i][2], ranges[i][3]);
    const double span = std::max(-c.min_deg, c.max_deg);
    const double c1 = in(0.3, 1.2) * 6.0 / span;                              // N/deg near rest
    const double c3 = in(0.5, 1.5) * (14.0 - c1 * span) / std::pow(span, 3);  // stiffer ends
    const double c2max = 0.8 * std::sqrt(3.0 * c1 * std::max(c3, 0.0));       // keeps dF/da > 0
    c.coeffs = {std::max(c3, 0.0), in(-c2max, c2max), c1, in(-1.0, 1.0)};
  }
  p.damping_nms_per_rad = in(0.0005, 0.004);
  return p;
}

TEST(CaptureFit, RandomPhysiologicalJoints) {
  uint64_t seed = std::random_device{}();
  if (const char* s = std::getenv("TELEHAND_TEST_SEED")) seed = std::strtoull(s, nullptr, 10);
  std::printf("TELEHAND_TEST_SEED=%llu reproduces these joints\n",
              static_cast<unsigned long long>(seed));
  std::mt19937_64 rng(seed);
  for (int trial = 0; trial < 3; ++trial) {
    const JointModelParams truth = randomJoint(rng);
    SCOPED_TRACE("seed " + std::to_string(seed) + ", joint " + std::to_string(trial));
    const auto checks = fitAndCompare(truth, seed + static_cast<uint64_t>(trial), 15.0);
    for (std::size_t i = 0; i < kAxes; ++i) {
      SCOPED_TRACE(
          std::string(kAxisNames[i]) + " coeffs " + std::to_string(truth.axes[i].coeffs[0]) + ", " +
          std::to_string(truth.axes[i].coeffs[1]) + ", " + std::to_string(truth.axes[i].coeffs[2]) +
          ", " + std::to_string(truth.axes[i].coeffs[3]));
      EXPECT_LT(checks[i].max_error_n, 0.3);
      EXPECT_NEAR(checks[i].rms_n, kPaperNoiseN, 0.2 * kPaperNoiseN);
    }
  }
}

TEST(CaptureFit, FaultySensorsAndRenderedSamplesAreLeftOut) {
  const JointModel geometry(captureGeometry(healthyIndexMcp()));
  Sample s{};
  s.flags = sample_flags::kCapture;
  const auto p = geometry.gripFromAngles(Vec3::Zero(), 0.008);
  for (int k = 0; k < 2; ++k) {
    for (int i = 0; i < 3; ++i) s.fingers[k].position_m[i] = p[k][i];
    s.fingers[k].orientation_q[0] = 1.0;
  }
  CaptureCounts counts;
  EXPECT_TRUE(capturePoint(geometry, s, true, counts).has_value());
  EXPECT_FALSE(capturePoint(geometry, s, false, counts).has_value());
  Sample sat = s;
  sat.flags |= 1u << (sample_flags::kFsrFaultShift + 4 + 3);  // index pad sensor
  EXPECT_FALSE(capturePoint(geometry, sat, true, counts).has_value());
  Sample rendered = s;
  rendered.flags = 0;
  EXPECT_FALSE(capturePoint(geometry, rendered, true, counts).has_value());
  EXPECT_EQ(counts.used, 1u);
  EXPECT_EQ(counts.invalid, 1u);
  EXPECT_EQ(counts.fsr_fault, 1u);
  EXPECT_EQ(counts.not_capture, 1u);
}

/// Near an FSR's ceiling (FitOptions::saturation_margin): the samples left out are chosen by
/// the sensor's reading around them, not by their own noise. The index pad sensor's force
/// rises past its 22 N ceiling and falls back, with 0.5 N of noise; what saturates is
/// flagged and read at the ceiling. Every sample whose noise-free reading is within 3
/// noise widths of the ceiling goes, none further than 5 below it; a dead channel's flags
/// (reading 0) and a capture that never saturates leave nothing out, nor does a margin of 0.
TEST(CaptureFit, SamplesNearAnFsrsCeilingAreLeftOutByTheirNeighbours) {
  const JointModel geometry(captureGeometry(healthyIndexMcp()));
  const auto p = geometry.gripFromAngles(Vec3::Zero(), 0.008);
  constexpr double kCeiling = 22.0, kSigma = 0.5;
  constexpr int kPad = 3;  // sensor 4 of the index
  // `hostile`: every flagged sample sent four times, and flagged samples whose readings are
  // not numbers, beside the capture.
  auto capture = [&](double peak_n, bool dead_channel, const FitOptions& o, bool hostile = false) {
    std::mt19937_64 rng(11);
    std::normal_distribution<double> noise(0.0, kSigma);
    CaptureFitter fitter(captureGeometry(healthyIndexMcp()), o);
    std::size_t near = 0, far = 0;  // unflagged samples by their noise-free reading
    for (uint64_t i = 0; i < 4000; ++i) {
      Sample s{};
      s.seq = i;
      s.source_time_ns = static_cast<int64_t>(i) * kNsPerMs;
      s.flags = sample_flags::kCapture;
      for (int k = 0; k < 2; ++k) {
        for (int j = 0; j < 3; ++j) s.fingers[k].position_m[j] = p[k][j];
        s.fingers[k].orientation_q[0] = 1.0;
      }
      // Four pushes of 1 s, each a half sine up to peak_n.
      const double phase = static_cast<double>(i % 1000) / 1000.0;
      const double truth = peak_n * std::sin(std::numbers::pi * phase);
      const double read = truth + noise(rng);
      s.fingers[1].fsr_n[kPad] = static_cast<float>(std::min(read, kCeiling));
      if (read >= kCeiling) s.flags |= 1u << (sample_flags::kFsrFaultShift + 4 + kPad);
      if (dead_channel && i % 1000 < 50) {
        s.fingers[0].fsr_n[1] = 0.0f;
        s.flags |= 1u << (sample_flags::kFsrFaultShift + 1);
      }
      if (!(s.flags >> sample_flags::kFsrFaultShift)) {
        if (truth > kCeiling - 3.0 * kSigma) ++near;
        if (truth < kCeiling - 5.0 * kSigma) ++far;
      }
      fitter.add(s, true);
      if (hostile && (s.flags >> sample_flags::kFsrFaultShift)) {
        for (int copy = 0; copy < 3; ++copy) fitter.add(s, true);
        Sample junk = s;
        junk.seq += 1'000'000;
        for (auto& f : junk.fingers)
          for (float& v : f.fsr_n) v = std::numeric_limits<float>::quiet_NaN();
        fitter.add(junk, true);
      }
    }
    const CaptureCounts c = fitter.fit().counts;
    return std::array<std::size_t, 4>{static_cast<std::size_t>(c.near_saturation), near, far,
                                      static_cast<std::size_t>(c.fsr_fault)};
  };
  const auto sat = capture(24.0, false, {});
  ASSERT_GT(sat[3], 100u) << "the pushes saturate the sensor";
  ASSERT_GT(sat[1], 100u);
  EXPECT_GE(sat[0], sat[1]) << "every sample near the ceiling is left out";
  EXPECT_LE(sat[0], 4000u - sat[3] - sat[2]) << "none far below it";
  EXPECT_EQ(capture(24.0, false, {}, true)[0], sat[0])
      << "copies of the flagged samples and readings that are not numbers change nothing";
  const auto dead = capture(18.0, true, {});
  EXPECT_EQ(dead[3], 200u) << "the dead channel's samples are flagged";
  EXPECT_EQ(dead[0], 0u) << "a dead channel is not a ceiling";
  EXPECT_EQ(capture(18.0, false, {})[0], 0u) << "nothing saturated";
  FitOptions off;
  off.saturation_margin = 0.0;
  EXPECT_EQ(capture(24.0, false, off)[0], 0u);
}

TEST(CaptureFit, SamplesOutOfOrderGiveTheSamePointsAsInOrder) {
  // A backlog sent after an outage while live samples go on, a retried chunk: the same points,
  // in sequence order, the first copy of a sequence number kept.
  SyntheticCaptureOptions o;
  o.seconds_per_axis = 4.0;
  const SyntheticCapture cap = synthesizeCapture(o);
  const std::size_t n = cap.samples.size();
  ASSERT_GT(n, 4000u);
  CaptureFitter in_order(cap.geometry), scrambled(cap.geometry);
  for (const auto& s : cap.samples) in_order.add(s, true);
  auto altered = [](Sample s) {  // a second copy that must not be the one kept
    s.fingers[0].normal_n += 5.0f;
    s.fingers[0].tangential_n += 5.0f;
    return s;
  };
  for (std::size_t k = n / 2; k < n; ++k) scrambled.add(cap.samples[k], true);
  for (std::size_t k = n / 2; k-- > 0;) scrambled.add(cap.samples[k], true);  // far back
  for (std::size_t k = 0; k < 100; ++k) scrambled.add(altered(cap.samples[k]), true);
  for (std::size_t k = n - 10; k < n; ++k) {
    EXPECT_FALSE(scrambled.add(altered(cap.samples[k]), true)) << "held already, in order";
  }
  for (std::size_t k = n - 40; k < n - 30; ++k) scrambled.add(altered(cap.samples[k]), true);
  {
    CaptureFitter one(cap.geometry);
    one.add(altered(cap.samples[50]), true);
    ASSERT_EQ(one.size(), 1u);
    const auto it =
        std::find_if(in_order.points().begin(), in_order.points().end(),
                     [&](const CapturePoint& p) { return p.seq == cap.samples[50].seq; });
    ASSERT_NE(it, in_order.points().end());
    ASSERT_NE(one.points()[0].axis_force_n, it->axis_force_n) << "the second copy differs";
  }
  ASSERT_EQ(scrambled.size(), in_order.size());
  const auto& a = in_order.points();
  const auto& b = scrambled.points();
  for (std::size_t i = 0; i < a.size(); ++i) {
    ASSERT_EQ(a[i].seq, b[i].seq) << i;
    ASSERT_EQ(a[i].angles_rad, b[i].angles_rad) << i;
    ASSERT_EQ(a[i].axis_force_n, b[i].axis_force_n) << i << ": the first copy is kept";
  }
  // Read again after more arrive: merged again, still in order.
  scrambled.add(altered(cap.samples[n / 4]), true);
  EXPECT_EQ(scrambled.points().size(), a.size());
}

TEST(CaptureFit, StoredCaptureFitsTheSameAndWritesALoadableCase) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / ("telehand-fit-" + std::to_string(getpid()));
  fs::create_directories(dir);
  SyntheticCaptureOptions o;
  o.seconds_per_axis = 8.0;
  o.device = mf2::loadMf2Description(std::string(TELEHAND_DEPLOY_DIR) + "/devices/mf2.toml");
  const SyntheticCapture cap = synthesizeCapture(o);
  CaptureFitter direct(cap.geometry);
  for (const auto& s : cap.samples) direct.add(s, true);
  uint64_t id = 0;
  {
    store::SqliteStore store((dir / "r.db").string());
    id = storeCapture(store, cap, "healthy", "expert", deviceFiles(o.device));
  }
  store::SqliteStore store((dir / "r.db").string(), store::SqliteStore::Mode::kReadOnly);
  const auto info = store.session(id);
  ASSERT_TRUE(info.has_value());
  EXPECT_EQ(info->mode, "capture");
  EXPECT_EQ(info->samples, cap.samples.size());
  const auto files = store.files(id);
  ASSERT_EQ(files.size(), 3u) << "the device file and both thimble calibrations";
  EXPECT_EQ(files[0].name, "device/mf2.toml");
  EXPECT_NE(files[1].content.find("serial = \"T02\""), std::string::npos);
  CaptureFitter stored(cap.geometry);
  store.forEachSample(id, [&](const Sample& s, bool valid) { stored.add(s, valid); });
  const CaptureFit a = direct.fit(), b = stored.fit();
  for (std::size_t i = 0; i < kAxes; ++i) EXPECT_EQ(a.axes[i].curve, b.axes[i].curve);

  const JointModelParams model = b.model(healthyIndexMcp());
  const std::string toml =
      patientCaseToml(b, model, "fitted", "fitted from session", "synthetic capture");
  const PatientCase pc = parsePatientCase(toml, "fitted.toml");
  EXPECT_EQ(pc.name, "fitted");
  for (std::size_t i = 0; i < kAxes; ++i) {
    for (int c = 0; c < 4; ++c) {
      EXPECT_NEAR(pc.model.axes[i].coeffs[c], model.axes[i].coeffs[c],
                  1e-8 * (1 + std::abs(model.axes[i].coeffs[c])));
    }
    EXPECT_NEAR(pc.model.axes[i].min_deg, model.axes[i].min_deg, 1e-3);
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace telehand::server::estimate

namespace telehand::server::estimate {
namespace {

/// Abduction stiffer in flexion (the MCP collateral ligaments tighten as it flexes): the
/// abduction torque of the paper's joint scaled by 0.4 at 40 deg extension up to 1.6 at
/// 90 deg flexion. Separable cubics cannot express it.
class CoupledJoint final : public devices::PatientJoint {
 public:
  explicit CoupledJoint(const JointModelParams& base) : base_(base) {}
  static double factor(double flexion_rad) {
    return 0.4 + 1.2 * std::clamp((radToDeg(flexion_rad) + 40.0) / 130.0, 0.0, 1.0);
  }
  Vec3 passiveTorqueNm(const Vec3& a, const Vec3& r) const noexcept override {
    Vec3 t = base_.passiveTorqueNm(a, r);
    t[kAbduction] *= factor(a[kFlexion]);
    return t;
  }

 private:
  JointModel base_;
};

TEST(CaptureFit, KnnBeatsCubicsOnACoupledJoint) {
  const JointModelParams truth = healthyIndexMcp();
  const CoupledJoint joint(truth);
  auto capture = [&](uint64_t seed) {
    SyntheticCaptureOptions o;
    o.truth = truth;
    o.patient = &joint;
    o.combined_sweep = true;
    o.seconds_per_axis = 15.0;  // 45 s of flexion and abduction swept together
    o.frequency_hz = 0.1;
    o.max_force_n = 8.0;
    o.seed = seed;
    return synthesizeCapture(o);
  };
  const SyntheticCapture train = capture(1), held_out = capture(2);
  CaptureFitter fitter(train.geometry);
  for (const auto& s : train.samples) fitter.add(s, true);
  const CaptureFit fit = fitter.fit();
  ASSERT_TRUE(fit.axes[kFlexion].ok && fit.axes[kAbduction].ok);
  JointModelParams cubic_params = fit.model(truth);
  cubic_params.damping_nms_per_rad = 0.0;  // compare the static torques
  const JointModel cubic(cubic_params);
  std::vector<KnnPoint> raw;
  const double lever = train.geometry.lever_arm_m;
  for (const auto& p : fitter.points()) raw.push_back({p.angles_rad, -p.axis_force_n * lever});
  const KnnTorqueModel knn(voxelAverage(raw, KnnOptions{}.cell_deg));

  CaptureFitter test(held_out.geometry);
  for (const auto& s : held_out.samples) test.add(s, true);
  double se_cubic = 0.0, se_knn = 0.0;
  std::size_t n = 0;
  for (std::size_t i = 0; i < test.points().size(); i += 10) {
    const Vec3 a = test.points()[i].angles_rad;
    const double want = joint.passiveTorqueNm(a, Vec3::Zero())[kAbduction];
    se_cubic += std::pow(cubic.passiveTorqueNm(a, Vec3::Zero())[kAbduction] - want, 2);
    se_knn += std::pow(knn.torqueNm(a)[kAbduction] - want, 2);
    ++n;
  }
  const double nd = static_cast<double>(n);
  const double rms_cubic = std::sqrt(se_cubic / nd) / lever,
               rms_knn = std::sqrt(se_knn / nd) / lever;
  std::printf(
      "held-out abduction error, force at the lever arm: cubic %.3f N RMS, kNN %.3f N RMS "
      "(%zu cells from %zu samples)\n",
      rms_cubic, rms_knn, knn.size(), fitter.size());
  RecordProperty("cubic_rms_n", std::to_string(rms_cubic));
  RecordProperty("knn_rms_n", std::to_string(rms_knn));
  EXPECT_LT(rms_knn, 0.6 * rms_cubic);
}

}  // namespace
}  // namespace telehand::server::estimate

namespace telehand::server::estimate {
namespace {

/// Fitted against true holding force, as the joint model renders both (neutral zone, walls).
struct TruthCheck {
  double inner_n = 0.0;  ///< over the range the capture could reach, off the zone edges and walls
  double edges_n = 0.0;  ///< the same plus the zone edges and 2° into each wall it reached
  double inner_at = 0.0, edges_at = 0.0;
};

/// The part of the truth's range a clinician reaches under `max_force_n`.
std::pair<double, double> reachable(const JointModel& m, int axis, double max_force_n) {
  const CubicCurve& c = m.params().axes[static_cast<std::size_t>(axis)];
  const double rest = radToDeg(m.restAngleRad(axis));
  double lo = rest, hi = rest;
  while (lo - 0.05 >= c.min_deg &&
         std::abs(m.holdingForceN(axis, degToRad(lo - 0.05))) <= max_force_n)
    lo -= 0.05;
  while (hi + 0.05 <= c.max_deg &&
         std::abs(m.holdingForceN(axis, degToRad(hi + 0.05))) <= max_force_n)
    hi += 0.05;
  return {lo, hi};
}

/// The fitted holding force against the truth's, over the truth's range under max_force_n;
/// with `fit`, cut to the range the capture covered (a range end the clinician could not
/// reach, e.g. against a spasm's resistance at speed, is not judged: the fit reports it as
/// not reached).
std::array<TruthCheck, kAxes> compareWithTruth(const JointModelParams& truth_p,
                                               const JointModelParams& fitted_p, double max_force_n,
                                               const CaptureFit* fit = nullptr) {
  JointModelParams static_truth = truth_p;
  static_truth.speed_gain_s_per_rad = 0.0;  // the holding force does not depend on it
  const JointModel truth(static_truth), fitted(fitted_p);
  std::array<TruthCheck, kAxes> out{};
  for (int i = 0; i < kAxes; ++i) {
    const auto ax = static_cast<std::size_t>(i);
    const CubicCurve& c = truth_p.axes[ax];
    auto [lo, hi] = reachable(truth, i, max_force_n);
    bool wall_lo = lo <= c.min_deg + 0.05, wall_hi = hi >= c.max_deg - 0.05;
    if (fit) {
      const AxisFit& a = fit->axes[ax];
      lo = std::max(lo, a.reached_min_deg);
      hi = std::min(hi, a.reached_max_deg);
      wall_lo = wall_lo && a.reached_min_deg <= c.min_deg - 2.0;
      wall_hi = wall_hi && a.reached_max_deg >= c.max_deg + 2.0;
    }
    const double rest = radToDeg(truth.restAngleRad(i));
    const double zone = truth_p.neutral_zone_deg[ax];
    auto nearEdge = [&](double d) {
      if (wall_lo && d < c.min_deg + 1.0) return true;
      if (wall_hi && d > c.max_deg - 1.0) return true;
      return zone > 0.0 && (std::abs(d - (rest - zone)) < 1.5 || std::abs(d - (rest + zone)) < 1.5);
    };
    const double from = wall_lo ? c.min_deg - 2.0 : lo, to = wall_hi ? c.max_deg + 2.0 : hi;
    for (double d = from; d <= to + 1e-9; d += 0.05) {
      const double err =
          std::abs(fitted.holdingForceN(i, degToRad(d)) - truth.holdingForceN(i, degToRad(d)));
      auto& o = out[ax];
      if (err > o.edges_n) {
        o.edges_n = err;
        o.edges_at = d;
      }
      if (d >= lo && d <= hi && !nearEdge(d) && err > o.inner_n) {
        o.inner_n = err;
        o.inner_at = d;
      }
    }
  }
  return out;
}

struct CaseRun {
  CaptureFit fit;
  std::array<TruthCheck, kAxes> check;
};

CaseRun runCase(const JointModelParams& truth, double hz, uint64_t seed,
                double noise_n = kPaperNoiseN, bool captured_range = false,
                const FitOptions& options = {}, int rig_substeps = kContinuousRig) {
  SyntheticCaptureOptions o;  // the default length: 10 s per axis, as telehand-client
  o.truth = truth;
  o.noise_n = noise_n;
  o.frequency_hz = hz;
  o.seed = seed;
  o.rig_substeps = rig_substeps;
  const SyntheticCapture cap = synthesizeCapture(o);
  CaptureFitter fitter(cap.geometry, options);
  for (const auto& s : cap.samples) fitter.add(s, true);
  CaseRun r;
  r.fit = fitter.fit();
  EXPECT_TRUE(r.fit.ok());
  r.check =
      compareWithTruth(truth, r.fit.model(truth), o.max_force_n, captured_range ? &r.fit : nullptr);
  return r;
}

void expectWithin(const JointModelParams& truth, const CaseRun& r, const std::string& what,
                  double inner_n, double edges_n) {
  for (std::size_t i = 0; i < kAxes; ++i) {
    const auto& c = r.check[i];
    const auto& a = r.fit.axes[i];
    std::printf(
        "%-28s %-9s inner %.3f N (at %6.1f)  edges+walls %.3f N (at %6.1f)  range %6.1f..%5.1f "
        "walls %d%d zone %.1f/%.1f  inertia %.2e±%.1e  dyn %.2f N  hyst %.2f N  delay %.2f\n",
        what.c_str(), kAxisNames[i].data(), c.inner_n, c.inner_at, c.edges_n, c.edges_at,
        a.curve.min_deg, a.curve.max_deg, a.wall_min, a.wall_max, a.zone_deg,
        truth.neutral_zone_deg[i], a.inertia_kgm2, a.inertia_se_kgm2, a.dynamic_n, a.hysteresis_n,
        r.fit.delay_samples);
    EXPECT_LT(c.inner_n, inner_n) << what << " " << kAxisNames[i];
    EXPECT_LT(c.edges_n, edges_n) << what << " " << kAxisNames[i];
  }
}

/// One capture of a 6 Hz mobilization fitted twice, as the fit is and with `other` options
/// (judged over the range the capture covered): what an option changes, on the same data.
std::pair<CaseRun, CaseRun> fitBothWays(const JointModelParams& truth, uint64_t seed,
                                        const FitOptions& other,
                                        int rig_substeps = kContinuousRig) {
  return {runCase(truth, 6.0, seed, kPaperNoiseN, true, {}, rig_substeps),
          runCase(truth, 6.0, seed, kPaperNoiseN, true, other, rig_substeps)};
}

JointModelParams shippedCase(const std::string& name) {
  return loadPatientCase(std::string(TELEHAND_DEPLOY_DIR) + "/cases/" + name + ".toml").model;
}

/// The shipped cases (deploy/cases) at the default capture length, at the paper's slow
/// mobilization and at the clinician's 3 and 6 Hz: within 0.3 N off the zone edges and
/// walls, 0.5 N with them. The fit uses the known moving mass (FitOptions::inertia_kgm2):
/// a sweep does not separate inertia from stiffness (docs/capture.md). None of these has a
/// spasm, and none is found. spasm: CaptureFitTruth.SpasmGainAndElasticCurve.
/// A test name's rate: 0.5 Hz as "0p5Hz", 3 Hz as "3Hz".
std::string hzName(double hz) {
  const int tenths = static_cast<int>(std::lround(hz * 10.0));
  return std::to_string(tenths / 10) + (tenths % 10 ? "p" + std::to_string(tenths % 10) : "") +
         "Hz";
}

struct ShippedRun {
  const char* name;
  double hz;
  uint64_t seed;
};

void PrintTo(const ShippedRun& r, std::ostream* os) { *os << r.name << " " << r.hz << " Hz"; }

class ShippedCasesAtDefaultLength : public ::testing::TestWithParam<ShippedRun> {};

TEST_P(ShippedCasesAtDefaultLength, FitsWithinTheBoundsAndFindsNoSpasm) {
  const ShippedRun& run = GetParam();
  const JointModelParams truth = shippedCase(run.name);
  const CaseRun r = runCase(truth, run.hz, run.seed);
  const std::string what =
      std::string(run.name) + " " + std::to_string(run.hz).substr(0, 3) + " Hz";
  expectWithin(truth, r, what, 0.3, 0.5);
  EXPECT_EQ(r.fit.model(truth).speed_gain_s_per_rad, 0.0) << what;
}

// One ctest entry per case and rate (each a capture and a fit of its own, seeds 12-23).
INSTANTIATE_TEST_SUITE_P(
    CaptureFitTruth, ShippedCasesAtDefaultLength,
    ::testing::Values(ShippedRun{"healthy", 0.5, 12}, ShippedRun{"healthy", 3.0, 13},
                      ShippedRun{"healthy", 6.0, 14}, ShippedRun{"stiff", 0.5, 15},
                      ShippedRun{"stiff", 3.0, 16}, ShippedRun{"stiff", 6.0, 17},
                      ShippedRun{"lax", 0.5, 18}, ShippedRun{"lax", 3.0, 19},
                      ShippedRun{"lax", 6.0, 20}, ShippedRun{"recovery", 0.5, 21},
                      ShippedRun{"recovery", 3.0, 22}, ShippedRun{"recovery", 6.0, 23}),
    [](const ::testing::TestParamInfo<ShippedRun>& i) {
      return std::string(i.param.name) + "_" + hzName(i.param.hz);
    });

/// The spasm case (deploy/cases/spasm.toml: gain 1.5 s/rad, damping 0.002 N·m·s/rad, capped
/// at 0.01): the fit holds the stretch reflex, so the holding curve comes out as for the
/// healthy joint it is built on, within 0.3 N (0.5 N with the walls) over the range the
/// capture covered, and the gain within 0.4 s/rad at 0.5-3 Hz. At 6 Hz the gain comes out
/// 17-27 % high (1.75-1.90 on seeds 1-3, 1.87 on this one; measured) and the clinician stops
/// about 3 deg short of the flexion end against the reflex's resistance; the curve is still
/// within 0.3 N where captured.
/// The fitted case file carries the gain.
TEST(CaptureFitTruth, SpasmGainAndElasticCurve) {
  const JointModelParams truth = shippedCase("spasm");
  uint64_t seed = 40;
  for (const double hz : {0.5, 3.0, 6.0}) {
    const CaseRun r = runCase(truth, hz, ++seed, kPaperNoiseN, true);
    const std::string what = "spasm " + std::to_string(hz).substr(0, 3) + " Hz";
    expectWithin(truth, r, what, 0.3, 0.5);
    const JointModelParams m = r.fit.model(truth);
    std::printf("%s: speed gain %.3f s/rad (truth %.2f), damping %.4f N·m·s/rad (truth %.4f)\n",
                what.c_str(), m.speed_gain_s_per_rad, truth.speed_gain_s_per_rad,
                m.damping_nms_per_rad, truth.damping_nms_per_rad);
    for (const auto& a : r.fit.axes) {
      EXPECT_TRUE(a.spasm) << what;
      EXPECT_NEAR(a.damping_cap_nms_per_rad, JointModel(truth).maxDampingNmsPerRad(), 1e-12);
    }
    EXPECT_NEAR(m.speed_gain_s_per_rad, truth.speed_gain_s_per_rad, hz < 5.0 ? 0.4 : 0.6) << what;
    EXPECT_NEAR(m.damping_nms_per_rad, truth.damping_nms_per_rad, 0.001) << what;
    // The flexion end (26 N at 90 deg) is not reached; the case file says so.
    EXPECT_FALSE(r.fit.axes[kFlexion].wall_max) << what;
    const std::string toml = patientCaseToml(r.fit, m, "fitted-spasm", "fitted", "synthetic");
    EXPECT_NE(toml.find("range end not reached"), std::string::npos);
    const PatientCase pc = parsePatientCase(toml, "fitted-spasm.toml");
    EXPECT_NEAR(pc.model.speed_gain_s_per_rad, m.speed_gain_s_per_rad, 1e-5);
    EXPECT_GT(pc.model.speed_gain_s_per_rad, 0.0);
  }
}

/// Without the spasm term (FitOptions::fit_spasm false) the same capture's curve takes up
/// the reflex's force and misses by newtons at speed: the term is what brings it back.
TEST(CaptureFitTruth, SpasmLeftOutBendsTheCurve) {
  const JointModelParams truth = shippedCase("spasm");
  SyntheticCaptureOptions o;
  o.truth = truth;
  o.frequency_hz = 3.0;
  o.seed = 7;
  const SyntheticCapture cap = synthesizeCapture(o);
  FitOptions plain;
  plain.fit_spasm = false;
  CaptureFitter with(cap.geometry), without(cap.geometry, plain);
  for (const auto& s : cap.samples) {
    with.add(s, true);
    without.add(s, true);
  }
  const CaptureFit a = with.fit(), b = without.fit();
  const auto ca = compareWithTruth(truth, a.model(truth), o.max_force_n, &a);
  const auto cb = compareWithTruth(truth, b.model(truth), o.max_force_n, &b);
  EXPECT_LT(ca[kFlexion].inner_n, 0.3);
  EXPECT_GT(cb[kFlexion].inner_n, 2.0);
  EXPECT_EQ(b.model(truth).speed_gain_s_per_rad, 0.0);
  EXPECT_GT(b.axes[kFlexion].hysteresis_n, 1.0) << "the reflex shows as up/down hysteresis";
  EXPECT_LT(a.axes[kFlexion].hysteresis_n, 0.5);
}

/// Joints nobody tuned the fit to: the shipped curves scaled, shifted and given other
/// ranges and zones.
TEST(CaptureFitTruth, PerturbedJoints) {
  JointModelParams a = shippedCase("healthy");
  for (auto& c : a.axes) {
    for (auto& k : c.coeffs) k *= 1.4;
    c.coeffs[3] += 0.6;
    c.min_deg *= 0.8;
    c.max_deg *= 0.85;
  }
  JointModelParams b = shippedCase("lax");
  b.neutral_zone_deg = {7.0, 3.0, 2.5};
  for (auto& c : b.axes) c.coeffs[2] *= 0.7;
  b.axes[kFlexion].min_deg = -55.0;
  JointModelParams c = shippedCase("stiff");
  c.axes[kAbduction].min_deg = -14.0;
  c.axes[kAbduction].max_deg = 6.0;
  int k = 0;
  for (const JointModelParams* truth : {&a, &b, &c}) {
    for (const double hz : {0.5, 3.0, 6.0}) {
      const CaseRun r = runCase(*truth, hz, 100 + static_cast<uint64_t>(k));
      expectWithin(*truth, r,
                   "perturbed " + std::to_string(k) + " " + std::to_string(hz).substr(0, 3) + " Hz",
                   0.3, 0.5);
    }
    ++k;
  }
}

/// One synthetic capture (the default length, the paper's noise) added to two fitters: one
/// with the default options, one with `other`.
std::pair<CaptureFitter, CaptureFitter> twoFitters(const JointModelParams& truth, double hz,
                                                   uint64_t seed, const FitOptions& other,
                                                   int rig_substeps = kContinuousRig) {
  SyntheticCaptureOptions o;
  o.truth = truth;
  o.frequency_hz = hz;
  o.seed = seed;
  o.rig_substeps = rig_substeps;
  const SyntheticCapture cap = synthesizeCapture(o);
  std::pair<CaptureFitter, CaptureFitter> f{CaptureFitter(cap.geometry),
                                            CaptureFitter(cap.geometry, other)};
  for (const auto& s : cap.samples) {
    f.first.add(s, true);
    f.second.add(s, true);
  }
  return f;
}

/// The turns at the range ends are read with the narrow window (FitOptions::turn_outlier):
/// random patient 10 at 6 Hz (seed 1; no spasm, a 6.1° flexion zone) bounces off its flexion
/// walls at 1,000-5,000 rad/s² within 5-10 ms, which the ±5 ms second difference smears;
/// the curve absorbed the misread inertial force near rest, 0.34 N off. With the turns read
/// narrow it is within 0.3 N; only the turns are read so (a few per cent of the samples).
/// On a record stepped once a sample (kSteppedRig): the continuous record turns less hard
/// and fits within 0.3 N either way (0.13 N narrow, 0.20 N wide, measured).
TEST(CaptureFitTruth, TurnsAtTheRangeEndsAreReadWithTheNarrowWindow) {
  const PatientCase pc = randomPatientCase(10);
  FitOptions wide_only;
  wide_only.turn_outlier = 0.0;
  const auto [with, without] = fitBothWays(pc.model, 1, wide_only, kSteppedRig);
  expectWithin(pc.model, with, "random-10 6 Hz, turns narrow", 0.3, 0.5);
  EXPECT_GT(without.check[kFlexion].inner_n, with.check[kFlexion].inner_n + 0.1)
      << "the wide window alone: the turns' inertial force bends the curve";

  const auto [a, b] = twoFitters(pc.model, 6.0, 1, wide_only, kSteppedRig);
  const auto acc = a.accelerations(), wide = b.accelerations();
  ASSERT_EQ(acc.size(), wide.size());
  std::size_t changed = 0;
  for (std::size_t i = 0; i < acc.size(); ++i) changed += acc[i][kFlexion] != wide[i][kFlexion];
  EXPECT_GT(changed, 0u);
  EXPECT_LT(changed, acc.size() / 20) << "only the turns";
}

/// The turns' rates are read narrow too (FitOptions::turn_rate_half_window): the shipped
/// spasm case at 6 Hz, seed 45, reaches 72.4° of flexion; the ±4 ms quadratic reads the
/// upper turn's rate low where the damping sits at the cap, and the fit took the missing
/// damping force for a wall one degree inside the end reached, 0.92 N off. Over ±2 ms at
/// the turns it is within, and only the turns' rates change. On a record stepped once a
/// sample (kSteppedRig); from the continuous record both are within (0.14 N, measured). With
/// only the saturated samples left out (FitOptions::saturation_margin 0), the fit this was
/// found with: leaving out the samples near the ceiling as well keeps that wall out too
/// (0.17 N with the wide window alone).
TEST(CaptureFitTruth, TurnsRatesAreReadWithTheNarrowWindow) {
  const JointModelParams truth = shippedCase("spasm");
  FitOptions narrow_rates;
  // The turns weighed as every other sample: the weights (TurnsWeighLess...) also keep this
  // wall out.
  narrow_rates.weigh_turns = false;
  narrow_rates.saturation_margin = 0.0;
  FitOptions wide_rates = narrow_rates;
  wide_rates.turn_rate_half_window = 0;
  const CaseRun with = runCase(truth, 6.0, 45, kPaperNoiseN, true, narrow_rates, kSteppedRig);
  const CaseRun without = runCase(truth, 6.0, 45, kPaperNoiseN, true, wide_rates, kSteppedRig);
  expectWithin(truth, with, "spasm 6 Hz seed 45, turns' rates narrow", 0.3, 0.5);
  EXPECT_GT(without.check[kFlexion].inner_n, 0.5)
      << "the wide window alone: a false wall inside the range reached";

  const auto [a, b] = twoFitters(truth, 6.0, 45, wide_rates, kSteppedRig);
  const auto rate = a.rates(), wide = b.rates();
  const auto turn = a.turns();
  ASSERT_EQ(rate.size(), wide.size());
  ASSERT_EQ(turn.size(), rate.size());
  std::size_t changed = 0, off_turn = 0;
  for (std::size_t i = 0; i < rate.size(); ++i) {
    const bool differs = rate[i][kFlexion] != wide[i][kFlexion];
    changed += differs;
    off_turn += differs && !turn[i][kFlexion];
  }
  EXPECT_GT(changed, 0u);
  EXPECT_EQ(off_turn, 0u) << "only the turns";
  EXPECT_LT(changed, rate.size() / 20);
}

/// A shape whose zone reaches both walls leaves the cubic held by a sliver of samples: its
/// normal matrix is nearly singular and its residual, read off the normal equations, is
/// numerically meaningless. Random patient 199 at 6 Hz, seed 10, captured for 15 s an axis:
/// its flexion fit with the spasm went to a 24° zone between walls at the zone's edges, a
/// gain of 8 s/rad, a residual read as 0.96 N RMS (the noise alone is 1.43 N; 2.13 N as it
/// is) and a curve 3,369 N off the truth. With the nearly singular trials refused
/// (fitPiecewiseCubic) it fits as the plain fit does.
TEST(CaptureFitTruth, ANearlySingularShapeIsNotTakenForTheBest) {
  const PatientCase pc = randomPatientCase(199);
  SyntheticCaptureOptions o;
  o.truth = pc.model;
  o.frequency_hz = 6.0;
  o.seed = 10;
  o.seconds_per_axis = 15.0;
  const SyntheticCapture cap = synthesizeCapture(o);
  CaptureFitter fitter(cap.geometry);
  for (const auto& smp : cap.samples) fitter.add(smp, true);
  const CaptureFit fit = fitter.fit();
  ASSERT_TRUE(fit.ok());
  const auto check = compareWithTruth(pc.model, fit.model(pc.model), o.max_force_n, &fit);
  const AxisFit& a = fit.axes[kFlexion];
  EXPECT_LT(check[kFlexion].inner_n, 0.3);
  EXPECT_LT(a.zone_deg, 10.0);
  EXPECT_LT(a.rms_n, 1.5);
  EXPECT_GT(a.curve.max_deg - a.curve.min_deg, 60.0) << "walls at the range reached";
}

/// The turns' samples weigh by how well their inertial force is known
/// (FitOptions::weigh_turns). Random patient 173 at 6 Hz, seed 10 (a spasm of 1.7 s/rad):
/// counted as every other sample, the turns' misread inertial force took the reflex's gain
/// down to 0.42-0.53 s/rad and bent the axial curve 0.5 N off the truth (an upper wall at
/// 5.1 deg inside the 14.5 reached, before walls had to explain their force); weighed, the
/// axis is within. And the shipped spasm case's false wall at 6 Hz, seed 45, which the
/// narrow rates keep out, stays out with the wide rates too. On a record stepped once a
/// sample (kSteppedRig); from the continuous record counted alike the axial axis is 0.32 N
/// off, weighed 0.24 N (measured). Each axis with its own gain (FitOptions::one_speed_gain
/// false), as when this was built: at the joint's gain (flexion's) the axial axis is within
/// counted alike too (0.09 N, measured).
TEST(CaptureFitTruth, TurnsWeighLessByHowWellTheirInertialForceIsKnown) {
  const PatientCase pc = randomPatientCase(173);
  ASSERT_GT(pc.model.speed_gain_s_per_rad, 1.0);
  FitOptions own;
  own.one_speed_gain = false;
  FitOptions alike = own;
  alike.weigh_turns = false;
  const CaseRun weighed = runCase(pc.model, 6.0, 10, kPaperNoiseN, true, own, kSteppedRig);
  const CaseRun counted = runCase(pc.model, 6.0, 10, kPaperNoiseN, true, alike, kSteppedRig);
  expectWithin(pc.model, weighed, "random-173 6 Hz seed 10", 0.3, 0.5);
  EXPECT_GT(counted.check[kAxial].inner_n, 0.4) << "the turns counted alike";

  const JointModelParams spasm = shippedCase("spasm");
  FitOptions wide_rates;
  wide_rates.turn_rate_half_window = 0;
  const CaseRun wide = runCase(spasm, 6.0, 45, kPaperNoiseN, true, wide_rates, kSteppedRig);
  expectWithin(spasm, wide, "spasm 6 Hz seed 45, turns' rates wide, weighed", 0.3, 0.5);
}

/// A wall must explain a share of the force it adds beyond it (FitOptions::min_wall_share).
/// Random patient 197 at 6 Hz, seed 10: the sweep reached 11.1 deg on the axial axis (the
/// truth's range runs to 17.6), and a wall at 3.2 deg, with 8 deg of samples beyond it,
/// paid for itself by a few times the noise while explaining 0.2 % of its force; the zone's
/// edge was 0.62 N off (with the joint's gain reached in steps: a wall at 2.8 deg, 0.27 N
/// off, against 0.11 N without the wall; with the samples near the FSRs' ceiling left out, a
/// wall at 2.8 deg, 0.26 N with the edges, against 0.20 N). The truth's walls explain 1-60 %
/// (the shipped stiff case's axial walls, reached 2-3 deg deep, about 1 %).
TEST(CaptureFitTruth, AWallMustExplainTheForceItAdds) {
  const PatientCase pc = randomPatientCase(197);
  FitOptions any_wall;
  any_wall.min_wall_share = 0.0;
  const auto [shared, paid] = fitBothWays(pc.model, 10, any_wall);
  expectWithin(pc.model, shared, "random-197 6 Hz seed 10", 0.3, 0.5);
  EXPECT_FALSE(shared.fit.axes[kAxial].wall_max) << "the sweep did not reach the truth's wall";
  ASSERT_TRUE(paid.fit.axes[kAxial].wall_max);
  EXPECT_LT(paid.fit.axes[kAxial].curve.max_deg, 5.0) << "a wall far inside the range reached";
  std::printf("axial with any wall: wall at %.1f deg, %.3f N with the edges; without: %.3f N\n",
              paid.fit.axes[kAxial].curve.max_deg, paid.check[kAxial].edges_n,
              shared.check[kAxial].edges_n);
  EXPECT_GT(paid.check[kAxial].edges_n, shared.check[kAxial].edges_n);
  // Real walls reached only a few degrees deep are kept (stiff: axial walls at -5 and 8 deg).
  const JointModelParams stiff = shippedCase("stiff");
  const CaseRun s = runCase(stiff, 3.0, 13);
  EXPECT_TRUE(s.fit.axes[kAxial].wall_min && s.fit.axes[kAxial].wall_max);
  EXPECT_NEAR(s.fit.axes[kAxial].curve.min_deg, stiff.axes[kAxial].min_deg, 0.5);
  EXPECT_NEAR(s.fit.axes[kAxial].curve.max_deg, stiff.axes[kAxial].max_deg, 0.5);
}

/// A reflex can hide a zone the plain fit does not see: random patient 7 at 6 Hz (an 8.9°
/// flexion zone, a soft curve beyond it, 3.0 s/rad) ended with no zone at 7.9-9.5 s/rad and
/// the curve 0.6 N low over its middle. The profiled start settles the shape at each gain of
/// its scan and finds the zone (0.23 N, gain 1.9 s/rad).
TEST(CaptureFitTruth, AReflexDoesNotHideTheNeutralZone) {
  const PatientCase pc = randomPatientCase(7);
  const double truth_zone = pc.model.neutral_zone_deg[kFlexion];
  ASSERT_GT(truth_zone, 5.0);
  ASSERT_GT(pc.model.speed_gain_s_per_rad, 1.0);
  const CaseRun r = runCase(pc.model, 6.0, 3, kPaperNoiseN, true);
  expectWithin(pc.model, r, "random-7 6 Hz", 0.3, 0.5);
  const AxisFit& f = r.fit.axes[kFlexion];
  EXPECT_TRUE(f.spasm);
  EXPECT_GT(f.zone_deg, 0.6 * truth_zone) << "the zone kept";
  EXPECT_LT(f.speed_gain_s_per_rad, 2.0 * pc.model.speed_gain_s_per_rad);
}

/// The joint model renders one speed gain; the joint's is the estimate of the axis whose
/// capture shows the spasm most (CaptureFit::speedGain: the largest drop in residual the
/// term brings), not the axes' estimates weighted by their standard errors, which the axes
/// swept over less of the reflex hold too tight (random patient 184 at 6 Hz, seed 10,
/// 2.86 s/rad: 2.82 ± 0.15, 1.10 ± 0.05 and 0.83 ± 0.04 s/rad, weighted 1.03). An axis
/// that found no spasm does not count, whatever its estimate.
TEST(CaptureFit, TheJointsGainIsTheAxisWhereTheSpasmShowsMost) {
  CaptureFit f;
  EXPECT_EQ(f.speedGain(), 0.0);
  auto set = [&](std::size_t axis, bool spasm, double gain, double se, double evidence) {
    AxisFit& a = f.axes[axis];
    a.ok = true;
    a.spasm = spasm;
    a.speed_gain_s_per_rad = spasm ? gain : 0.0;
    a.speed_gain_fitted_s_per_rad = gain;
    a.speed_gain_se_s_per_rad = se;
    a.spasm_evidence_n2 = spasm ? evidence : 0.0;
  };
  set(kFlexion, true, 2.82, 0.15, 12'000.0);
  set(kAbduction, true, 1.10, 0.045, 9'900.0);
  set(kAxial, true, 0.83, 0.042, 4'500.0);
  EXPECT_DOUBLE_EQ(f.speedGain(), 2.82);
  EXPECT_DOUBLE_EQ(f.model(JointModelParams{}).speed_gain_s_per_rad, 2.82);
  set(kAxial, true, 0.83, 0.042, 15'000.0);
  EXPECT_DOUBLE_EQ(f.speedGain(), 0.83);
  set(kAxial, false, 5.0, 0.001, 15'000.0);
  EXPECT_DOUBLE_EQ(f.speedGain(), 2.82) << "an axis without spasm does not count";
  set(kFlexion, false, 2.82, 0.15, 0.0);
  set(kAbduction, false, 1.10, 0.045, 0.0);
  EXPECT_EQ(f.speedGain(), 0.0);
  f.axes[kAbduction].ok = false;
  set(kFlexion, true, 25.0, 1.0, 100.0);
  EXPECT_DOUBLE_EQ(f.speedGain(), 20.0) << "the case files' bound";
}

/// Every axis fitted with the joint's gain (FitOptions::one_speed_gain), the one the model
/// renders on all three: random patient 41 at 6 Hz (seed 5, 2.26 s/rad) read 1.5 s/rad on
/// flexion and 0.23 on axial, whose curve, fitted with its own, came out 0.34 N off; with
/// the joint's, 0.11 N.
TEST(CaptureFitTruth, EveryAxisIsFittedWithTheJointsGain) {
  const PatientCase pc = randomPatientCase(41);
  const CaseRun r = runCase(pc.model, 6.0, 5, kPaperNoiseN, true);
  expectWithin(pc.model, r, "random-41 6 Hz seed 5", 0.3, 0.5);
  const double g = r.fit.speedGain();
  EXPECT_GT(g, 0.5 * pc.model.speed_gain_s_per_rad);
  for (const AxisFit& a : r.fit.axes) {
    EXPECT_TRUE(a.spasm);
    EXPECT_DOUBLE_EQ(a.speed_gain_s_per_rad, g);
  }
  FitOptions own;
  own.one_speed_gain = false;
  const CaseRun o = runCase(pc.model, 6.0, 5, kPaperNoiseN, true, own);
  std::printf("axial with its own gain %.2f s/rad: %.3f N; with the joint's %.2f: %.3f N\n",
              o.fit.axes[kAxial].speed_gain_s_per_rad, o.check[kAxial].inner_n, g,
              r.check[kAxial].inner_n);
  EXPECT_DOUBLE_EQ(o.fit.speedGain(), g) << "the joint's gain is the same either way";
  EXPECT_LT(o.fit.axes[kAxial].speed_gain_s_per_rad, 0.5 * g);
  EXPECT_GT(o.check[kAxial].inner_n, r.check[kAxial].inner_n + 0.1);
}

/// ...except where the joint's gain would take a zone or wall the axis' own fit found: a
/// zone and a strong reflex trade against each other near the zone's edges, and random
/// patient 184's axial axis at 6 Hz (seed 10; a 3.7 deg zone, 2.86 s/rad) lost its zone at
/// flexion's 2.82 s/rad and came out 0.73 N off; with its own 0.83 it keeps the zone. That
/// was the fit with only the saturated samples left out (FitOptions::saturation_margin 0),
/// and the keeping is checked there; with the samples near the ceiling left out too, flexion
/// reads 2.30 s/rad and the axial axis keeps its zone at that gain.
TEST(CaptureFitTruth, AnAxisKeepsTheZoneItsOwnFitFound) {
  const PatientCase pc = randomPatientCase(184);
  const CaseRun r = runCase(pc.model, 6.0, 10, kPaperNoiseN, true);
  expectWithin(pc.model, r, "random-184 6 Hz seed 10", 0.3, 0.5);
  EXPECT_GT(r.fit.axes[kAxial].zone_deg, 0.6 * pc.model.neutral_zone_deg[kAxial]);
  EXPECT_NEAR(r.fit.speedGain(), pc.model.speed_gain_s_per_rad,
              0.25 * pc.model.speed_gain_s_per_rad);
  FitOptions only_saturated;
  only_saturated.saturation_margin = 0.0;
  const CaseRun s = runCase(pc.model, 6.0, 10, kPaperNoiseN, true, only_saturated);
  expectWithin(pc.model, s, "random-184, only the saturated out", 0.3, 0.5);
  const AxisFit& axial = s.fit.axes[kAxial];
  EXPECT_GT(axial.zone_deg, 0.6 * pc.model.neutral_zone_deg[kAxial]);
  EXPECT_LT(axial.speed_gain_s_per_rad, 0.5 * s.fit.speedGain()) << "its own gain";
}

/// An axis reaches the joint's gain from its own in steps, its walls and zone settled at each
/// (FitOptions::joint_gain_steps): random patient 193's axial axis at 6 Hz (seed 2; a
/// 2.3 deg zone, 1.48 s/rad) read 0.50 s/rad itself and flexion's 1.66 for the joint; settled
/// there in one step its zone came out 2.8 deg wide and the curve 0.50 N off, stepped there
/// it keeps the truth's zone within 0.3 N, at a lower residual at the same gain. That was the
/// fit with only the saturated samples left out (FitOptions::saturation_margin 0), and the
/// steps are checked there; with the samples near the ceiling left out too, flexion reads
/// 1.48 s/rad and one step finds the zone as well (2.47 deg, 0.09 N).
TEST(CaptureFitTruth, AnAxisReachesTheJointsGainInSteps) {
  const PatientCase pc = randomPatientCase(193);
  expectWithin(pc.model, runCase(pc.model, 6.0, 2, kPaperNoiseN, true), "random-193 6 Hz seed 2",
               0.3, 0.5);
  FitOptions stepped;
  stepped.saturation_margin = 0.0;
  FitOptions direct = stepped;
  direct.joint_gain_steps = 0;
  const CaseRun r = runCase(pc.model, 6.0, 2, kPaperNoiseN, true, stepped);
  expectWithin(pc.model, r, "random-193, only the saturated out", 0.3, 0.5);
  const CaseRun o = runCase(pc.model, 6.0, 2, kPaperNoiseN, true, direct);
  const AxisFit &a = r.fit.axes[kAxial], &b = o.fit.axes[kAxial];
  std::printf(
      "axial at the joint's %.2f s/rad: in steps zone %.2f deg, %.3f N, RMS %.4f N; "
      "in one zone %.2f deg, %.3f N, RMS %.4f N\n",
      r.fit.speedGain(), a.zone_deg, r.check[kAxial].inner_n, a.rms_n, b.zone_deg,
      o.check[kAxial].inner_n, b.rms_n);
  EXPECT_DOUBLE_EQ(o.fit.speedGain(), r.fit.speedGain()) << "the joint's gain either way";
  EXPECT_DOUBLE_EQ(a.speed_gain_s_per_rad, r.fit.speedGain());
  EXPECT_DOUBLE_EQ(b.speed_gain_s_per_rad, r.fit.speedGain());
  EXPECT_NEAR(a.zone_deg, pc.model.neutral_zone_deg[kAxial], 0.3);
  EXPECT_GT(b.zone_deg, pc.model.neutral_zone_deg[kAxial] + 0.3);
  EXPECT_GT(o.check[kAxial].inner_n, r.check[kAxial].inner_n + 0.2);
  EXPECT_LT(a.rms_n, b.rms_n);
}

/// A sensor's ceiling does not bend the spasm's reading (FitOptions::saturation_margin):
/// random patient 80 at 6 Hz (seed 7; 1.80 s/rad) runs the pad sensors into their 22 N on
/// the stretches at speed. With only the saturated samples left out, those whose noise
/// pushed the reading down stay, and the gain read 2.17 s/rad, the axial curve 0.33 N off
/// at it; left out by their neighbours' readings the gain is within 10 % and every axis
/// within the bounds.
TEST(CaptureFitTruth, ASensorsCeilingDoesNotBendTheSpasm) {
  const PatientCase pc = randomPatientCase(80);
  const double truth = pc.model.speed_gain_s_per_rad;
  const CaseRun r = runCase(pc.model, 6.0, 7, kPaperNoiseN, true);
  expectWithin(pc.model, r, "random-80 6 Hz seed 7", 0.3, 0.5);
  FitOptions only_saturated;
  only_saturated.saturation_margin = 0.0;
  const CaseRun o = runCase(pc.model, 6.0, 7, kPaperNoiseN, true, only_saturated);
  std::printf(
      "gain %.3f s/rad (truth %.3f), %llu samples near the ceiling left out; with only the "
      "%llu saturated left out %.3f s/rad, axial %.3f N\n",
      r.fit.speedGain(), truth, static_cast<unsigned long long>(r.fit.counts.near_saturation),
      static_cast<unsigned long long>(o.fit.counts.fsr_fault), o.fit.speedGain(),
      o.check[kAxial].inner_n);
  EXPECT_GT(r.fit.counts.fsr_fault, 100u) << "the capture saturates the sensors";
  EXPECT_GT(r.fit.counts.near_saturation, r.fit.counts.fsr_fault);
  EXPECT_EQ(o.fit.counts.near_saturation, 0u);
  EXPECT_NEAR(r.fit.speedGain(), truth, 0.1 * truth);
  EXPECT_GT(o.fit.speedGain(), 1.15 * truth) << "the truncation reads the reflex high";
  EXPECT_GT(o.check[kAxial].inner_n, r.check[kAxial].inner_n);
}

/// Random patients with a spasm whose first fit kept it: choosing the lag again (with the
/// spasm in) and fitting at that lag must not leave the capture explained worse. Searched
/// anew from the first fit, the shape and gain could end in a poorer optimum where the
/// spasm no longer pays for itself and was dropped: random patient 25 at 3 Hz (seed 2)
/// came out 1.43 N off on its axial axis, random patient 32 at 2 Hz (seed 4) 0.70 N, each
/// with 1.45-1.48 N RMS residual against the 1.43 N noise. The fit now starts afresh when
/// the earlier start does not pay, and keeps the first lag's fits when the new lag's explain
/// the capture worse. Patients 40 and 41 (spasms of their own, not looked at while making the
/// change) at 2 and 4 Hz hold the same limits.
struct PatientRun {
  uint64_t patient;
  double hz;
  uint64_t seed;
};

std::string describe(const PatientRun& run) {
  return "random-" + std::to_string(run.patient) + " " + std::to_string(run.hz).substr(0, 3) +
         " Hz seed " + std::to_string(run.seed);
}

void PrintTo(const PatientRun& r, std::ostream* os) { *os << describe(r); }

class SpasmIsNotLostWhenTheLagIsChosenAgain : public ::testing::TestWithParam<PatientRun> {};

TEST_P(SpasmIsNotLostWhenTheLagIsChosenAgain, FitsWithinTheBoundsAndExplainsTheCapture) {
  const PatientRun& run = GetParam();
  const PatientCase pc = randomPatientCase(run.patient);
  const std::string what = describe(run);
  ASSERT_GT(pc.model.speed_gain_s_per_rad, 0.0) << what;
  const CaseRun r = runCase(pc.model, run.hz, run.seed, kPaperNoiseN, true);
  expectWithin(pc.model, r, what, 0.3, 0.5);
  for (std::size_t i = 0; i < kAxes; ++i)
    EXPECT_LT(r.fit.axes[i].rms_n, 1.45) << what << " " << kAxisNames[i];
}

// One ctest entry per patient and rate.
INSTANTIATE_TEST_SUITE_P(CaptureFitTruth, SpasmIsNotLostWhenTheLagIsChosenAgain,
                         ::testing::Values(PatientRun{25, 3.0, 2}, PatientRun{32, 2.0, 4},
                                           PatientRun{41, 2.0, 6}, PatientRun{41, 4.0, 6},
                                           PatientRun{40, 2.0, 6}, PatientRun{40, 4.0, 6}),
                         [](const ::testing::TestParamInfo<PatientRun>& i) {
                           return "random" + std::to_string(i.param.patient) + "_" +
                                  hzName(i.param.hz) + "_seed" + std::to_string(i.param.seed);
                         });

/// The force channel's lag is chosen with each axis' walls and zone searched at every lag
/// (FitOptions::lag_with_shape): a plain cubic misreads the kinks where the stiffness
/// changes, and random patient 10 at 3 Hz (seed 1; no spasm, a 6.1 deg flexion zone, the
/// truth's lag one sample) came out at a lag of 0 and 0.39 N off on flexion, 0.15 N with the
/// shape in.
/// The record stepped once a sample (kSteppedRig), whose force lags its angle by a sample;
/// the continuous record's lag is 0.1 sample, and the fit reads 0 there.
TEST(CaptureFitTruth, LagIsChosenWithTheShape) {
  const PatientCase pc = randomPatientCase(10);
  const CaseRun r = runCase(pc.model, 3.0, 1, kPaperNoiseN, true, {}, kSteppedRig);
  expectWithin(pc.model, r, "random-10 3 Hz seed 1", 0.3, 0.5);
  EXPECT_NEAR(r.fit.delay_samples, 1.0, 0.3);
  FitOptions plain;
  plain.lag_with_shape = false;
  const CaseRun p = runCase(pc.model, 3.0, 1, kPaperNoiseN, true, plain, kSteppedRig);
  std::printf("lag with the shape %.2f, with a plain cubic %.2f samples (truth 1)\n",
              r.fit.delay_samples, p.fit.delay_samples);
  EXPECT_LT(p.fit.delay_samples, 0.5);
  EXPECT_GT(p.check[kFlexion].inner_n, r.check[kFlexion].inner_n + 0.1);
}

/// Neutral zones and walls the search used to lose. A zone and a reflex steep near rest trade
/// against each other (inside a zone the elastic force, and with it the reflex, is zero), and
/// the gain scanned with the plain fit's shape held, then refined with the shape searched
/// again, ended where the reflex had taken the zone, though the truth's shape explains the
/// capture better: random patient 2 at 2 Hz (seed 2) lost its 9.3 deg flexion zone to a gain
/// of 7.0 s/rad (truth 3.0), 0.84 N off; random patient 1 at 3 Hz (seed 2) its 4.6 deg
/// abduction zone to 3.2 (truth 1.23), 0.38 N off. And the walls searched before the zone
/// ended short: random patient 24's axial axis at 1 Hz (seed 3), a wall at 5.6 deg for
/// 10.7, the lower one and the 3.9 deg zone missed, 1.04 N off.
TEST(CaptureFitTruth, ZonesAndWallsAreNotLostToTheSearch) {
  struct Run {
    uint64_t patient;
    double hz;
    uint64_t seed;
    int axis;
  };
  for (const Run& run :
       {Run{2, 2.0, 2, kFlexion}, Run{1, 3.0, 2, kAbduction}, Run{24, 1.0, 3, kAxial}}) {
    const PatientCase pc = randomPatientCase(run.patient);
    const std::string what = "random-" + std::to_string(run.patient) + " " +
                             std::to_string(run.hz).substr(0, 3) + " Hz seed " +
                             std::to_string(run.seed);
    const auto ax = static_cast<std::size_t>(run.axis);
    ASSERT_GT(pc.model.neutral_zone_deg[ax], 3.0) << what;
    const CaseRun r = runCase(pc.model, run.hz, run.seed, kPaperNoiseN, true);
    expectWithin(pc.model, r, what, 0.3, 0.5);
    EXPECT_NEAR(r.fit.axes[ax].zone_deg, pc.model.neutral_zone_deg[ax], 1.0) << what;
  }
}

/// A fast capture leans on the dynamic terms, a slow one hardly: the fit reports how much.
TEST(CaptureFitTruth, DynamicTermsAreReported) {
  const JointModelParams truth = shippedCase("healthy");
  const CaseRun slow = runCase(truth, 0.5, 5), fast = runCase(truth, 3.0, 5);
  EXPECT_LT(slow.fit.axes[kFlexion].dynamic_n, 0.3);
  EXPECT_GT(fast.fit.axes[kFlexion].dynamic_n, 0.5);
  // The moving mass: the phalanx (2.1e-5 kg·m²) and the grip's 0.05 kg at 1 cm (0.5e-5).
  // A sweep does not excite it apart from the stiffness: the known value is used, the free
  // estimate reported beside it.
  for (const auto& a : fast.fit.axes) {
    EXPECT_FALSE(a.inertia_estimated);
    EXPECT_DOUBLE_EQ(a.inertia_kgm2, FitOptions{}.inertia_kgm2);
    EXPECT_GT(a.inertia_collinearity, FitOptions{}.max_inertia_collinearity);
  }
  EXPECT_NEAR(fast.fit.axes[kFlexion].inertia_fitted_kgm2, 2.6e-5, 1.5e-5);
}

/// Which inertia a fit uses follows the options: estimated past any correlation when
/// allowed, else the known value given.
TEST(CaptureFitTruth, InertiaChoiceFollowsTheOptions) {
  const JointModelParams truth = shippedCase("healthy");
  SyntheticCaptureOptions o;
  o.truth = truth;
  o.frequency_hz = 3.0;
  o.seed = 9;
  const SyntheticCapture cap = synthesizeCapture(o);
  CaptureFitter ref(cap.geometry);
  for (const auto& s : cap.samples) ref.add(s, true);
  FitOptions always;
  always.max_inertia_collinearity = 2.0;  // any correlation
  always.max_inertia_rel_se = 1e9;
  CaptureFitter est(cap.geometry, always);
  for (const auto& s : cap.samples) est.add(s, true);
  const CaptureFit a = ref.fit(), b = est.fit();
  for (std::size_t i = 0; i < kAxes; ++i) {
    EXPECT_FALSE(a.axes[i].inertia_estimated);
    EXPECT_TRUE(b.axes[i].inertia_estimated);
    EXPECT_DOUBLE_EQ(b.axes[i].inertia_kgm2, b.axes[i].inertia_fitted_kgm2);
    EXPECT_GT(b.axes[i].inertia_se_kgm2, 0.0);
  }
  FitOptions never;
  never.max_inertia_collinearity = 0.0;
  never.inertia_kgm2 = 3.0e-5;
  CaptureFitter known(cap.geometry, never);
  for (const auto& s : cap.samples) known.add(s, true);
  EXPECT_DOUBLE_EQ(known.fit().axes[kFlexion].inertia_kgm2, 3.0e-5);
}

/// Every curve the live refit publishes rises over its range and holds a joint's force, while
/// a noisy fast capture arrives chunk by chunk.
class LiveRefitTruth : public ::testing::TestWithParam<const char*> {};

TEST_P(LiveRefitTruth, NeverPublishesAFallingCurve) {
  const char* name = GetParam();
  SyntheticCaptureOptions o;
  o.truth = shippedCase(name);
  o.frequency_hz = 3.0;
  o.seed = 21;
  // 6 s per axis, each swept to its range ends (the default 10 s costs twice the time,
  // every refit fitting the whole capture so far).
  o.seconds_per_axis = 6.0;
  const SyntheticCapture cap = synthesizeCapture(o);
  // Refits at fixed steps of the capture's time, whatever they cost on this machine: every
  // 3 s of it, 6 of them (a fit of lax at 3 Hz takes 4-5 s for 30 s of capture, the walls and
  // zone searched from two starts; every 1.5 s took 46 s alone).
  LiveRefitOptions lo;
  lo.max_busy_fraction = 0.0;
  lo.min_interval_ns = 3 * kNsPerS;
  LiveRefit live(cap.geometry, o.truth, lo);
  int64_t now = 0;
  int published = 0;
  double last_gain = 0.0;
  for (std::size_t i = 0; i < cap.samples.size(); ++i) {
    live.add(cap.samples[i], true, now);
    if (i % 100 != 99) continue;
    now += 100 * kNsPerMs;
    const auto u = live.poll(now);
    if (!u) continue;
    ++published;
    last_gain = u->params.speed_gain_s_per_rad;
    const JointModel m(u->params);
    for (int ax = 0; ax < kAxes; ++ax) {
      const CubicCurve& c = u->params.axes[static_cast<std::size_t>(ax)];
      EXPECT_TRUE(risesOverRange(c)) << name << " " << kAxisNames[static_cast<std::size_t>(ax)];
      // ...so that a client takes it: what fromWire holds a JointModel's curves to.
      const auto problem = passiveCurveProblem(c);
      EXPECT_FALSE(problem.has_value())
          << name << " " << kAxisNames[static_cast<std::size_t>(ax)] << ": " << *problem;
      double last = -1e9;
      for (double d = c.min_deg - 3.0; d <= c.max_deg + 3.0; d += 0.1) {
        const double f = m.holdingForceN(ax, degToRad(d));
        EXPECT_GE(f, last - 1e-9) << name << " at " << d;
        last = f;
      }
    }
  }
  std::printf("%s: %d refits published\n", name, published);
  EXPECT_GT(published, 2) << name;
  // The spasm reaches followers too (truth 1.5 s/rad).
  if (std::string(name) == "spasm") {
    EXPECT_NEAR(last_gain, 1.5, 0.5);
  }
}

// One ctest entry per case: a free neutral zone, and a spasm.
INSTANTIATE_TEST_SUITE_P(Cases, LiveRefitTruth, ::testing::Values("lax", "spasm"),
                         [](const ::testing::TestParamInfo<const char*>& i) {
                           return std::string(i.param);
                         });

}  // namespace
}  // namespace telehand::server::estimate
