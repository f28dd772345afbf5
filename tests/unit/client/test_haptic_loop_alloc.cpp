// HapticLoop::step() allocates nothing (docs/design.md "House style"). This executable replaces
// the global operator new/delete with counting versions, armed per thread around step().
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <memory>
#include <new>
#include <string>
#include <thread>
#include <vector>

#include "alloc_guard.h"
#include "telehand/client/loop/haptic_loop.h"
#include "telehand/core/clock.h"
#include "telehand/core/knn_model.h"
#include "telehand/core/tissue_model.h"
#include "telehand/devices/simulated_massage_mf2.h"
#include "telehand/devices/simulated_mf2.h"

namespace telehand::client {
namespace {

using devices::DeviceSample;
using devices::ForceCommand;
using devices::SimulatedMf2;
using loop::HapticLoop;
using loop::StepStatus;
using test::AllocationGuard;
using test::escape;

/// Forwards to a device, but can stall (a stalled USB link: reads fail and writes do not reach
/// the device, which keeps rendering its last accepted command) or allocate in read() (the
/// bug the guard must catch).
class TestDevice final : public devices::Device {
 public:
  explicit TestDevice(devices::Device& inner) : inner_(inner) {}
  bool read(DeviceSample& out) noexcept override {
    if (allocate_in_read) {
      auto* s = new (std::nothrow) std::string(100, 'x');
      escape(s);
      delete s;
    }
    if (fail_reads) return false;
    if (stall_every > 0 && ++reads_ % stall_every == 0) {
      std::this_thread::sleep_for(std::chrono::microseconds(2500));  // a slow transfer
    }
    return inner_.read(out);
  }
  bool write(const ForceCommand& cmd) noexcept override {
    if (fail_reads) return false;
    return inner_.write(cmd);
  }
  devices::DeviceStatus status() const noexcept override { return inner_.status(); }
  std::string_view name() const noexcept override { return "test"; }

  bool fail_reads = false;
  bool allocate_in_read = false;
  int stall_every = 0;  ///< every n-th read takes 2.5 ms (0: none)

