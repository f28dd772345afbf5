// The web's tissue model: Hunt–Crossley normal force, stick–slip friction, the patch, the
// proxy's fade and its passivity on closed paths, its state saved and restored, and its skin
// re-anchored from another proxy's force.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <vector>

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

/// Both pads `depth` deep, circling `radius` at `hz` on the web, with a slow press wander and
/// a little jitter (as a hand does): sample `i` of it (1 ms apart). On a circle of 8 mm the
/// healthy skin's static limit (6.9 mm of stretch at 10 N) is passed all the way round: it
/// sticks and slips.
PerFinger<Vec3> circling(const TissueModel& m, int i, double radius = 0.008, double hz = 1.5,
                         double depth = 0.006) {
  const double t = i * 1e-3;
  const double ph = 2 * kPi * hz * t;
  const double jitter = 2e-5 * std::sin(i * 1.7) * std::cos(i * 0.31);
  const double d = depth + 0.0005 * std::sin(2 * kPi * 0.4 * t);
  const double x = radius * std::cos(ph) + jitter, y = radius * std::sin(ph) - jitter;
  return {thumbAt(m, x, y, d), indexAt(m, x, y, d)};
}

TEST(TissueProxy, ARestoredStateGoesOnAsTheProxyItWasSavedFrom) {
  for (const char* name : {"healthy", "scar"}) {
    const TissueParams p = tissueCase(name);
    TissueProxy a(p, 0.25);
    const TissueModel m(p);
    int slips = 0;
    for (int i = 0; i < 1500; ++i) {
      const TissueOutput o = a.render(circling(m, i), int64_t{i} * 1'000'000);
      slips += o.contact[0].depth_m > 0.0 && !o.contact[0].sticking;
    }
    ASSERT_GT(slips, 10) << "the skin slips on the circle: the anchors are state to keep";
    std::vector<double> saved;
    a.saveState(saved);
    ASSERT_EQ(saved.size(), TissueProxy::kStateSize);
    TissueProxy b(p, 0.25);
    ASSERT_TRUE(b.restoreState(saved));
    TissueProxy fresh(p, 0.25);
    double largest = 0.0, fresh_largest = 0.0;
    for (int i = 1500; i < 3000; ++i) {
      const auto pos = circling(m, i);
      const TissueOutput oa = a.render(pos, int64_t{i} * 1'000'000);
      const TissueOutput ob = b.render(pos, int64_t{i} * 1'000'000);
      const TissueOutput of = fresh.render(pos, int64_t{i} * 1'000'000);
      for (int k = 0; k < 2; ++k) {
        largest = std::max(largest, (oa.contact[k].force() - ob.contact[k].force()).norm());
        fresh_largest =
            std::max(fresh_largest, (oa.contact[k].force() - of.contact[k].force()).norm());
      }
    }
    EXPECT_EQ(largest, 0.0) << name;
    EXPECT_GT(fresh_largest, 1.0) << name << ": a proxy started afresh there differs";
  }
}

TEST(TissueProxy, ABadStateIsRefusedWithNothingChanged) {
  const TissueParams p = tissueCase("healthy");
  const TissueModel m(p);
  TissueProxy a(p, 0.25);
  for (int i = 0; i < 500; ++i) a.render(circling(m, i), int64_t{i} * 1'000'000);
  std::vector<double> saved;
  a.saveState(saved);
  TissueProxy b(p, 0.25);
  for (int i = 0; i < 300; ++i) b.render(circling(m, i, 0.005), int64_t{i} * 1'000'000);
  std::vector<double> before;
  b.saveState(before);
  const auto refused = [&](std::vector<double> s, const char* what) {
    EXPECT_FALSE(b.restoreState(s)) << what;
    std::vector<double> now;
    b.saveState(now);
    EXPECT_EQ(now, before) << what;
  };
  refused({}, "empty");
  refused(std::vector<double>(saved.begin(), saved.end() - 1), "truncated");
  auto s = saved;
  s.push_back(0.0);
  refused(s, "too long");
  const double nan = std::numeric_limits<double>::quiet_NaN();
  for (std::size_t i = 0; i < saved.size(); ++i) {
    s = saved;
    s[i] = nan;
    refused(s, "a NaN");
    s[i] = std::numeric_limits<double>::infinity();
    refused(s, "an infinity");
  }
  s = saved;
  s[0] = 1.0;
  refused(s, "another magic number");
  s = saved;
  s[3] = 0.5;  // the thumb's anchor neither attached nor not
  refused(s, "a flag");
  s = saved;
  s[1] = 1e3;  // an anchor a kilometre off
  refused(s, "an anchor");
  s = saved;
  s[8] = 0.5;  // a time that is not a whole number of nanoseconds
  refused(s, "a time");
  s = saved;
  s[10] = 5.0;  // a thimble 5 m from the device
  refused(s, "a position");
  s = saved;
  s[s.size() - 9] = -1.0;  // the current set's mu_static
  refused(s, "a parameter");
  EXPECT_TRUE(b.restoreState(saved));
}

