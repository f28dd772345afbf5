// The simulated MF-2 whose virtual operator performs the circular massage of the web: alone,
// in a closed loop with the tissue proxy (healthy, hypertonic, oedema), and in a capture of
// a real web with the actuators off.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <vector>

#include "alloc_guard.h"  // replaces operator new: this executable only
#include "massage_trial.h"
#include "telehand/core/clock.h"
#include "telehand/core/thimble.h"
#include "telehand/core/tissue_model.h"
#include "telehand/devices/simulated_massage_mf2.h"

namespace telehand {
namespace {

using devices::DeviceSample;
using devices::ForceCommand;
using devices::SimulatedMassageMf2;
using test::MassageTrial;
using test::MassageTrialOptions;
using test::runMassageTrial;

constexpr double kSettleS = 1.0;

bool sameSample(const DeviceSample& a, const DeviceSample& b) {
  if (a.seq != b.seq || a.time_ns != b.time_ns) return false;
  for (int k = 0; k < 2; ++k) {
    const auto& fa = a.fingers[k];
    const auto& fb = b.fingers[k];
    if (fa.position_m != fb.position_m) return false;
    if (fa.orientation.coeffs() != fb.orientation.coeffs()) return false;
    if (std::memcmp(fa.fsr_n.data(), fb.fsr_n.data(), sizeof(fa.fsr_n)) != 0) return false;
  }
  return true;
}

/// The contact point's circle, measured here on its own (not with the scoring code): a
/// least-squares circle (Kasa) through the thimbles' midpoint in the web frame, and the
/// slope of its unwrapped angle around that centre.
struct Circle {
  double cx = 0, cy = 0, radius_m = 0, frequency_hz = 0;
};

Circle fitCircle(const std::vector<double>& t, const std::vector<Vec3>& pw) {
  Eigen::Matrix3d ata = Eigen::Matrix3d::Zero();
  Eigen::Vector3d atb = Eigen::Vector3d::Zero();
  for (const Vec3& p : pw) {
    const Eigen::Vector3d row(p.x(), p.y(), 1.0);
    ata += row * row.transpose();
    atb += row * (p.x() * p.x() + p.y() * p.y());
  }
  const Eigen::Vector3d sol = ata.ldlt().solve(atb);
  Circle c;
  c.cx = 0.5 * sol[0];
  c.cy = 0.5 * sol[1];
  c.radius_m = std::sqrt(sol[2] + c.cx * c.cx + c.cy * c.cy);
  double prev = 0.0, unwrapped = 0.0;
  double st = 0, sa = 0, stt = 0, sta = 0;
  for (std::size_t i = 0; i < pw.size(); ++i) {
    const double a = std::atan2(pw[i].y() - c.cy, pw[i].x() - c.cx);
    if (i > 0) unwrapped += std::remainder(a - prev, 2.0 * kPi);
    prev = a;
    st += t[i];
    sa += unwrapped;
    stt += t[i] * t[i];
    sta += t[i] * unwrapped;
  }
  const double n = static_cast<double>(pw.size());
  c.frequency_hz = (n * sta - st * sa) / (n * stt - st * st) / (2.0 * kPi);
  return c;
}

/// What a closed-loop trial did after the first second.
struct LoopFigures {
  PerFinger<double> in_band{};           ///< FSR normal / force_scale within 10 ± 2 N
  PerFinger<double> rendered_in_band{};  ///< rendered normal / force_scale within 10 ± 2 N
  PerFinger<double> mean_n{};            ///< FSR normal / force_scale
  double max_device_n = 0;               ///< largest rendered force on a thimble (whole trial)
  Circle circle;
};

LoopFigures measure(const MassageTrial& trial, const TissueParams& web, double force_scale) {
  const TissueModel m(web);
  LoopFigures f;
  std::vector<double> t;
  std::vector<Vec3> pw;
  PerFinger<int> ok{}, rok{};
  PerFinger<double> sum{};
  const int64_t t0 = trial.samples.front().source_time_ns - kNsPerMs;
  for (std::size_t i = 0; i < trial.samples.size(); ++i) {
    const Sample& s = trial.samples[i];
    for (int k = 0; k < 2; ++k)
      f.max_device_n = std::max(f.max_device_n, trial.rendered[i][k].norm());
    const double ts = static_cast<double>(s.source_time_ns - t0) * 1e-9;
    if (ts < kSettleS) continue;
    t.push_back(ts);
    const PerFinger<Vec3> p = thimblePositions(s);
    pw.push_back(m.toWeb(0.5 * (p[kThumb] + p[kIndex])));
    for (int k = 0; k < 2; ++k) {
      const double applied = s.fingers[k].normal_n / force_scale;
      // The web pushes the thumb toward +z, the index toward −z.
      const double rendered =
          (k == kThumb ? 1.0 : -1.0) * trial.rendered[i][k].dot(m.normalAxis()) / force_scale;
      ok[k] += std::abs(applied - 10.0) <= 2.0 ? 1 : 0;
      rok[k] += std::abs(rendered - 10.0) <= 2.0 ? 1 : 0;
      sum[k] += applied;
    }
  }
  const double n = static_cast<double>(t.size());
  for (int k = 0; k < 2; ++k) {
    f.in_band[k] = ok[k] / n;
    f.rendered_in_band[k] = rok[k] / n;
    f.mean_n[k] = sum[k] / n;
  }
  f.circle = fitCircle(t, pw);
  return f;
}

TEST(SimulatedMassage, SameSeedAndClockGiveIdenticalSamples) {
  const TissueParams web = tissueCase("healthy");
  OperatorConfig op;
  op.seed = 7;
  op.tremor_n = 0.5;
  ManualClock clock_a(5 * kNsPerS), clock_b(5 * kNsPerS);
  SimulatedMassageMf2 a(web, op, clock_a), b(web, op, clock_b);
  TissueProxy proxy_a(web, 0.25), proxy_b(web, 0.25);
  DeviceSample sa, sb;
  for (int i = 0; i < 3000; ++i) {
    clock_a.advance(kNsPerMs);
    clock_b.advance(kNsPerMs);
    ASSERT_TRUE(a.read(sa));
    ASSERT_TRUE(b.read(sb));
    ASSERT_TRUE(sameSample(sa, sb)) << "diverged at sample " << i;
    ForceCommand ca, cb;
    ca.force_n = proxy_a.render({sa.fingers[0].position_m, sa.fingers[1].position_m}, sa.time_ns)
                     .force_device_n;
    cb.force_n = proxy_b.render({sb.fingers[0].position_m, sb.fingers[1].position_m}, sb.time_ns)
                     .force_device_n;
    a.write(ca);
    b.write(cb);
  }
  EXPECT_EQ(sa.seq, 3000u);
  EXPECT_EQ(sa.time_ns, 5 * kNsPerS + 3000 * kNsPerMs);
  // Another seed: another wander, other noise.
  op.seed = 8;
  ManualClock clock_c(5 * kNsPerS);
  SimulatedMassageMf2 c(web, op, clock_c);
  EXPECT_NE(c.targetPressN(5.0), a.targetPressN(5.0));
}

TEST(SimulatedMassage, PlanAndSkillSetTheTargets) {
  const TissueParams web = tissueCase("healthy");
  ManualClock clock;
  const SimulatedMassageMf2 clinician(web, OperatorConfig{}, clock);
  EXPECT_DOUBLE_EQ(clinician.targetPressN(0.0), 0.0);  // builds up from nothing
  EXPECT_DOUBLE_EQ(clinician.targetRadiusM(), 0.006);
  EXPECT_DOUBLE_EQ(clinician.targetFrequencyHz(), 1.5);
  double sum = 0, sum2 = 0;
  int n = 0;
  for (double t = 1.0; t < 101.0; t += 0.01, ++n) {
    const double f = clinician.targetPressN(t);
    sum += f;
    sum2 += f * f;
  }
  const double mean = sum / n, rms = std::sqrt(sum2 / n - mean * mean);
  EXPECT_NEAR(mean, 10.0, 0.1);
  EXPECT_NEAR(rms, 0.7, 0.1);  // the plan's wander
  // The target point runs on the circle, a lap per 1/1.5 s once built up.
  const Vec3 a = clinician.targetPointW(2.0), b = clinician.targetPointW(2.0 + 1.0 / 1.5);
  EXPECT_NEAR(std::hypot(a.x(), a.y()), 0.006, 1e-12);
  EXPECT_NEAR((a - b).norm(), 0.0, 1e-9);
  // Counter-clockwise seen from the dorsal side: the angle grows.
  const Vec3 c = clinician.targetPointW(2.05);
  EXPECT_GT(a.x() * c.y() - a.y() * c.x(), 0.0);

  OperatorConfig student;
  student.force_bias_n = 2.0;
  student.frequency_error_hz = 0.5;
  student.amplitude_scale = 0.7;
  const SimulatedMassageMf2 s(web, student, clock);
  EXPECT_NEAR(s.targetPressN(5.0) - clinician.targetPressN(5.0), 2.0, 1e-12);
  EXPECT_DOUBLE_EQ(s.targetFrequencyHz(), 2.0);
  EXPECT_NEAR(s.targetRadiusM(), 0.0042, 1e-12);
}

TEST(SimulatedMassage, StepAllocatesNothing) {
  const TissueParams web = tissueCase("scar");
  OperatorConfig op;
  op.tremor_n = 0.5;
  ManualClock clock;
  SimulatedMassageMf2 dev(web, op, clock);
  dev.setForceNoise(1.43);
  TissueProxy proxy(web, 0.25);
  DeviceSample s;
  int ok = 0;
  test::AllocationGuard guard;
  for (int i = 0; i < 2000; ++i) {
    clock.advance(kNsPerMs);
    ok += dev.read(s) ? 1 : 0;
    ForceCommand cmd;
    cmd.force_n =
        proxy.render({s.fingers[0].position_m, s.fingers[1].position_m}, s.time_ns).force_device_n;
    dev.write(cmd);
  }
  EXPECT_EQ(guard.allocations(), 0u);
  EXPECT_EQ(ok, 2000);
}

struct LoopCase {
  const char* tissue;
  uint64_t seed;
};

class MassageClosedLoop : public ::testing::TestWithParam<LoopCase> {};

// 20 s of the clinician's massage in a closed loop with the tissue proxy: the press each
// finger applies (FSR normal / force_scale) and the force the device renders stay within
// 10 ± 2 N, the device never renders more than 4 N on a thimble, and the contact point's
// circle comes out at the plan's 6 mm and 1.5 Hz, round the web's centre.
TEST_P(MassageClosedLoop, HoldsThePressAndTheCircle) {
  MassageTrialOptions o;
  o.web = tissueCase(GetParam().tissue);
  o.op.seed = GetParam().seed;
  const MassageTrial trial = runMassageTrial(o);
  ASSERT_TRUE(trial.complete);
  const LoopFigures f = measure(trial, o.web, o.force_scale);
  std::printf(
      "%s seed %llu: in band %.3f/%.3f (rendered %.3f/%.3f), mean %.2f/%.2f N, max device "
      "%.2f N, radius %.3f mm, %.4f Hz, centre (%.2f, %.2f) mm\n",
      GetParam().tissue, static_cast<unsigned long long>(GetParam().seed), f.in_band[0],
      f.in_band[1], f.rendered_in_band[0], f.rendered_in_band[1], f.mean_n[0], f.mean_n[1],
      f.max_device_n, f.circle.radius_m * 1e3, f.circle.frequency_hz, f.circle.cx * 1e3,
      f.circle.cy * 1e3);
  for (int k = 0; k < 2; ++k) {
    EXPECT_GE(f.in_band[k], 0.9) << "finger " << k;
    EXPECT_GE(f.rendered_in_band[k], 0.9) << "finger " << k;
    EXPECT_NEAR(f.mean_n[k], 10.0, 0.3) << "finger " << k;
  }
  EXPECT_LE(f.max_device_n, 4.0);
  EXPECT_NEAR(f.circle.radius_m, 0.006, 0.05 * 0.006);
  EXPECT_NEAR(f.circle.frequency_hz, 1.5, 0.01);
  // Round the web's centre: oedema's looser skin (500 N/m, sticking up to 11 mm of stretch)
  // rarely slips and pulls the circle half a millimetre toward where the fingers first
  // touched it (the start point, +x).
  EXPECT_LT(std::hypot(f.circle.cx, f.circle.cy), 0.001);
}

INSTANTIATE_TEST_SUITE_P(Cases, MassageClosedLoop,
                         ::testing::Values(LoopCase{"healthy", 1}, LoopCase{"hypertonic", 7},
                                           LoopCase{"oedema", 23}),
                         [](const auto& p) {
                           return std::string(p.param.tissue) + "_seed" +
                                  std::to_string(p.param.seed);
                         });

// A student with a bias, a frequency error and a smaller circle does just that in the loop.
TEST(SimulatedMassage, SkillShowsInTheClosedLoop) {
  MassageTrialOptions o;
  o.op.seed = 5;
  o.op.force_bias_n = 2.0;
  o.op.frequency_error_hz = 0.5;
  o.op.amplitude_scale = 0.7;
  const MassageTrial trial = runMassageTrial(o);
  ASSERT_TRUE(trial.complete);
  const LoopFigures f = measure(trial, o.web, o.force_scale);
  std::printf("student: mean %.2f/%.2f N, radius %.3f mm, %.4f Hz\n", f.mean_n[0], f.mean_n[1],
              f.circle.radius_m * 1e3, f.circle.frequency_hz);
  for (int k = 0; k < 2; ++k) EXPECT_NEAR(f.mean_n[k], 12.0, 0.3);
  EXPECT_NEAR(f.circle.radius_m, 0.0042, 0.05 * 0.0042);
  EXPECT_NEAR(f.circle.frequency_hz, 2.0, 0.01);
}

// A capture: the real web pushes on the thimbles, the actuators are off, and the FSRs read
// the web's normal force at reference scale: to the ADC's resolution without thimble noise,
// and within the paper's 1.43 N error with it.
TEST(SimulatedMassage, CaptureFsrTracksTheWeb) {
  for (const double noise : {0.0, 1.43}) {
    MassageTrialOptions o;
    o.op.seed = 3;
    o.capture = true;
    o.force_noise_n = noise;
    const MassageTrial trial = runMassageTrial(o);
    ASSERT_TRUE(trial.complete);
    double sum = 0, sum2 = 0, max_rendered = 0, truth_sum = 0;
    int n = 0, in_band = 0;
    for (std::size_t i = kSettleS * 1000; i < trial.samples.size(); ++i) {
      for (int k = 0; k < 2; ++k) {
        const double e = trial.samples[i].fingers[k].normal_n - trial.truth_normal_n[i][k];
        sum += e;
        sum2 += e * e;
        truth_sum += trial.truth_normal_n[i][k];
        in_band += std::abs(trial.truth_normal_n[i][k] - 10.0) <= 2.0 ? 1 : 0;
        max_rendered = std::max(max_rendered, trial.rendered[i][k].norm());
        ++n;
      }
    }
    const double bias = sum / n, rms = std::sqrt(sum2 / n);
    std::printf(
        "capture, thimble noise %.2f N: FSR normal - web normal %+.3f N mean, %.3f N RMS; "
        "web normal %.2f N mean, %.3f in 10 ± 2 N\n",
        noise, bias, rms, truth_sum / n, static_cast<double>(in_band) / n);
    EXPECT_EQ(max_rendered, 0.0) << "the actuators are off in a capture";
    EXPECT_NEAR(truth_sum / n, 10.0, 0.2);
    EXPECT_GE(static_cast<double>(in_band) / n, 0.9);
    if (noise == 0.0) {
      EXPECT_LT(rms, 0.05);
    } else {
      EXPECT_NEAR(bias, 0.0, 0.05);
      EXPECT_NEAR(rms, noise, 0.1 * noise);
    }
  }
}

}  // namespace
}  // namespace telehand
