// The web's tissue model: Hunt–Crossley normal force, stick–slip friction, the patch, the
// proxy's fade and its passivity on closed paths.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "telehand/core/tissue_model.h"
#include "telehand/core/web_guide.h"

namespace telehand {
namespace {

constexpr double kPi = 3.14159265358979323846;

// Thumb centre that presses the dorsal surface `depth` deep at (x, y) of the web frame.
Vec3 thumbAt(const TissueModel& m, double x, double y, double depth) {
  const TissueParams& p = m.params();
  return m.fromWeb(Vec3(x, y, 0.5 * p.thickness_m + p.pad_radius_m - depth));
}
Vec3 indexAt(const TissueModel& m, double x, double y, double depth) {
  const TissueParams& p = m.params();
  return m.fromWeb(Vec3(x, y, -(0.5 * p.thickness_m + p.pad_radius_m) + depth));
}

TEST(TissueModel, NormalForceIsHuntCrossleyAndNeverPulls) {
  const TissueModel m(tissueCase("healthy"));
  const TissueParams& p = m.params();
  for (double d : {0.001, 0.004, 0.006, 0.01}) {
    const double f = p.stiffness_n_per_m_pow * std::pow(d, p.exponent);
    EXPECT_NEAR(m.normalForceN(d, 0.0), f, 1e-9 * f);
    EXPECT_NEAR(m.normalForceN(d, 0.05), f * (1.0 + p.damping_s_per_m * 0.05), 1e-9 * f);
    EXPECT_NEAR(m.depthForForce(f), d, 1e-12);
  }
  EXPECT_EQ(m.normalForceN(0.0, 1.0), 0.0);       // touching: no step
  EXPECT_EQ(m.normalForceN(-0.01, 0.0), 0.0);     // apart
  EXPECT_EQ(m.normalForceN(0.005, -100.0), 0.0);  // withdrawing fast: releases, never pulls
  // The healthy web holds the paper's 10 N at a press of about 6 mm.
  EXPECT_NEAR(m.depthForForce(10.0), 0.006, 0.0005);
}

TEST(TissueModel, ThumbAndIndexArePushedOutOfTheirSurfaces) {
  TissueParams p = tissueCase("healthy");
  p.orientation = Quat(Eigen::AngleAxisd(0.4, Vec3(1, 2, 3).normalized()));
  p.origin_m = Vec3(0.01, -0.02, 0.03);
  const TissueModel m(p);
  TissueAnchor a0, a1;
  const TissueContact t = tissueContact(m, kThumb, thumbAt(m, 0, 0, 0.005), Vec3::Zero(), a0);
  const TissueContact i = tissueContact(m, kIndex, indexAt(m, 0, 0, 0.005), Vec3::Zero(), a1);
  EXPECT_NEAR(t.depth_m, 0.005, 1e-12);
  EXPECT_NEAR(i.depth_m, 0.005, 1e-12);
  EXPECT_GT(t.normal_n.dot(m.normalAxis()), 0.0);  // thumb pushed dorsally
  EXPECT_LT(i.normal_n.dot(m.normalAxis()), 0.0);  // index pushed palmarly
  EXPECT_NEAR(t.normal_n.norm(), m.normalForceN(0.005, 0.0), 1e-9);
  // Outside the web's area: nothing.
  TissueAnchor a2;
  const TissueContact off = tissueContact(m, kThumb, thumbAt(m, 0.05, 0, 0.005), Vec3::Zero(), a2);
  EXPECT_EQ(off.depth_m, 0.0);
  EXPECT_EQ(off.force().norm(), 0.0);
}

TEST(TissueModel, SkinSticksUntilTheStaticLimitThenSlipsAtTheKineticOne) {
  TissueParams p = tissueCase("healthy");
  p.viscous_n_s_per_m = 0.0;
  const TissueModel m(p);
  TissueAnchor a;
  const double depth = 0.006;
  const double fn = m.normalForceN(depth, 0.0);
  tissueContact(m, kThumb, thumbAt(m, 0, 0, depth), Vec3::Zero(), a);
  double last_ft = 0.0;
  bool slipped = false;
  double x = 0.0;
  for (int i = 1; i <= 2000 && !slipped; ++i) {
    x = 1e-5 * i;  // 10 µm steps along x
    const TissueContact c = tissueContact(m, kThumb, thumbAt(m, x, 0, depth), Vec3::Zero(), a);
    const double ft = c.tangential_n.norm();
    if (c.sticking) {
      EXPECT_NEAR(ft, p.lateral_stiffness_n_per_m * x, 1e-9);  // the skin's spring
      EXPECT_LE(ft, p.mu_static * fn + 1e-9);
      // It pulls the finger back toward where it touched.
      EXPECT_LT(c.tangential_n.dot(m.params().orientation * Vec3::UnitX()), 0.0);
    } else {
      slipped = true;
      EXPECT_GT(last_ft, 0.9 * p.mu_static * fn);
      EXPECT_NEAR(ft, p.mu_kinetic * fn, 1e-9);  // the drop of stick–slip
    }
    last_ft = ft;
  }
  ASSERT_TRUE(slipped);
  // Dragged on, the skin sticks and slips again and again: the force saw-tooths between the
  // two limits, a slip every (mu_static - mu_kinetic)·F_n / k_t of travel.
  int slips = 0;
  for (int i = 1; i <= 1000; ++i) {
    const TissueContact c =
        tissueContact(m, kThumb, thumbAt(m, x + 1e-5 * i, 0, depth), Vec3::Zero(), a);
    EXPECT_LE(c.tangential_n.norm(), p.mu_static * fn + 1e-9);
    EXPECT_GE(c.tangential_n.norm(), p.mu_kinetic * fn - 1e-9);
    if (!c.sticking) ++slips;
  }
  const double period = (p.mu_static - p.mu_kinetic) * fn / p.lateral_stiffness_n_per_m;
  EXPECT_NEAR(slips, 0.01 / period, 1.5);
  // Lifting off forgets the anchor.
  tissueContact(m, kThumb, thumbAt(m, 0.0, 0, -0.001), Vec3::Zero(), a);
  EXPECT_FALSE(a.attached);
}

TEST(TissueModel, ThePatchIsStifferAndStickierInsideAndBlendsAtItsRim) {
  const TissueModel m(tissueCase("scar"));
  const TissueParams& p = m.params();
  ASSERT_GT(p.patch_radius_m, 0.0);
  EXPECT_NEAR(m.normalForceN(0.004, 0, p.patch_x_m, p.patch_y_m),
              p.patch_stiffness_factor * m.normalForceN(0.004, 0, -0.015, 0.015), 1e-9);
  double last = m.normalForceN(0.004, 0, p.patch_x_m, p.patch_y_m);
  for (int i = 1; i <= 200; ++i) {  // walking out across the rim: continuous, decreasing
    const double r = 1.5 * p.patch_radius_m * i / 200.0;
    const double f = m.normalForceN(0.004, 0, p.patch_x_m + r, p.patch_y_m);
    EXPECT_LE(f, last + 1e-12);
    EXPECT_LT(last - f, 0.05 * last);
    last = f;
  }
}

TEST(TissueModel, CasesAreValidAndDifferAsDocumented) {
  for (const char* name : {"healthy", "oedema", "scar", "hypertonic"}) {
    const TissueParams p = tissueCase(name);
    EXPECT_EQ(invalidTissueParam(p), nullptr) << name << ": " << invalidTissueParam(p);
  }
  const TissueModel healthy(tissueCase("healthy")), oedema(tissueCase("oedema")),
      hyper(tissueCase("hypertonic"));
  // Oedema: softer at a light touch, stiffer deep; hypertonic: stiffer throughout.
  EXPECT_LT(oedema.normalForceN(0.002, 0), healthy.normalForceN(0.002, 0));
  EXPECT_GT(oedema.normalForceN(0.012, 0), healthy.normalForceN(0.012, 0));
  EXPECT_GT(hyper.normalForceN(0.003, 0), healthy.normalForceN(0.003, 0));
  EXPECT_LT(hyper.depthForForce(10.0), healthy.depthForForce(10.0));
  TissueParams bad = tissueCase("healthy");
  bad.mu_kinetic = bad.mu_static + 0.1;
  EXPECT_STREQ(invalidTissueParam(bad), "mu_kinetic");
  bad = tissueCase("healthy");
  bad.exponent = std::nan("");
  EXPECT_STREQ(invalidTissueParam(bad), "exponent");
  Technique t;
  EXPECT_TRUE(parseTechnique("massage", &t));
  EXPECT_EQ(t, Technique::kMassage);
  EXPECT_FALSE(parseTechnique("Massage", &t));
}

// A finger that circles on the web and comes back to where it started has received no energy
// from it: the rendered web is passive (the work the finger did on it is ≥ 0), for every case,
// random circles and random orientations of the web.
TEST(TissueProxy, ClosedCirclesDrawNoEnergyFromTheWeb) {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (const char* name : {"healthy", "oedema", "scar", "hypertonic"}) {
    for (int trial = 0; trial < 5; ++trial) {
      TissueParams p = tissueCase(name);
      p.orientation =
          Quat(Eigen::AngleAxisd(u(rng) * kPi, Vec3(u(rng), u(rng), u(rng) + 0.1).normalized()));
      TissueProxy proxy(p, 0.25, 0);
      const TissueModel& m = proxy.model();
      const double radius = 0.002 + 0.006 * u(rng), hz = 0.5 + 2.5 * u(rng);
      const double depth = 0.003 + 0.006 * u(rng);
      double work = 0.0;  // done by the finger on the web (device J)
      PerFinger<Vec3> last{thumbAt(m, radius, 0, 0), indexAt(m, radius, 0, 0)};
      PerFinger<Vec3> force{Vec3::Zero(), Vec3::Zero()};
      const int n = static_cast<int>(3.0 / hz * 1000);
      for (int i = 0; i <= n; ++i) {
        const double t = i * 1e-3;
        const double ramp = std::min(1.0, std::sin(kPi * t * hz / 3.0) * 3.0);  // in, out
        const double ph = 2 * kPi * hz * t;
        const double d = depth * std::max(0.0, ramp) - 0.001;
        PerFinger<Vec3> pos{thumbAt(m, radius * std::cos(ph), radius * std::sin(ph), d),
                            indexAt(m, radius * std::cos(ph), radius * std::sin(ph), d)};
        for (int k = 0; k < 2; ++k) work -= force[k].dot(pos[k] - last[k]);
        const TissueOutput out = proxy.render(pos, static_cast<int64_t>(t * 1e9));
        for (int k = 0; k < 2; ++k) {
          force[k] = out.force_device_n[k];
          ASSERT_TRUE(allFinite(force[k]));
        }
        last = pos;
      }
      // Zero-order hold adds at most a sliver; the web dissipates far more.
      EXPECT_GT(work, -1e-4) << name << " trial " << trial;
    }
  }
}

TEST(TissueProxy, ANewParameterSetFadesInWithoutAStep) {
  const TissueParams a = tissueCase("healthy");
  const TissueParams b = tissueCase("hypertonic");
  TissueProxy proxy(a, 0.25, 200'000'000);
  const TissueModel ma(a);
  const PerFinger<Vec3> pos{thumbAt(ma, 0, 0, 0.005), indexAt(ma, 0, 0, 0.005)};
  double last = proxy.render(pos, 0).force_device_n[0].norm();
  proxy.setParams(b, 0.25);
  double largest_step = 0.0;
  TissueOutput out;
  for (int i = 1; i <= 300; ++i) {
    out = proxy.render(pos, int64_t{i} * 1'000'000);
    const double f = out.force_device_n[0].norm();
    largest_step = std::max(largest_step, std::abs(f - last));
    last = f;
  }
  const double gap = 0.25 * (TissueModel(b).normalForceN(0.005, 0) - ma.normalForceN(0.005, 0));
  EXPECT_GT(std::abs(gap), 0.5);
  EXPECT_LT(largest_step, std::abs(gap) / 150.0);  // spread over the 200 ms fade
  EXPECT_FALSE(out.blending);
  EXPECT_NEAR(last, 0.25 * TissueModel(b).normalForceN(0.005, 0), 1e-6);
}

}  // namespace
}  // namespace telehand