 private:
  int reads_ = 0;
  devices::Device& inner_;
};

TEST(AllocationGuard, CountsAllocationsOnlyWhileArmed) {
  std::size_t counted = 0;
  {
    AllocationGuard guard;
    auto v = std::make_unique<std::vector<double>>(64, 1.0);
    escape(v.get());
    escape(v->data());
    counted = guard.allocations();
  }
  EXPECT_EQ(counted, 2u) << "the vector object and its buffer";

  const std::size_t before = t_allocations;
  auto w = std::make_unique<std::vector<double>>(64, 1.0);
  escape(w->data());
  EXPECT_EQ(t_allocations, before) << "not armed: not counted";
}

TEST(AllocationGuard, CatchesAnAllocationInsideStep) {
  ManualClock clock(kNsPerS);
  const JointModelParams model = healthyIndexMcp();
  SimulatedMf2 sim(model, OperatorConfig{}, clock);
  TestDevice dev(sim);
  HapticLoop hl(dev, clock, model, SafetyLimits{});
  dev.allocate_in_read = true;
  clock.advance(kNsPerMs);
  AllocationGuard guard;
  hl.step();
  EXPECT_GE(guard.allocations(), 1u) << "a device that allocates in read() must be caught";
  EXPECT_GE(guard.deallocations(), 1u);
}

TEST(HapticLoopAlloc, StepAllocatesNothingThroughModelUpdateAndWatchdog) {
  constexpr int kTicks = 6000;
  constexpr int kModelAt = 2000;
  constexpr int kFaultFrom = 3500;
  constexpr int kFaultTicks = 50;

  ManualClock clock(kNsPerS);
  const JointModelParams model = healthyIndexMcp();
  SimulatedMf2 sim(model, OperatorConfig{}, clock);
  TestDevice dev(sim);
  HapticLoop hl(dev, clock, model, SafetyLimits{});
  hl.setSession(77);
  JointModelParams stiffer = model;
  stiffer.version = 2;
  stiffer.axes[kFlexion].coeffs = {3e-5, 0.002, 0.08, 1.0};

  std::vector<Sample> samples;
  samples.reserve(kTicks);
  std::vector<StepStatus> statuses;
  statuses.reserve(kTicks);
  std::size_t allocations = 0, deallocations = 0;
  for (int i = 0; i < kTicks; ++i) {
    clock.advance(kNsPerMs);
    if (i == kModelAt) {
      ASSERT_TRUE(hl.models().tryPush(stiffer));  // the link thread's side
    }
    // The link stalls for 50 ms. (Were only the reads to fail, the zero force of the watchdog
    // would reach the simulated device, which integrates the 50 ms it was not read in one go:
    // its operator, a 3-4 N force source on 50 g, flings the phalanx more than a turn around
    // the joint, 12 000 deg/s, before the loop sees a sample again; no rendering within 4 N and
    // 200 N/s stops that, and the clamp storm that follows is rightly a fault.)
    dev.fail_reads = i >= kFaultFrom && i < kFaultFrom + kFaultTicks;
    StepStatus st;
    {
      AllocationGuard guard;
      st = hl.step();
      allocations += guard.allocations();
      deallocations += guard.deallocations();
    }
    statuses.push_back(st);
    Sample s;
    while (hl.samples().tryPop(s)) samples.push_back(s);
  }

  EXPECT_EQ(allocations, 0u) << "HapticLoop::step() allocated";
  EXPECT_EQ(deallocations, 0u) << "HapticLoop::step() freed memory";

  // The run really went through the model update, the watchdog and the passivity
  // controller (it damps the start-up deficit, through its windowed velocity).
  const loop::LoopHealth& h = hl.health();
  EXPECT_GT(h.passivity_activations.load(), 0u);
  EXPECT_EQ(h.ticks.load(), static_cast<uint64_t>(kTicks));
  EXPECT_EQ(h.models_applied.load(), 1u);
  EXPECT_EQ(h.model_version.load(), 2u);
  EXPECT_EQ(h.device_read_failures.load(), static_cast<uint64_t>(kFaultTicks));
  EXPECT_GT(h.watchdog_trips.load(), 0u);
  EXPECT_EQ(h.samples_dropped.load(), 0u);
  // The outage and the stiffer model leave the rendering stable: no clamp, no fault, and the
  // loop counted the outage it resumed from.
  EXPECT_EQ(h.clamped.load(), 0u) << "peak request " << h.request_max_n.load() << " N";
  EXPECT_EQ(hl.fault(), loop::LoopFault::kNone) << loop::faultName(hl.fault());
  EXPECT_EQ(h.outages.load(), 1u);

  // Every tick produced one sample, in order, with a gated force.
  ASSERT_EQ(samples.size(), static_cast<std::size_t>(kTicks));
  EXPECT_EQ(hl.nextSeq(), static_cast<uint64_t>(kTicks));
  int watchdog_samples = 0;
  for (int i = 0; i < kTicks; ++i) {
    const Sample& s = samples[i];
    ASSERT_EQ(s.seq, static_cast<uint64_t>(i));
    EXPECT_EQ(s.session_id, 77u);
    EXPECT_EQ(s.model_version, i < kModelAt ? 1u : 2u) << i;
    for (const auto& f : s.fingers) {
      const Vec3 cmd(f.command_n[0], f.command_n[1], f.command_n[2]);
      ASSERT_TRUE(allFinite(cmd)) << i;
      ASSERT_LE(cmd.norm(), 4.0 + 1e-9) << i;
      if (s.flags & sample_flags::kWatchdog) {
        ASSERT_TRUE(cmd.isZero()) << i;
      }
    }
    const bool in_fault = i >= kFaultFrom && i < kFaultFrom + kFaultTicks;
    if (i > 0) {
      // One device sample per tick, 1 ms apart; a failed read repeats the last one.
      const int64_t dt = s.source_time_ns - samples[i - 1].source_time_ns;
      if (in_fault) {
        EXPECT_EQ(dt, 0) << i;
      } else if (i == kFaultFrom + kFaultTicks) {
        EXPECT_EQ(dt, (kFaultTicks + 1) * kNsPerMs) << i;
      } else {
        EXPECT_EQ(dt, kNsPerMs) << i;
      }
    }
    if (s.flags & sample_flags::kWatchdog) {
      ++watchdog_samples;
      EXPECT_TRUE(in_fault) << i;
      EXPECT_EQ(statuses[i], StepStatus::kSafetyFault) << i;
    } else if (in_fault) {
      EXPECT_EQ(statuses[i], StepStatus::kNoSample) << i;
    } else {
      EXPECT_EQ(statuses[i], StepStatus::kOk)
          << i << " " << loop::faultName(hl.fault()) << " clamps " << hl.health().clamped.load()
          << " at " << hl.health().fault_time_ns.load() << " peak "
          << hl.health().request_max_n.load();
    }
    if (i > kModelAt && i < kModelAt + 150) {
      EXPECT_TRUE(s.flags & sample_flags::kModelBlending) << i;
    }
  }
  // Stale after 5 ms without a sample: 50 failed reads leave about 45 watchdog ticks.
  EXPECT_GE(watchdog_samples, kFaultTicks - 6);
  EXPECT_LE(watchdog_samples, kFaultTicks - 4);
  // Force comes back after the fault.
  const auto& last = samples.back().fingers[0].command_n;
  EXPECT_GT(Vec3(last[0], last[1], last[2]).norm(), 0.1);
}

TEST(HapticLoopAlloc, KnnModelAndCaptureModeAllocateNothing) {
  // A data-driven model arrives (FLANN queries every tick), crossfades in, and the loop then
  // switches to capture mode: no allocation in any step.
  ManualClock clock(kNsPerS);
  const JointModelParams model = healthyIndexMcp();
  const JointModel cubic(model);
  std::vector<KnnPoint> pts;
  for (double a = -40; a <= 85; a += 2.5) {
    for (double b = -18; b <= 18; b += 2) {
      for (double g = -9; g <= 14; g += 2) {
        const Vec3 ang(degToRad(a), degToRad(b), degToRad(g));
        pts.push_back({ang, cubic.passiveTorqueNm(ang, Vec3::Zero())});
      }
    }
  }
  const KnnTorqueModel knn(pts);
  SimulatedMf2 sim(model, OperatorConfig{}, clock);
  TestDevice dev(sim);
  HapticLoop hl(dev, clock, model, SafetyLimits{});
  JointModelParams data_driven = model;
  data_driven.version = 2;
  data_driven.knn = &knn;
  std::size_t allocations = 0;
  Sample s;
  double max_force = 0.0;
  for (int i = 0; i < 4000; ++i) {
    clock.advance(kNsPerMs);
    if (i == 500) {
      ASSERT_TRUE(hl.models().tryPush(data_driven));
    }
    if (i == 3000) hl.setActuatorsEnabled(false);
    {
      AllocationGuard guard;
      hl.step();
      allocations += guard.allocations() + guard.deallocations();
    }
    while (hl.samples().tryPop(s)) {
      const Vec3 f(s.fingers[0].command_n[0], s.fingers[0].command_n[1], s.fingers[0].command_n[2]);
      if (i > 1000 && i < 3000) max_force = std::max(max_force, f.norm());
      if (i > 3000) {
        EXPECT_TRUE(f.isZero()) << "capture mode: zero output whatever the model says";
        EXPECT_TRUE(s.flags & sample_flags::kCapture);
      }
    }
  }
  EXPECT_EQ(allocations, 0u);
  EXPECT_EQ(hl.health().model_version.load(), 2u);
  EXPECT_GT(max_force, 0.5) << "the data-driven model rendered a force";
}

TEST(HapticLoopAlloc, StepAllocatesNothingWithPassivityControlDirectForcesAndQueuedModels) {
  ManualClock clock(kNsPerS);
  const JointModelParams model = healthyIndexMcp();
  SimulatedMf2 sim(model, OperatorConfig{}, clock);
  loop::TeleopOptions teleop;
  teleop.render = loop::RenderMode::kDirect;
  HapticLoop hl(sim, clock, model, SafetyLimits{}, LoopConfig{}, teleop);
  JointModelParams v2 = model, v3 = model;
  v2.version = 2;
  v2.axes[kFlexion].coeffs = {3e-5, 0.002, 0.08, 1.0};
  v3.version = 3;
  std::size_t allocations = 0;
  Sample s;
  for (int i = 0; i < 4000; ++i) {
    clock.advance(kNsPerMs);
    if (i == 500) {
      ASSERT_TRUE(hl.models().tryPush(v2));
    }
    if (i == 550) {
      ASSERT_TRUE(hl.models().tryPush(v3));  // mid-fade: queued in the proxy
    }
    if (i == 2000) hl.setRenderMode(loop::RenderMode::kModel);
    // 300 ms of silence from the server: its force goes stale, and nothing is rendered.
    if (i % 3 == 0 && hl.nextSeq() > 0 && (i < 1000 || i >= 1300)) {
      // A server that renders an active (energy-injecting) force: the controller must act.
      loop::DirectForceSample f;
      f.device_seq = hl.nextSeq() - 1;  // the answer to the newest sample
      f.force_n = {Vec3(0.0, 0.0, 3.5 * std::sin(i * 0.2)),
                   Vec3(0.0, 0.0, -3.5 * std::sin(i * 0.2))};
      hl.directForces().tryPush(f);
    }
    {
      AllocationGuard guard;
      hl.step();
      allocations += guard.allocations() + guard.deallocations();
    }
    while (hl.samples().tryPop(s)) {
    }
  }
  EXPECT_EQ(allocations, 0u);
  const loop::LoopHealth& h = hl.health();
  EXPECT_GT(h.direct_forces.load(), 600u);
  EXPECT_GT(h.direct_stale_ticks.load(), 150u);
  EXPECT_EQ(h.models_applied.load(), 2u);
  EXPECT_EQ(h.model_version.load(), 3u) << "the queued version came after the first fade";
  EXPECT_LE(h.update_step_max_ratio.load(), 1.0);
}

/// A guide along a 3 Hz flexion swing of +-6 deg about 20 deg (a demonstration's path).
GuideParams swingGuide(double authority) {
  GuideParams g;
  g.authority = authority;
  g.period_s = 1.0 / 3.0;
  for (int k = 0; k < GuideParams::kPoints; ++k) {
    const double ph = 2.0 * M_PI * k / GuideParams::kPoints;
    g.path_rad[static_cast<std::size_t>(k)] = Vec3(degToRad(20.0 + 6.0 * std::sin(ph)), 0, 0);
  }
  return g;
}

TEST(HapticLoopAlloc, GuidanceStaysInsideTheGateFadesAsScheduledAndAllocatesNothing) {
  // A lesson's guided trials, as the server schedules them: full, half, then none, each a
  // new model version faded in by the proxy. The simulated student pushes at 3 Hz.
  ManualClock clock(kNsPerS);
  const JointModelParams model = healthyIndexMcp();
  SimulatedMf2 sim(model, OperatorConfig{}, clock);
  TestDevice dev(sim);
  const SafetyLimits limits{};
  HapticLoop hl(dev, clock, model, limits);
  hl.setSession(78);
  const double authorities[] = {1.0, 0.5, 0.0};
  constexpr int kTrialTicks = 3000;
  std::size_t allocations = 0;
  double max_force = 0.0;
  // The guide's share of the commanded torque per trial (largest |guide| torque seen).
  double guide_max[3] = {0, 0, 0};
  double guide_end[3] = {0, 0, 0};
  for (int trial = 0; trial < 3; ++trial) {
    JointModelParams next = model;
    next.version = static_cast<uint32_t>(2 + trial);
    next.guide = swingGuide(authorities[trial]);
    ASSERT_TRUE(hl.models().tryPush(next));
    for (int i = 0; i < kTrialTicks; ++i) {
      clock.advance(kNsPerMs);
      {
        AllocationGuard guard;
        hl.step();
        allocations += guard.allocations() + guard.deallocations();
      }
      Sample s;
      while (hl.samples().tryPop(s)) {
        for (int k = 0; k < 2; ++k) {
          const Vec3 f(s.fingers[k].command_n[0], s.fingers[k].command_n[1],
                       s.fingers[k].command_n[2]);
          max_force = std::max(max_force, f.norm());
        }
      }
      // After the 200 ms fade the guide is the trial's own.
      const loop::LoopHealth& h = hl.health();
      if (i > 300) guide_max[trial] = std::max(guide_max[trial], h.guide_nm.load());
      if (i == kTrialTicks - 1) guide_end[trial] = h.guide_authority.load();
    }
  }
  EXPECT_EQ(allocations, 0u) << "step() allocated or freed with a guide";
  EXPECT_LE(max_force, limits.max_force_n + 1e-9) << "every force leaves through the gate";
  EXPECT_EQ(hl.health().fault.load(), 0u) << loop::faultName(hl.fault());
  EXPECT_EQ(hl.health().models_applied.load(), 3u);
  // Authority as scheduled: full, half, none; the guide's torque bounded by authority.
  EXPECT_DOUBLE_EQ(guide_end[0], 1.0);
  EXPECT_DOUBLE_EQ(guide_end[1], 0.5);
  EXPECT_DOUBLE_EQ(guide_end[2], 0.0);
  const double bound = swingGuide(1.0).max_force_n * model.lever_arm_m;
  EXPECT_GT(guide_max[0], 0.0);
  EXPECT_LE(guide_max[0], 1.0 * bound + 1e-12);
  EXPECT_LE(guide_max[1], 0.5 * bound + 1e-12);
  EXPECT_EQ(guide_max[2], 0.0);
}

// A supervisor's take-over (docs/lessons.md "Take-over"): the guide follows another
// rhythm (2 Hz, the supervisor's) than the simulated student's own push (3 Hz), and is
// refreshed every 2 s with a path of another amplitude and period, as the server derives it
// from the supervisor's latest record. Each refresh goes on from the phase the movement is
// at; the finger stays in its range, nothing faults, every force leaves through the gate.
TEST(HapticLoopAlloc, ATakenOverGuideRefreshedAsTheSupervisorMovesStaysStable) {
  ManualClock clock(kNsPerS);
  const JointModelParams model = healthyIndexMcp();
  SimulatedMf2 sim(model, OperatorConfig{}, clock);
  TestDevice dev(sim);
  const SafetyLimits limits{};
  HapticLoop hl(dev, clock, model, limits);
  hl.setSession(79);
  const double amplitudes[] = {9.2, 11.8, 10.9, 9.6, 12.5, 8.7};
  const double periods[] = {0.50, 0.50, 0.52, 0.49, 0.50, 0.51};
  double lo = 1e9, hi = -1e9, max_force = 0.0;
  std::size_t allocations = 0;
  for (int refresh = 0; refresh < 6; ++refresh) {
    JointModelParams next = model;
    next.version = static_cast<uint32_t>(2 + refresh);
    next.guide.authority = 0.67;
    next.guide.period_s = periods[refresh];
    for (int k = 0; k < GuideParams::kPoints; ++k) {
      const double ph = 2.0 * M_PI * k / GuideParams::kPoints;
      next.guide.path_rad[static_cast<std::size_t>(k)] =
          Vec3(degToRad(65.0 + amplitudes[refresh] / 2 * std::sin(ph)), 0, 0);
    }
    ASSERT_TRUE(hl.models().tryPush(next));
    for (int i = 0; i < 2000; ++i) {
      clock.advance(kNsPerMs);
      {
        AllocationGuard guard;
        hl.step();
        allocations += guard.allocations() + guard.deallocations();
      }
      Sample s;
      while (hl.samples().tryPop(s)) {
        lo = std::min(lo, radToDeg(s.mcp_angles_rad[kFlexion]));
        hi = std::max(hi, radToDeg(s.mcp_angles_rad[kFlexion]));
        for (int k = 0; k < 2; ++k) {
          const Vec3 f(s.fingers[k].command_n[0], s.fingers[k].command_n[1],
                       s.fingers[k].command_n[2]);
          max_force = std::max(max_force, f.norm());
        }
      }
    }
  }
  EXPECT_EQ(allocations, 0u);
  EXPECT_EQ(hl.health().fault.load(), 0u) << loop::faultName(hl.fault());
  EXPECT_LE(max_force, limits.max_force_n + 1e-9);
  EXPECT_EQ(hl.health().models_applied.load(), 6u);
  // The student's swing and the guide's together stay a mobilization, not a runaway.
  EXPECT_GT(lo, model.axes[kFlexion].min_deg) << lo << ".." << hi << " deg";
  EXPECT_LT(hi, model.axes[kFlexion].max_deg) << lo << ".." << hi << " deg";
  std::printf("flexion %.1f..%.1f deg, peak device force %.2f N\n", lo, hi, max_force);
}

// The loop at its own pace (start/stop, the monotonic clock) on a device whose every 50th
// transfer takes 2.5 ms: each tick that ends after its deadline is counted, and the sample
// after it says so (sample_flags::kLoopOverrun), which is how the server and the web console
// learn of them (HandState.device_overruns).
TEST(HapticLoopAlloc, MassageStepAndTissueUpdatesMidRunAllocateNothing) {
  // The massage: the loop renders the web (the joint proxy and the tissue proxy both step
  // every tick) while the clinician circles on it; mid-run the server's model changes the
  // tissue (a stiffer web, then, mid-fade, a scar's patch), and a later one goes back to the
  // healthy web. No step allocates.
  ManualClock clock(kNsPerS);
  JointModelParams model = healthyIndexMcp();
  model.technique = Technique::kMassage;
  model.tissue = tissueCase("healthy");
  devices::SimulatedMassageMf2 sim(model.tissue, OperatorConfig{}, clock, model.force_scale);
  TestDevice dev(sim);
  HapticLoop hl(dev, clock, model, SafetyLimits{});
  JointModelParams stiffer = model, scar = model, back = model;
  stiffer.version = 2;
  stiffer.tissue = tissueCase("hypertonic");
  scar.version = 3;
  scar.tissue = tissueCase("scar");
  back.version = 4;
  std::size_t allocations = 0;
  Sample s;
  double max_web_n = 0.0;
  for (int i = 0; i < 6000; ++i) {
    clock.advance(kNsPerMs);
    if (i == 1500) {
      ASSERT_TRUE(hl.models().tryPush(stiffer));
    }
    if (i == 1600) {
      ASSERT_TRUE(hl.models().tryPush(scar));  // while the stiffer web still fades in
    }
    if (i == 4000) {
      ASSERT_TRUE(hl.models().tryPush(back));
    }
    {
      AllocationGuard guard;
      hl.step();
      allocations += guard.allocations() + guard.deallocations();
    }
    while (hl.samples().tryPop(s)) {
      for (int k = 0; k < 2; ++k) {
        const Vec3 f(s.fingers[k].tissue_force_n[0], s.fingers[k].tissue_force_n[1],
                     s.fingers[k].tissue_force_n[2]);
        max_web_n = std::max(max_web_n, f.norm());
      }
    }
  }
  EXPECT_EQ(allocations, 0u);
  const loop::LoopHealth& h = hl.health();
  EXPECT_EQ(h.models_applied.load(), 3u);
  EXPECT_EQ(h.model_version.load(), 4u);
  EXPECT_TRUE(h.massage.load()) << "the loop renders the web";
  EXPECT_GT(h.massage_ticks.load(), 5000u);
  EXPECT_GT(max_web_n, 5.0) << "the web was pressed";
  EXPECT_EQ(h.fault.load(), 0u);
}

TEST(HapticLoopAlloc, AMassageGuideLeadsThroughTheGateFadesAndAllocatesNothing) {
  // A massage lesson's guided trials: the clinician circles while a guide at full, then half
  // authority leads round a circle 2 mm wider than the clinician's, then none. The guide's
  // force stays within authority times its bound, nothing passes the gate, no step allocates,
  // and the guide is gone after the last update.
  ManualClock clock(kNsPerS);
  JointModelParams model = healthyIndexMcp();
  model.technique = Technique::kMassage;
  model.tissue = tissueCase("healthy");
  devices::SimulatedMassageMf2 sim(model.tissue, OperatorConfig{}, clock, model.force_scale);
  TestDevice dev(sim);
  SafetyLimits limits;
  HapticLoop hl(dev, clock, model, limits);
  auto guided = [&](uint32_t version, double authority) {
    JointModelParams m = model;
    m.version = version;
    m.guide.authority = authority;
    m.guide.period_s = 1.0 / 1.5;
    for (int k = 0; k < GuideParams::kPoints; ++k) {
      const double a = 2.0 * kPi * k / GuideParams::kPoints;
      m.guide.path_rad[static_cast<std::size_t>(k)] =
          Vec3(0.008 * std::cos(a), 0.008 * std::sin(a), 0.0);
    }
    return m;
  };
  const JointModelParams full = guided(2, 1.0), half = guided(3, 0.5);
  JointModelParams none = model;
  none.version = 4;
  std::size_t allocations = 0;
  double guide_max[3] = {0, 0, 0};
  double command_max = 0.0;
  Sample s;
  for (int i = 0; i < 7000; ++i) {
    clock.advance(kNsPerMs);
    if (i == 1000) {
      ASSERT_TRUE(hl.models().tryPush(full));
    }
    if (i == 3500) {
      ASSERT_TRUE(hl.models().tryPush(half));
    }
    if (i == 5500) {
      ASSERT_TRUE(hl.models().tryPush(none));
    }
    {
      AllocationGuard guard;
      hl.step();
      allocations += guard.allocations() + guard.deallocations();
    }
    const double g = hl.health().guide_web_n.load();
    if (i >= 1300 && i < 3500) guide_max[0] = std::max(guide_max[0], g);
    if (i >= 3800 && i < 5500) guide_max[1] = std::max(guide_max[1], g);
    if (i >= 5800) guide_max[2] = std::max(guide_max[2], g);
    while (hl.samples().tryPop(s)) {
      for (int k = 0; k < 2; ++k) {
        command_max = std::max(
            command_max,
            Vec3(s.fingers[k].command_n[0], s.fingers[k].command_n[1], s.fingers[k].command_n[2])
                .norm());
      }
    }
  }
  EXPECT_EQ(allocations, 0u);
  const double bound = std::sqrt(2.0) * full.guide.max_force_n;  // both web axes at the bound
  EXPECT_GT(guide_max[0], 1.0) << "the guide pulls toward its wider circle";
  EXPECT_LE(guide_max[0], bound + 1e-9);
  EXPECT_GT(guide_max[1], 0.3);
  EXPECT_LE(guide_max[1], 0.5 * bound + 1e-9);
  EXPECT_EQ(guide_max[2], 0.0) << "no guide after the last update";
  EXPECT_LE(command_max, limits.max_force_n + 1e-9);
  EXPECT_EQ(hl.health().fault.load(), 0u);
  EXPECT_EQ(hl.health().guide_nm.load(), 0.0) << "the joint's proxy never saw the web's path";
}

TEST(HapticLoopOverrun, EveryOverrunFlagsTheNextSample) {
  SteadyClock clock;
  const JointModelParams model = healthyIndexMcp();
  SimulatedMf2 sim(model, OperatorConfig{}, clock);
  TestDevice dev(sim);
  dev.stall_every = 50;
  loop::TeleopOptions teleop;
  teleop.fault.enabled = false;  // the stalls are the point here, not a fault
  HapticLoop hl(dev, clock, model, SafetyLimits{}, LoopConfig{}, teleop);
  hl.setSession(5);
  hl.start();
  std::this_thread::sleep_for(std::chrono::milliseconds(600));
  hl.stop();
  uint64_t flagged = 0, samples = 0;
  Sample s;
  while (hl.samples().tryPop(s)) {
    ++samples;
    if (s.flags & sample_flags::kLoopOverrun) ++flagged;
  }
  const uint64_t overruns = hl.health().overruns.load();
  EXPECT_GT(samples, 300u);
  EXPECT_GE(overruns, 8u) << "about 12 stalls of 2.5 ms in 600 ticks";
  // The last tick may have overrun with no sample after it.
  EXPECT_GE(flagged + 1, overruns);
  EXPECT_LE(flagged, overruns);
}

}  // namespace
}  // namespace telehand::client
