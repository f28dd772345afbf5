// The simulated MF-2 and its virtual operator, alone and inside the haptic loop.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <string_view>
#include <vector>

#include "telehand/client/loop/haptic_loop.h"
#include "telehand/core/clock.h"
#include "telehand/core/thimble.h"
#include "telehand/devices/simulated_mf2.h"

namespace telehand::client {
namespace {

using devices::DeviceSample;
using devices::ForceCommand;
using devices::SimulatedMf2;

/// Net force the operator exerts, device frame, estimated from the FSRs (paper eqs. 1-2).
Vec3 fsrForce(const DeviceSample& s) {
  Vec3 f = Vec3::Zero();
  for (const auto& finger : s.fingers) {
    f += thimbleForceVector(thimbleForces(finger.fsr_n), finger.orientation);
  }
  return f;
}

Vec3 fsrForce(const Sample& s) {
  Vec3 f = Vec3::Zero();
  for (const auto& finger : s.fingers) {
    FsrReadings fsr;
    std::copy(std::begin(finger.fsr_n), std::end(finger.fsr_n), fsr.begin());
    const Quat q(finger.orientation_q[0], finger.orientation_q[1], finger.orientation_q[2],
                 finger.orientation_q[3]);
    f += thimbleForceVector(thimbleForces(fsr), q);
  }
  return f;
}

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

TEST(SimulatedMf2, SameSeedAndClockGiveIdenticalSamples) {
  const JointModelParams model = healthyIndexMcp();
  OperatorConfig op;
  op.seed = 7;
  ManualClock clock_a(5 * kNsPerS);
  ManualClock clock_b(5 * kNsPerS);
  SimulatedMf2 a(model, op, clock_a);
  SimulatedMf2 b(model, op, clock_b);
  DeviceSample sa, sb;
  for (int i = 0; i < 3000; ++i) {
    clock_a.advance(kNsPerMs);
    clock_b.advance(kNsPerMs);
    // Some command, the same for both, so the dynamics are exercised too.
    ForceCommand cmd;
    cmd.force_n[0] = Vec3(0.0, 0.0, 0.5 * std::sin(i * 0.01));
    cmd.force_n[1] = cmd.force_n[0];
    a.write(cmd);
    b.write(cmd);
    ASSERT_TRUE(a.read(sa));
    ASSERT_TRUE(b.read(sb));
    ASSERT_TRUE(sameSample(sa, sb)) << "diverged at sample " << i;
    ASSERT_EQ(a.angles(), b.angles()) << i;
  }
  EXPECT_EQ(sa.seq, 3000u);
  EXPECT_EQ(sa.time_ns, 5 * kNsPerS + 3000 * kNsPerMs);
}

TEST(SimulatedMf2, DifferentSeedsGiveDifferentNoise) {
  const JointModelParams model = healthyIndexMcp();
  OperatorConfig op_a, op_b;
  op_a.seed = 1;
  op_b.seed = 2;
  ManualClock clock;
  SimulatedMf2 a(model, op_a, clock);
  SimulatedMf2 b(model, op_b, clock);
  int differing = 0;
  DeviceSample sa, sb;
  for (int i = 0; i < 100; ++i) {
    clock.advance(kNsPerMs);
    a.read(sa);
    b.read(sb);
    differing += sameSample(sa, sb) ? 0 : 1;
  }
  EXPECT_GT(differing, 90);
}

TEST(SimulatedMf2, OperatorForceRampsIntoTheBandAndOscillates) {
  OperatorConfig op;  // 3 Hz, 12-16 N, 1.5 s ramp
  ManualClock clock;
  const SimulatedMf2 dev(healthyIndexMcp(), op, clock);
  EXPECT_DOUBLE_EQ(dev.targetForceN(0.0), 0.0);
  EXPECT_LT(dev.targetForceN(0.2), 12.0);
  for (double t = 1.5; t < 5.0; t += 0.001) {
    EXPECT_GE(dev.targetForceN(t), 12.0 - 1e-9) << t;
    EXPECT_LE(dev.targetForceN(t), 16.0 + 1e-9) << t;
  }
  EXPECT_NEAR(dev.targetForceN(2.0 + 1.0 / 12.0), 16.0, 1e-9);  // sin peak at 3 Hz
}

TEST(SimulatedMf2, FsrReadingsMatchTheOperatorForce) {
  const JointModelParams model = healthyIndexMcp();
  OperatorConfig op;
  op.sensor_noise_n = 0.0;  // compare up to the ADC's resolution
  ManualClock clock;
  SimulatedMf2 dev(model, op, clock);
  const JointModel m(model);
  constexpr double kHalfWidth = 0.008;  // SimulatedMf2Dynamics default
  DeviceSample s;
  int checked = 0;
  for (int i = 1; i <= 4000; ++i) {
    // Hold the phalanx still against the operator (what a rigid joint would render), so the
    // thimbles do not turn between the device step and the read.
    const double t_step = static_cast<double>(clock.nowNs()) * 1e-9;
    const Vec3 tau_op(dev.targetForceN(t_step) * model.force_scale * model.lever_arm_m, 0, 0);
    ForceCommand hold;
    hold.force_n =
        m.fingertipForces(m.gripFromAngles(dev.angles(), kHalfWidth), dev.angles(), -tau_op);
    dev.write(hold);
    clock.advance(kNsPerMs);
    ASSERT_TRUE(dev.read(s));
    for (const auto& f : s.fingers) {
      for (float r : f.fsr_n) ASSERT_GE(r, 0.0f) << "FSRs only sense pressure";
    }
    // The operator force behind this sample was set at the start of the last device step.
    const double want_device_n = dev.targetForceN(t_step) * model.force_scale;
    const Vec3 f = fsrForce(s);
    // Up to the ADC: each FSR reading is quantized to one count (~1/180 N).
    ASSERT_NEAR(f.norm(), want_device_n, 0.01) << "t " << t_step;
    // It pushes the phalanx toward flexion: along d(grip)/d(alpha) = y x (phalanx axis).
    const Vec3 axis = (0.5 * (s.fingers[0].position_m + s.fingers[1].position_m)).normalized();
    const Vec3 flex_dir = Vec3::UnitY().cross(axis);
    if (want_device_n > 0.1) {
      ASSERT_GT(f.normalized().dot(flex_dir), 0.999) << "t " << t_step;
      ++checked;
    }
  }
  EXPECT_GT(checked, 3500);
  EXPECT_LT(dev.angles().norm(), degToRad(0.1)) << "the hold kept the phalanx still";
}

TEST(SimulatedMf2, WithoutResistanceTheFingerMovesIntoFlexion) {
  // Nothing rendered back: the operator's push is opposed only by viscosity.
  ManualClock clock;
  SimulatedMf2 dev(healthyIndexMcp(), OperatorConfig{}, clock);
  DeviceSample s;
  for (int i = 0; i < 150; ++i) {
    clock.advance(kNsPerMs);
    dev.read(s);
  }
  EXPECT_GT(dev.angles()[kFlexion], 0.0);
  EXPECT_LT(dev.angles()[kFlexion], degToRad(90.0));
  EXPECT_NEAR(dev.angles()[kAbduction], 0.0, 1e-9);
  const Vec3 from_grip = JointModel(healthyIndexMcp())
                             .anglesFromGrip({s.fingers[0].position_m, s.fingers[1].position_m});
  // Positions come through encoder counts (26076 counts/rad): a few 1e-4 rad at the MCP.
  EXPECT_LT((from_grip - dev.angles()).norm(), 5e-4) << "positions follow the ground truth";
}

TEST(SimulatedMf2, CommandsAreRenderedThroughTheActuators) {
  ManualClock clock;
  const JointModelParams model = healthyIndexMcp();
  SimulatedMf2 dev(model, OperatorConfig{}, clock);
  DeviceSample s;
  clock.advance(kNsPerMs);
  ASSERT_TRUE(dev.read(s));
  ForceCommand cmd;
  cmd.force_n = {Vec3(0.0, 0.0, -3.0), Vec3(1.0, 2.0, 0.5)};
  ASSERT_TRUE(dev.write(cmd));
  for (int k = 0; k < 2; ++k) EXPECT_LT((dev.renderedForce()[k] - cmd.force_n[k]).norm(), 1e-9);
  // tau = J^T F at the device's pose, as read back from the sample.
  PerFinger<mf2::ThimblePose> pose;
  for (int k = 0; k < 2; ++k) {
    pose[k].position_m = s.fingers[k].position_m;
    pose[k].orientation = s.fingers[k].orientation;
  }
  mf2::JointAngles q;
  ASSERT_TRUE(dev.kinematics().inverse(pose, 0.0, q));
  mf2::ActuatorTorques tau;
  ASSERT_TRUE(dev.kinematics().actuatorTorques(q.actuators, cmd.force_n, tau));
  EXPECT_LT((tau - dev.actuatorTorques()).cwiseAbs().maxCoeff(), 1e-6);
  // Far beyond the actuators' limits the force keeps its direction and shrinks.
  cmd.force_n = {Vec3(0.0, 0.0, -400.0), Vec3::Zero()};
  ASSERT_TRUE(dev.write(cmd));
  const auto& lim = dev.kinematics().description().max_torque_nm;
  EXPECT_LE((dev.actuatorTorques().cwiseAbs() - lim).maxCoeff(), 1e-12);
  EXPECT_LT(dev.renderedForce()[kThumb].norm(), 400.0);
  EXPECT_GT(dev.renderedForce()[kThumb].normalized().dot(Vec3(0, 0, -1)), 0.999);
}

TEST(SimulatedMf2, CaptureWithAPatientJointAndActuatorsOff) {
  // A real finger in the grip, nothing rendered: the operator's push is held by the joint,
  // the FSRs see the push and no channel is flagged (ADC noise keeps them alive).
  ManualClock clock;
  OperatorConfig op;
  op.band_min_n = op.band_max_n = 10.0;
  JointModelParams geometry = healthyIndexMcp();
  geometry.force_scale = 1.0;  // a capture measures real forces: no 1:4 rendering scale
  SimulatedMf2 dev(geometry, op, clock);
  dev.setPatient(healthyIndexMcp());
  DeviceSample s;
  for (int i = 0; i < 4000; ++i) {
    clock.advance(kNsPerMs);
    ASSERT_TRUE(dev.read(s));
    dev.write(ForceCommand{});
  }
  const JointModel m(healthyIndexMcp());
  // Settles where the healthy joint holds 10 N (plus the operator's own hold on flexion: none).
  EXPECT_NEAR(m.holdingForceN(kFlexion, dev.angles()[kFlexion]), 10.0, 0.3);
  EXPECT_NEAR(fsrForce(s).norm(), 10.0, 0.05);
  EXPECT_EQ(s.fingers[0].fsr_fault_mask | s.fingers[1].fsr_fault_mask, 0);
}

TEST(SimulatedMf2, StalledCallerSkipsAheadInsteadOfSpinning) {
  ManualClock clock;
  SimulatedMf2 dev(healthyIndexMcp(), OperatorConfig{}, clock);
  DeviceSample s;
  clock.advance(10 * kNsPerS);
  ASSERT_TRUE(dev.read(s));
  EXPECT_LE(s.seq, 201u);
  EXPECT_LE(s.time_ns, 10 * kNsPerS);
  EXPECT_GT(s.time_ns, 10 * kNsPerS - kNsPerMs) << "sample time catches up with the clock";
}

/// Smallest flexion angle at which the model's holding force reaches `force_n`.
double flexionAtForce(const JointModel& m, double force_n) {
  double lo = degToRad(-45.0), hi = degToRad(90.0);
  for (int i = 0; i < 80; ++i) {
    const double mid = 0.5 * (lo + hi);
    (m.holdingForceN(kFlexion, mid) < force_n ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

/// The simulated MF-2 whose `nan_at`-th read gives a thumb position that is not finite.
class NanOnceDevice final : public devices::Device {
 public:
  NanOnceDevice(devices::Device& inner, int nan_at) : inner_(inner), nan_at_(nan_at) {}
  bool read(DeviceSample& out) noexcept override {
    const bool got = inner_.read(out);
    if (++reads_ == nan_at_) out.fingers[kThumb].position_m[0] = std::nan("");
    return got;
  }
  bool write(const ForceCommand& cmd) noexcept override { return inner_.write(cmd); }
  devices::DeviceStatus status() const noexcept override { return inner_.status(); }
  std::string_view name() const noexcept override { return "nan-once"; }

 private:
  devices::Device& inner_;
  int nan_at_;
  int reads_ = 0;
};

// One device sample with a position that is not finite is not taken: the joint's rate filter
// is not left NaN, so the loop goes on rendering the joint (it did not fall to a silent 0 N
// for the rest of the session), and the sample is counted.
TEST(SimulatedMf2, ADeviceSampleThatIsNotFiniteIsNotTakenAndTheJointStillRenders) {
  const JointModelParams model = healthyIndexMcp();
  OperatorConfig op;
  ManualClock clock(1 * kNsPerS);
  SimulatedMf2 sim(model, op, clock);
  NanOnceDevice dev(sim, 2000);
  loop::HapticLoop hl(dev, clock, model, SafetyLimits{});
  Sample s;
  double late_max = 0.0;
  for (int i = 0; i < 4000; ++i) {
    clock.advance(kNsPerMs);
    hl.step();
    while (hl.samples().tryPop(s)) {
    }
    if (i > 3000) late_max = std::max(late_max, sim.renderedForce()[kThumb].norm());
  }
  EXPECT_EQ(hl.health().device_nonfinite.load(), 1u);
  EXPECT_GT(late_max, 0.5) << "the joint is no longer rendered after the bad sample";
  EXPECT_EQ(hl.health().nonfinite.load(), 0u);
}

TEST(SimulatedMf2, MobilizationInTheHapticLoop) {
  const JointModelParams model = healthyIndexMcp();
  const JointModel m(model);
  OperatorConfig op;  // the paper's mobilization: 3 Hz between 12 and 16 N
  ManualClock clock(1 * kNsPerS);
  SimulatedMf2 dev(model, op, clock);
  loop::HapticLoop hl(dev, clock, model, SafetyLimits{});

  struct Point {
    double t_s, applied_ref_n, commanded_ref_n, flexion_rad;
  };
  std::vector<Point> pts;
  pts.reserve(10'000);
  uint64_t expected_seq = 0;
  Sample s;
  for (int i = 0; i < 10'000; ++i) {
    clock.advance(kNsPerMs);
    ASSERT_EQ(hl.step(), loop::StepStatus::kOk) << i;
    while (hl.samples().tryPop(s)) {
      ASSERT_EQ(s.seq, expected_seq++);
      Vec3 cmd = Vec3::Zero();
      for (const auto& f : s.fingers) cmd += Vec3(f.command_n[0], f.command_n[1], f.command_n[2]);
      // (source_time_ns is wall clock on the wire; this sample is from this tick.)
      pts.push_back({static_cast<double>(clock.nowNs() - 1 * kNsPerS) * 1e-9,
                     fsrForce(s).norm() / model.force_scale, cmd.norm() / model.force_scale,
                     s.mcp_angles_rad[kFlexion]});
    }
  }
  ASSERT_EQ(pts.size(), 10'000u);
  EXPECT_EQ(hl.health().watchdog_trips.load(), 0u);
  EXPECT_EQ(hl.health().nonfinite.load(), 0u);
  EXPECT_EQ(hl.health().samples_dropped.load(), 0u);
  EXPECT_LE(hl.health().force_max_n.load(), 4.0 + 1e-9);

  // After the ramp (1.5 s) and settling: t in [2, 10) s. The FSR estimate is averaged over
  // 10 ms against sensor noise (this attenuates a 3 Hz swing by 0.15 %).
  constexpr std::size_t kAvg = 10;
  double lo = 1e9, hi = -1e9, flex_lo = 1e9, flex_hi = -1e9, track_err = 0.0;
  int crossings = 0, n = 0;
  int side = 0;  // hysteresis of +-0.5 N around 14 N
  for (std::size_t i = kAvg; i < pts.size(); ++i) {
    const Point& p = pts[i];
    if (p.t_s < 2.0) continue;
    double applied = 0.0;
    for (std::size_t j = i + 1 - kAvg; j <= i; ++j) applied += pts[j].applied_ref_n / kAvg;
    lo = std::min(lo, applied);
    hi = std::max(hi, applied);
    flex_lo = std::min(flex_lo, p.flexion_rad);
    flex_hi = std::max(flex_hi, p.flexion_rad);
    track_err += std::abs(p.commanded_ref_n - p.applied_ref_n);
    ++n;
    const int now_side = applied > 14.5 ? 1 : applied < 13.5 ? -1 : side;
    if (side != 0 && now_side != side) ++crossings;
    side = now_side;
  }
  // Reference scale: within about 12-16 N, and spanning the band.
  EXPECT_GT(lo, 11.7);
  EXPECT_LT(lo, 12.3);
  EXPECT_GT(hi, 15.7);
  EXPECT_LT(hi, 16.3);
  // ~3 Hz: two crossings of 14 N per period over 8 s.
  EXPECT_GE(crossings, 46);
  EXPECT_LE(crossings, 50);
  // The joint yields to the push as the model says, inside its range of motion.
  EXPECT_NEAR(flex_lo, flexionAtForce(m, 12.0), degToRad(1.0));
  EXPECT_NEAR(flex_hi, flexionAtForce(m, 16.0), degToRad(1.0));
  EXPECT_GT(flex_lo, degToRad(model.axes[kFlexion].min_deg));
  EXPECT_LT(flex_hi, degToRad(model.axes[kFlexion].max_deg));
  // The rendered joint holds against the operator: commanded ~ applied on average.
  EXPECT_LT(track_err / n, 0.5) << "mean |commanded - applied|, N reference scale";
  for (const Point& p : pts) {
    ASSERT_GT(p.flexion_rad, degToRad(model.axes[kFlexion].min_deg)) << p.t_s;
    ASSERT_LT(p.flexion_rad, degToRad(model.axes[kFlexion].max_deg)) << p.t_s;
  }
}

}  // namespace
}  // namespace telehand::client