namespace telehand {
namespace {

// A pair of free thimbles (nothing but their mass and a little damping, off the web) led by a
// massage guide alone goes round the guide's circle at its laps per second; a guide replaced
// mid-lap fades over 200 ms without a step; no guide, no force.
TEST(WebGuide, LeadsFreeThimblesRoundTheCircleAndFadesWithoutAStep) {
  TissueParams web = tissueCase("healthy");
  web.orientation = Quat(Eigen::AngleAxisd(0.4, Vec3(1.0, 2.0, 0.5).normalized()));
  web.origin_m = Vec3(0.01, -0.02, 0.03);
  const TissueModel model(web);
  for (const double freq : {1.2, -2.0}) {
    GuideParams g;
    g.authority = 1.0;
    g.stiffness_n_per_deg = 1.0;  // N/mm for a massage guide
    g.period_s = 1.0 / std::abs(freq);
    const double r = 0.005;
    for (int k = 0; k < GuideParams::kPoints; ++k) {
      const double a = (freq < 0 ? -1.0 : 1.0) * 2.0 * kPi * k / GuideParams::kPoints;
      g.path_rad[static_cast<std::size_t>(k)] = Vec3(0.001 + r * std::cos(a), r * std::sin(a), 0);
    }
    WebGuide guide;
    EXPECT_EQ(
        guide.force(model, {Vec3::Zero(), Vec3::Zero()}, {Vec3::Zero(), Vec3::Zero()}, 0, 0.25)[0]
            .norm(),
        0.0);
    guide.set(g, 0);
    // Off the web: 12 mm above the dorsal side and below the palmar one.
    PerFinger<Vec3> p{model.fromWeb(Vec3(0.001 + r, 0, -0.02)),
                      model.fromWeb(Vec3(0.001 + r, 0, 0.02))};
    PerFinger<Vec3> v{Vec3::Zero(), Vec3::Zero()};
    const double mass = 0.05, damping = 2.0, scale = 0.25;
    double worst = 0.0, angle = 0.0, last_angle = 0.0;
    bool first = true;
    const int64_t dt = 1'000'000;
    for (int64_t t = 0; t <= 6'000'000'000; t += dt) {
      const PerFinger<Vec3> f = guide.force(model, p, v, t, scale);
      for (int k = 0; k < 2; ++k) {
        v[k] += (f[k] - damping * scale * v[k]) / mass * 1e-3;
        p[k] += v[k] * 1e-3;
      }
      const Vec3 mid = model.toWeb(0.5 * (p[0] + p[1]));
      Vec3 target, tv;
      WebGuide::target(g, static_cast<double>(t) * 1e-9, target, tv);
      if (t >= 2'000'000'000) {
        worst = std::max(worst, std::hypot(mid.x() - target.x(), mid.y() - target.y()));
        const double a = std::atan2(mid.y(), mid.x() - 0.001);
        if (!first) {
          double d = a - last_angle;
          if (d > kPi) d -= 2 * kPi;
          if (d < -kPi) d += 2 * kPi;
          angle += d;
        }
        first = false;
        last_angle = a;
      }
    }
    const double laps_per_s = angle / (2 * kPi) / 4.0;
    EXPECT_NEAR(laps_per_s, freq, 0.02) << "led round at the guide's rate";
    EXPECT_LT(worst, 0.0015) << "within 1.5 mm of the guide's point";
  }
  // A replaced guide fades: from one circle to a circle 3 mm wider, the force moves in steps
  // no larger than 200 ms of fade allow.
  GuideParams a, b;
  a.authority = b.authority = 1.0;
  a.period_s = b.period_s = 1.0;
  for (int k = 0; k < GuideParams::kPoints; ++k) {
    const double ang = 2.0 * kPi * k / GuideParams::kPoints;
    a.path_rad[static_cast<std::size_t>(k)] = Vec3(0.004 * std::cos(ang), 0.004 * std::sin(ang), 0);
    b.path_rad[static_cast<std::size_t>(k)] = Vec3(0.007 * std::cos(ang), 0.007 * std::sin(ang), 0);
  }
  WebGuide guide;
  guide.set(a, 0);
  const PerFinger<Vec3> still{model.fromWeb(Vec3(0, 0, -0.02)), model.fromWeb(Vec3(0, 0, 0.02))};
  const PerFinger<Vec3> zero{Vec3::Zero(), Vec3::Zero()};
  Vec3 last = guide.force(model, still, zero, 500'000'000, 0.25)[0];
  guide.set(b, 500'000'000);
  double step = 0.0;
  for (int64_t t = 500'000'000; t <= 800'000'000; t += 1'000'000) {
    const Vec3 f = guide.force(model, still, zero, t, 0.25)[0];
    step = std::max(step, (f - last).norm());
    last = f;
  }
  EXPECT_LT(step, 0.05) << "a new guide fades in, the old one out";
  // Taken away: it fades out too, then nothing.
  guide.set(GuideParams{}, 800'000'000);
  EXPECT_GT(guide.force(model, still, zero, 850'000'000, 0.25)[0].norm(), 0.0);
  EXPECT_EQ(guide.force(model, still, zero, 1'100'000'000, 0.25)[0].norm(), 0.0);
}

}  // namespace
}  // namespace telehand