TEST(TissueProxy, AStateSavedUnderAnotherModelFadesIntoTheCurrentOne) {
  const TissueParams healthy = tissueCase("healthy"), hyper = tissueCase("hypertonic");
  const TissueModel m(healthy);
  TissueProxy a(healthy, 0.25);
  for (int i = 0; i < 500; ++i) a.render(circling(m, i), int64_t{i} * 1'000'000);
  std::vector<double> saved;
  a.saveState(saved);
  TissueProxy b(hyper, 0.25);
  ASSERT_TRUE(b.restoreState(saved));
  const TissueOutput o = b.render(circling(m, 500), 500'000'000);
  EXPECT_TRUE(o.blending) << "from the saved model to the current one, without a step";
}

TEST(TissueProxy, ResyncingTakesTheOtherProxysStateWithinTheModelsBounds) {
  const TissueParams p = tissueCase("healthy");
  const TissueModel m(p);
  // The client's proxy renders every sample; this one misses 30 of them and renders the
  // straight line between the ones either side instead.
  TissueProxy client(p, 0.25), server(p, 0.25);
  TissueOutput c, s;
  for (int i = 0; i < 730; ++i) {
    c = client.render(circling(m, i), int64_t{i} * 1'000'000);
    if (i >= 700 && i < 730) {
      const auto a = circling(m, 699), b = circling(m, 730);
      const double w = (i - 699) / 31.0;
      s = server.render({a[0] + w * (b[0] - a[0]), a[1] + w * (b[1] - a[1])},
                        int64_t{i} * 1'000'000);
    } else {
      s = server.render(circling(m, i), int64_t{i} * 1'000'000);
    }
  }
  // Back on the client's samples: the skins have parted.
  s = server.render(circling(m, 730), 730'000'000);
  c = client.render(circling(m, 730), 730'000'000);
  const Vec3 axis = m.normalAxis();
  const auto tangential = [&](const Vec3& f) { return Vec3(f - f.dot(axis) * axis); };
  ASSERT_GT((tangential(s.contact[0].force()) - tangential(c.contact[0].force())).norm(), 1e-3)
      << "the gap left the skins apart";
  for (int k = 0; k < 2; ++k) ASSERT_TRUE(server.resync(k, c.contact[k].force()));
  s = server.renderLast();
  for (int k = 0; k < 2; ++k) {
    EXPECT_LT((s.contact[k].force() - c.contact[k].force()).norm(), 1e-9);
    EXPECT_EQ(s.contact[k].depth_m, c.contact[k].depth_m);
  }
  // And they go on together: the velocity filter's depth rate and the anchors are the
  // client's (the filter's sideways velocity still remembers the straight line a while).
  double normal_after = 0.0;
  for (int i = 731; i < 760; ++i) {
    s = server.render(circling(m, i), int64_t{i} * 1'000'000);
    c = client.render(circling(m, i), int64_t{i} * 1'000'000);
    for (int k = 0; k < 2; ++k) {
      normal_after =
          std::max(normal_after, std::abs((s.contact[k].force() - c.contact[k].force()).dot(axis)));
    }
  }
  EXPECT_LT(normal_after, 1e-9);

  // A force no skin could pull with: the stretch stops at the static limit, and the next
  // render sticks there.
  ASSERT_TRUE(server.resync(0, Vec3(90.0, -90.0, 0.0)));
  s = server.renderLast();
  const double fn = s.contact[0].normal_n.norm();
  EXPECT_TRUE(s.contact[0].sticking);
  // The spring pulls with at most mu_static * F_n; the skin's viscous drag adds b * |v|
  // (the thimbles move under 0.1 m/s here).
  EXPECT_LE(s.contact[0].tangential_n.norm(), p.mu_static * fn + p.viscous_n_s_per_m * 0.1);

  // A normal force no press at this depth could make: the depth rate moves at most
  // kMaxRateStepMps.
  const double before_n = s.contact[0].normal_n.norm();
  const double elastic =
      m.normalForceN(s.contact[0].depth_m, 0.0, s.contact[0].point_w.x(), s.contact[0].point_w.y());
  ASSERT_TRUE(server.resync(0, Vec3(0.0, 0.0, 90.0)));
  s = server.renderLast();
  EXPECT_NEAR(s.contact[0].normal_n.norm() - before_n,
              elastic * p.damping_s_per_m * TissueProxy::kMaxRateStepMps, 1e-6);

  // Nothing taken from a force that is not a number, for a finger off the web, or mid-fade.
  const auto unchanged = [&](int finger, const Vec3& f, const char* what) {
    std::vector<double> before, after;
    server.saveState(before);
    EXPECT_FALSE(server.resync(finger, f)) << what;
    server.saveState(after);
    EXPECT_EQ(before, after) << what;
  };
  unchanged(0, Vec3(std::numeric_limits<double>::quiet_NaN(), 0, 0), "NaN");
  unchanged(2, Vec3::Zero(), "no such finger");
  server.render({thumbAt(m, 0, 0, -0.002), indexAt(m, 0, 0, -0.002)}, 760'000'000);
  unchanged(0, Vec3(1, 0, 0), "not pressing");
  server.render(circling(m, 761), 761'000'000);
  server.setParams(tissueCase("hypertonic"), 0.25);
  server.render(circling(m, 762), 762'000'000);
  unchanged(0, Vec3(1, 0, 0), "fading");
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
