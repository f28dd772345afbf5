// Model updates on the client: the fade is step-bounded, energy-gated, and a version that
// arrives mid-fade waits its turn (no force step, no energy injected).
#include <gtest/gtest.h>

#include <vector>

#include "telehand/core/clock.h"
#include "telehand/core/joint_model.h"

namespace telehand {
namespace {

/// A flexion sweep of the grip (1 Hz, 20 deg around 40 deg).
PerFinger<Vec3> sweep(const JointModel& m, int64_t t_ns) {
  const double t = static_cast<double>(t_ns) * 1e-9;
  const Vec3 a(degToRad(40.0 + 20.0 * std::sin(2 * kPi * t)), degToRad(3.0), degToRad(1.0));
  return m.gripFromAngles(a, 0.008);
}

JointModelParams stiffer(uint32_t version, double factor) {
  JointModelParams p = healthyIndexMcp();
  p.version = version;
  for (auto& axis : p.axes) {
    for (auto& c : axis.coeffs) c *= factor;
  }
  return p;
}

double updateBound(const ProxyOutput& out) {
  double f = 0.0;
  for (int k = 0; k < 2; ++k) f = std::max(f, out.force_device_n[k].norm());
  return JointProxy::updateStepBoundN(f);
}

TEST(ModelFade, PotentialEnergyIsZeroAtRestPositiveElsewhereAndIntegratesTheTorque) {
  const JointModel m(healthyIndexMcp());
  const Vec3 rest(m.restAngleRad(kFlexion), m.restAngleRad(kAbduction), m.restAngleRad(kAxial));
  EXPECT_NEAR(m.potentialEnergyJ(rest), 0.0, 1e-12);
  for (double deg : {-60.0, -20.0, 10.0, 45.0, 80.0, 100.0}) {
    Vec3 a = rest;
    a[kFlexion] = degToRad(deg);
    EXPECT_GE(m.potentialEnergyJ(a), 0.0) << deg;
    // dV/dα = holding force · lever · device scale (the torque the joint resists with).
    const double h = 1e-5;
    Vec3 ap = a, am = a;
    ap[kFlexion] += h;
    am[kFlexion] -= h;
    const double dv = (m.potentialEnergyJ(ap) - m.potentialEnergyJ(am)) / (2 * h);
    const double torque = m.holdingForceN(kFlexion, a[kFlexion]) * 0.01 * 0.25;
    EXPECT_NEAR(dv, torque, 2e-3 * std::abs(torque) + 1e-7) << deg;
  }
}

TEST(ModelFade, EveryTicksUpdateStepStaysUnderTheBoundEvenForAHugeChange) {
  // A 1 ms nominal fade of a model three times as stiff would step the force at once; the
  // bound stretches it instead.
  const JointModelParams old_p = healthyIndexMcp();
  const JointModelParams new_p = stiffer(2, 3.0);
  const JointModel geom(old_p);
  JointProxy proxy(old_p, kNsPerMs);
  int fade_ticks = 0;
  double worst = 0.0;
  for (int i = 0; i < 3000; ++i) {
    const int64_t t = i * kNsPerMs;
    if (i == 100) proxy.setModel(new_p);
    const ProxyOutput out = proxy.render(sweep(geom, t), t);
    worst = std::max(worst, out.update_step_n / updateBound(out));
    fade_ticks += out.blending;
  }
  EXPECT_LE(worst, 1.0);
  EXPECT_GT(worst, 0.5) << "the bound, not the nominal pace, set this fade";
  EXPECT_GT(fade_ticks, 5);
  EXPECT_FALSE(proxy.blending());
  EXPECT_EQ(proxy.version(), 2u);
}

TEST(ModelFade, AVersionArrivingMidFadeWaitsAndNothingSteps) {
  const JointModelParams v1 = healthyIndexMcp();
  const JointModelParams v2 = stiffer(2, 2.0);
  const JointModelParams v3 = stiffer(3, 0.5);
  const JointModel geom(v1);
  constexpr int64_t kBlend = 200 * kNsPerMs;
  JointProxy proxy(v1, kBlend);
  JointProxy only_v3(v3, kBlend);
  std::vector<PerFinger<Vec3>> f;
  double worst = 0.0;
  for (int i = 0; i < 1200; ++i) {
    const int64_t t = i * kNsPerMs;
    if (i == 100) proxy.setModel(v2);
    if (i == 200) {
      proxy.setModel(v3);  // mid-fade: queued
      EXPECT_EQ(proxy.version(), 2u);
    }
    const ProxyOutput out = proxy.render(sweep(geom, t), t);
    const ProxyOutput ref = only_v3.render(sweep(geom, t), t);
    worst = std::max(worst, out.update_step_n / updateBound(out));
    f.push_back(out.force_device_n);
    if (i >= 520) {  // both fades done: v3 exactly
      EXPECT_FALSE(out.blending) << i;
      EXPECT_LT((out.force_device_n[0] - ref.force_device_n[0]).norm(), 1e-12) << i;
    }
  }
  EXPECT_EQ(proxy.version(), 3u);
  EXPECT_LE(worst, 1.0);
  // Tick to tick, nothing beyond the sweep's own change plus the fades' share.
  double step = 0.0;
  for (std::size_t i = 1; i < f.size(); ++i) {
    for (int k = 0; k < 2; ++k) step = std::max(step, (f[i][k] - f[i - 1][k]).norm());
  }
  EXPECT_LT(step, 0.1);
}

TEST(ModelFade, AStifferModelWaitsForEnergyToPayForIt) {
  const JointModelParams soft = healthyIndexMcp();
  const JointModelParams stiff = stiffer(2, 2.0);
  const JointModel geom(soft);
  const PerFinger<Vec3> held = geom.gripFromAngles(Vec3(degToRad(60.0), 0.0, 0.0), 0.008);
  JointProxy proxy(soft, 200 * kNsPerMs);
  JointProxy only_soft(soft);
  proxy.render(held, 0);
  only_soft.render(held, 0);
  proxy.setModel(stiff);
  const double dv = JointModel(stiff).potentialEnergyJ(geom.anglesFromGrip(held)) -
                    JointModel(soft).potentialEnergyJ(geom.anglesFromGrip(held));
  ASSERT_GT(dv, 0.0);
  // No budget: the joint held at 60 deg keeps the old stiffness (for up to kEnergyWaitNs).
  for (int i = 1; i <= 1000; ++i) {
    proxy.setEnergyBudget(0.0);
    const ProxyOutput out = proxy.render(held, i * kNsPerMs);
    EXPECT_TRUE(out.blending);
    EXPECT_LE(out.blend_energy_j, 0.0);
    EXPECT_LT(
        (out.force_device_n[0] - only_soft.render(held, i * kNsPerMs).force_device_n[0]).norm(),
        1e-12);
  }
  // Half the difference paid: half way, and the energy spent never exceeds what was given.
  double spent = 0.0;
  proxy.setEnergyBudget(0.5 * dv);
  for (int i = 1001; i <= 1400; ++i) {
    const ProxyOutput out = proxy.render(held, i * kNsPerMs);
    spent += out.blend_energy_j;
    EXPECT_EQ(out.unpaid_energy_j, 0.0);
  }
  EXPECT_NEAR(spent, 0.5 * dv, 1e-9 + 1e-6 * dv);
  EXPECT_TRUE(proxy.blending());
  proxy.setEnergyBudget(dv);
  for (int i = 1401; i <= 1700; ++i) proxy.render(held, i * kNsPerMs);
  EXPECT_FALSE(proxy.blending());
}

TEST(ModelFade, AStarvedStifferModelFadesInAfterTheWaitUnderTheStepBound) {
  const JointModelParams soft = healthyIndexMcp();
  const JointModelParams stiff = stiffer(2, 2.0);
  const JointModel geom(soft);
  const PerFinger<Vec3> held = geom.gripFromAngles(Vec3(degToRad(60.0), 0.0, 0.0), 0.008);
  JointProxy proxy(soft, 200 * kNsPerMs);
  proxy.render(held, 0);
  proxy.setModel(stiff);
  const int wait_ms = static_cast<int>(JointProxy::kEnergyWaitNs / kNsPerMs);
  int i = 1;
  for (; i <= wait_ms; ++i) {
    proxy.setEnergyBudget(0.0);
    const ProxyOutput out = proxy.render(held, i * kNsPerMs);
    EXPECT_LE(out.blend_energy_j, 0.0) << i;
    EXPECT_EQ(out.unpaid_energy_j, 0.0) << i;
  }
  EXPECT_TRUE(proxy.blending());
  double prev = proxy.render(held, i * kNsPerMs).force_device_n[0].norm();
  double added = 0.0, unpaid = 0.0;
  for (++i; i < wait_ms + 2000 && proxy.blending(); ++i) {
    proxy.setEnergyBudget(0.0);
    const ProxyOutput out = proxy.render(held, i * kNsPerMs);
    const double f = out.force_device_n[0].norm();
    EXPECT_LE(std::abs(f - prev), JointProxy::updateStepBoundN(f) + 1e-9);
    prev = f;
    added += out.blend_energy_j;
    unpaid += out.unpaid_energy_j;
  }
  EXPECT_FALSE(proxy.blending()) << "the stiffer model is rendered in the end";
  // Nothing paid for it: all it added is reported as unpaid (the loop's health counts it).
  EXPECT_GT(unpaid, 0.0);
  EXPECT_NEAR(unpaid, added, 1e-12);
  EXPECT_EQ(proxy.version(), 2u);
}

TEST(ModelFade, ASofterModelReleasesEnergyAndFadesWithoutBudget) {
  const JointModelParams stiff = stiffer(1, 2.0);
  const JointModelParams soft = stiffer(2, 1.0);
  const JointModel geom(stiff);
  JointProxy proxy(stiff, 200 * kNsPerMs);
  int i = 0;
  proxy.setModel(soft);
  for (; i < 1000 && (i == 0 || proxy.blending()); ++i) {
    proxy.setEnergyBudget(0.0);
    const ProxyOutput out = proxy.render(sweep(geom, i * kNsPerMs), i * kNsPerMs);
    EXPECT_LE(out.blend_energy_j, 1e-15);
  }
  EXPECT_FALSE(proxy.blending());
  EXPECT_LE(i, 202);
}

JointModelParams corrected(uint32_t version, const Vec3& offset_deg) {
  JointModelParams p = healthyIndexMcp();
  p.version = version;
  p.grip_offset_rad = offset_deg * (kPi / 180.0);
  return p;
}

TEST(ModelFade, TheProxyRendersAtTheThimblesAnglesPlusTheServersGripOffset) {
  const JointModelParams p = corrected(2, Vec3(-4.0, 1.0, 2.5));
  const JointModel m(p);
  const JointModel plain(healthyIndexMcp());
  const Vec3 a(degToRad(30.0), degToRad(2.0), degToRad(-3.0));
  const PerFinger<Vec3> grip = plain.gripFromAngles(a, 0.008);
  EXPECT_LT((m.proxyAngles(grip) - (a + p.grip_offset_rad)).norm(), 1e-9);
  JointProxy proxy(p);
  const ProxyOutput out = proxy.render(grip, 0);
  EXPECT_LT((out.angles_rad - (a + p.grip_offset_rad)).norm(), 1e-9);
  // The force is the joint's at the corrected angles: 26 deg of flexion, not 30.
  const Vec3 torque = m.passiveTorqueNm(a + p.grip_offset_rad, Vec3::Zero());
  EXPECT_LT((out.torque_ref_nm - torque).norm(), 1e-12);
}

TEST(ModelFade, ADriftCorrectionFadesInUnderTheStepBoundWithoutARateSpike) {
  // The server moves the rendered joint 4 deg toward where its hand is while the student
  // mobilizes: the correction is a model version like any other.
  const JointModelParams v1 = healthyIndexMcp();
  const JointModelParams v2 = corrected(2, Vec3(-4.0, 0.0, 1.5));
  const JointModel geom(v1);
  JointProxy proxy(v1, 200 * kNsPerMs);
  JointProxy only_v2(v2, 200 * kNsPerMs);
  std::vector<double> f;
  double worst = 0.0;
  for (int i = 0; i < 1500; ++i) {
    const int64_t t = i * kNsPerMs;
    if (i == 300) proxy.setModel(v2);
    const ProxyOutput out = proxy.render(sweep(geom, t), t);
    const ProxyOutput ref = only_v2.render(sweep(geom, t), t);
    worst = std::max(worst, out.update_step_n / updateBound(out));
    f.push_back(out.force_device_n[1].norm());
    if (i >= 1000) {
      ASSERT_FALSE(out.blending) << i;
      EXPECT_LT((out.force_device_n[1] - ref.force_device_n[1]).norm(), 1e-12) << i;
      EXPECT_LT((out.angles_rad - ref.angles_rad).norm(), 1e-12) << i;
    }
  }
  EXPECT_LE(worst, 1.0);
  EXPECT_GT(worst, 0.0);
  // Around the switch the force moves no faster than the sweep alone makes it move (the
  // rates come from the thimbles: a new offset adds no spurious speed to the damping term).
  double sweep_step = 0.0, fade_step = 0.0;
  for (std::size_t i = 1; i < f.size(); ++i) {
    const double d = std::abs(f[i] - f[i - 1]);
    if (i >= 300 && i < 520) {
      fade_step = std::max(fade_step, d);
    } else {
      sweep_step = std::max(sweep_step, d);
    }
  }
  EXPECT_LT(fade_step, sweep_step + 0.1);
}

TEST(ModelFade, ADriftCorrectionIntoTheJointWaitsForEnergyLikeAStifferModel) {
  // Held at 60 deg of flexion: a correction of +3 deg renders the joint further in, where it
  // stores more energy. With no budget the old rendering stays (for up to kEnergyWaitNs).
  const JointModelParams v1 = healthyIndexMcp();
  const JointModelParams v2 = corrected(2, Vec3(3.0, 0.0, 0.0));
  const JointModel geom(v1);
  const PerFinger<Vec3> held = geom.gripFromAngles(Vec3(degToRad(60.0), 0.0, 0.0), 0.008);
  JointProxy proxy(v1, 200 * kNsPerMs);
  const ProxyOutput before = proxy.render(held, 0);
  proxy.setModel(v2);
  for (int i = 1; i <= 500; ++i) {
    proxy.setEnergyBudget(0.0);
    const ProxyOutput out = proxy.render(held, i * kNsPerMs);
    EXPECT_LE(out.blend_energy_j, 0.0);
    EXPECT_LT((out.force_device_n[1] - before.force_device_n[1]).norm(), 1e-12);
  }
  proxy.setEnergyBudget(1.0);
  for (int i = 501; i <= 1000; ++i) proxy.render(held, i * kNsPerMs);
  EXPECT_FALSE(proxy.blending());
  EXPECT_NEAR(radToDeg(proxy.render(held, 1001 * kNsPerMs).angles_rad[kFlexion]), 63.0, 1e-6);
}

TEST(ModelFade, TheEnergyWaitCountsFromTheFadesOwnStartOnAnyClock) {
  // A loop whose clock reads an hour: the 2 s wait must run from when this fade began, not
  // from the clock's zero.
  const JointModelParams soft = healthyIndexMcp();
  const JointModelParams stiff = stiffer(2, 2.0);
  const JointModel geom(soft);
  const PerFinger<Vec3> held = geom.gripFromAngles(Vec3(degToRad(60.0), 0.0, 0.0), 0.008);
  const int64_t t0 = 3600 * kNsPerS;
  JointProxy proxy(soft, 200 * kNsPerMs);
  proxy.render(held, t0);
  proxy.setModel(stiff);
  for (int i = 1; i <= 1000; ++i) {
    proxy.setEnergyBudget(0.0);
    const ProxyOutput out = proxy.render(held, t0 + i * kNsPerMs);
    EXPECT_LE(out.blend_energy_j, 0.0) << i;
    EXPECT_EQ(out.unpaid_energy_j, 0.0) << i;
  }
  EXPECT_TRUE(proxy.blending());
}

TEST(ModelFade, TheNewestVersionWinsEvenWhenItArrivesJustAfterAFade) {
  // v3 waits during v2's fade; v4 arrives in the moment after v2's fade ended and before v3
  // began: v4 is what is rendered in the end, not v3 after it.
  const JointModelParams v1 = healthyIndexMcp();
  const JointModelParams v2 = stiffer(2, 1.5);
  const JointModelParams v3 = stiffer(3, 0.5);
  const JointModelParams v4 = stiffer(4, 1.2);
  const JointModel geom(v1);
  JointProxy proxy(v1, 10 * kNsPerMs);
  int64_t t = 0;
  proxy.render(sweep(geom, t), t);
  proxy.setModel(v2);
  auto tick = [&] {
    t += kNsPerMs;
    proxy.render(sweep(geom, t), t);
  };
  tick();
  ASSERT_TRUE(proxy.blending());
  proxy.setModel(v3);  // mid-fade: waits
  while (proxy.blending()) tick();
  proxy.setModel(v4);
  for (int i = 0; i < 2000; ++i) tick();
  EXPECT_FALSE(proxy.blending());
  EXPECT_EQ(proxy.version(), 4u);
}

}  // namespace
}  // namespace telehand
