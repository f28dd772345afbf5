// Assessment by exploration: the extremes reached per direction, the force there, and the
// comparison of a reassessment with its baseline.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "telehand/config/config.h"
#include "telehand/core/joint_model.h"
#include "telehand/server/session/exploration.h"
#include "telehand/server/session/hand_runner.h"

namespace telehand::server::session {
namespace {

using ::testing::AllOf;
using ::testing::HasSubstr;
using ::testing::Not;

Vec3 deg(double flexion, double abduction, double axial) {
  Vec3 a;
  a[kFlexion] = degToRad(flexion);
  a[kAbduction] = degToRad(abduction);
  a[kAxial] = degToRad(axial);
  return a;
}

const SessionStore::Reach& find(const std::vector<SessionStore::Reach>& rs,
                                const std::string& dir) {
  for (const auto& r : rs) {
    if (r.direction == dir) return r;
  }
  static const SessionStore::Reach kNone{"", "none", 0.0, 0.0};
  ADD_FAILURE() << "no reach for " << dir;
  return kNone;
}

const Vec3 kRest = Vec3::Zero();
/// Each pose below is held for a second: the filter on angles and forces has settled.
constexpr double kHeld = 1.0;

/// Per-axis forces (N at the lever arm, positive toward +angle).
Vec3 forces(double flexion, double abduction, double axial) {
  Vec3 f;
  f[kFlexion] = flexion;
  f[kAbduction] = abduction;
  f[kAxial] = axial;
  return f;
}

const SessionStore::Reach* maybe(const std::vector<SessionStore::Reach>& rs,
                                 const std::string& dir) {
  for (const auto& r : rs) {
    if (r.direction == dir) return &r;
  }
  return nullptr;
}

TEST(Exploration, RecordsTheExtremeOfEachDirectionAndItsAxisForce) {
  Exploration e;
  EXPECT_FALSE(e.active());
  e.begin("baseline");
  EXPECT_TRUE(e.active());
  EXPECT_EQ(e.phase(), "baseline");
  e.observe(deg(0, 0, 0), kRest, forces(0.5, 0, 0), true, kHeld);
  // Each direction's force is its own axis' force in its sense, whatever the other axes carry.
  e.observe(deg(60, 2, -1), kRest, forces(11.0, 30.0, -40.0), true, kHeld);  // flexion peak
  e.observe(deg(30, 0, 0), kRest, forces(4.0, 0, 0), true, kHeld);
  e.observe(deg(-30, -1, 1), kRest, forces(-6.0, 0, 0), true, kHeld);        // extension peak
  e.observe(deg(5, 15, 0), kRest, forces(9.0, 2.5, 0), true, kHeld);         // abduction peak
  e.observe(deg(5, -12, 0), kRest, forces(9.0, -2.0, 0), true, kHeld);       // adduction peak
  e.observe(deg(5, 0, 12), kRest, forces(9.0, 0, 7.0), true, kHeld);         // supination peak
  e.observe(deg(5, 0, -8), kRest, forces(9.0, 0, -5.0), true, kHeld);        // pronation peak
  e.observe(deg(59.9, 14.9, 11.9), kRest, forces(99, 99, 99), true, kHeld);  // short of three peaks
  const auto r = e.finish();
  EXPECT_FALSE(e.active());
  ASSERT_EQ(r.size(), 6u);
  // finish() returns them in kDirections order.
  for (std::size_t i = 0; i < r.size(); ++i) {
    EXPECT_EQ(r[i].direction, Exploration::kDirections[i]);
    EXPECT_EQ(r[i].phase, "baseline");
  }
  struct Want {
    const char* dir;
    double angle_deg, force_n;
  };
  for (const Want& w :
       {Want{"flexion", 60, 11}, Want{"extension", -30, 6}, Want{"abduction", 15, 2.5},
        Want{"adduction", -12, 2}, Want{"supination", 12, 7}, Want{"pronation", -8, 5}}) {
    const auto& got = find(r, w.dir);
    EXPECT_NEAR(got.angle_deg, w.angle_deg, 1e-9) << w.dir;
    EXPECT_EQ(got.force_n, w.force_n) << w.dir;
  }
}

TEST(Exploration, TheStartPoseAndAnUnheldSwingAreNoReach) {
  Exploration e;
  e.begin("baseline");
  // Before the pads close the finger swings toward rest from wherever it was: not held.
  e.observe(deg(40, 15, 10), kRest, forces(0, 0, 0), false, kHeld);
  e.observe(deg(-30, -15, -8), kRest, forces(0, 0, 0), false, kHeld);
  // The pads close on a flexed joint and hold it there: that pose is where the phase starts,
  // not a reach, however far from rest it is.
  e.observe(deg(30, 6, 0), kRest, forces(5.0, 1.0, 0), true, kHeld);
  e.observe(deg(31, 6.5, 0.5), kRest, forces(5.2, 1.1, 0.1), true, kHeld);  // within 2 deg of it
  EXPECT_TRUE(e.finish().empty());

  // From the same start, the student takes the joint back past rest into extension: that
  // direction is reached; flexion and abduction, never taken past the start pose, are not.
  e.begin("baseline");
  e.observe(deg(30, 6, 0), kRest, forces(5.0, 1.0, 0), true, kHeld);
  e.observe(deg(10, 6, 0), kRest, forces(1.0, 1.0, 0), true, kHeld);
  e.observe(deg(1.5, 6, 0), kRest, forces(0.1, 1.0, 0), true, kHeld);  // not 2 deg past rest yet
  EXPECT_TRUE(e.finish().empty());
  e.begin("baseline");
  e.observe(deg(30, 6, 0), kRest, forces(5.0, 1.0, 0), true, kHeld);
  e.observe(deg(-20, 6, 0), kRest, forces(-3.0, 1.0, 0), true, kHeld);
  const auto r = e.finish();
  ASSERT_EQ(r.size(), 1u);
  EXPECT_EQ(r[0].direction, "extension");
  EXPECT_NEAR(r[0].angle_deg, -20.0, 1e-9);
  EXPECT_EQ(r[0].force_n, 3.0);
}

TEST(Exploration, DirectionsAreTakenFromTheRestAngle) {
  // A joint resting in 45 deg of flexion (the stiff case): 30 deg is extension, 50 flexion.
  Exploration e;
  e.begin("baseline");
  const Vec3 rest = deg(45, 0, 0);
  e.observe(deg(45, 0, 0), rest, forces(0, 0, 0), true, kHeld);
  e.observe(deg(30, 0, 0), rest, forces(-8.0, 0, 0), true, kHeld);
  e.observe(deg(50, 0, 0), rest, forces(2.0, 0, 0), true, kHeld);
  const auto r = e.finish();
  ASSERT_EQ(r.size(), 2u);
  EXPECT_NEAR(find(r, "flexion").angle_deg, 50.0, 1e-9);
  EXPECT_NEAR(find(r, "extension").angle_deg, 30.0, 1e-9);
  EXPECT_EQ(find(r, "extension").force_n, 8.0);
}

TEST(Exploration, DirectionsNeverExploredAreNotReached) {
  Exploration e;
  e.begin("baseline");
  e.observe(deg(0, 0, 0), kRest, forces(0, 0, 0), true, kHeld);
  e.observe(deg(60, 0, 0), kRest, forces(11.0, 0, 0), true, kHeld);
  e.observe(deg(0, 0, 0), kRest, forces(0, 0, 0), true, kHeld);
  e.observe(deg(0, 0, 12), kRest, forces(0, 0, 7.0), true, kHeld);
  const auto r = e.finish();
  ASSERT_EQ(r.size(), 2u);
  EXPECT_EQ(r[0].direction, "flexion");
  EXPECT_EQ(r[1].direction, "supination");
  for (const char* dir : {"extension", "abduction", "adduction", "pronation"}) {
    EXPECT_EQ(maybe(r, dir), nullptr) << dir;
  }
  EXPECT_EQ(Exploration::summary(r, {}),
            "flexion 60.0 deg, extension not reached, abduction not reached, adduction not "
            "reached, supination 12.0 deg, pronation not reached");
}

TEST(Exploration, AnOvershootBrakedByThePadsIsNotTheReachNorItsForce) {
  // 1 ms steps: the pads carry the joint to 40 deg of flexion (10 N holding it), it overshoots
  // to 43 deg for 5 ms while they brake it (a force the other way), then it is held at 40.
  Exploration e;
  e.begin("baseline");
  for (int i = 0; i < 300; ++i) e.observe(deg(0, 0, 0), kRest, forces(0, 0, 0), true);
  for (int i = 1; i <= 400; ++i) {
    e.observe(deg(0.1 * i, 0, 0), kRest, forces(0.025 * i, 0, 0), true);
  }
  for (int i = 0; i < 5; ++i) e.observe(deg(43, 0, 0), kRest, forces(-5, 0, 0), true);
  for (int i = 0; i < 500; ++i) e.observe(deg(40, 0, 0), kRest, forces(10, 0, 0), true);
  const auto r = e.finish();
  ASSERT_EQ(r.size(), 1u);
  EXPECT_NEAR(r[0].angle_deg, 40.0, 0.1);
  EXPECT_NEAR(r[0].force_n, 10.0, 0.1);
}

TEST(Exploration, NothingObservedOrNotBegunGivesNoReaches) {
  Exploration e;
  e.observe(deg(50, 0, 0), kRest, forces(3, 0, 0), true, kHeld);  // before begin: ignored
  EXPECT_TRUE(e.finish().empty());
  e.begin("baseline");
  EXPECT_TRUE(e.finish().empty());
  // After finish nothing counts until the next begin.
  e.observe(deg(0, 0, 0), kRest, forces(0, 0, 0), true, kHeld);
  e.observe(deg(50, 0, 0), kRest, forces(3, 0, 0), true, kHeld);
  EXPECT_TRUE(e.finish().empty());
}

TEST(Exploration, EachPhaseStartsAfresh) {
  Exploration e;
  e.begin("baseline");
  e.observe(deg(0, 0, 0), kRest, forces(0, 0, 0), true, kHeld);
  e.observe(deg(60, 10, 5), kRest, forces(10, 0, 0), true, kHeld);
  e.observe(deg(-30, -10, -5), kRest, forces(-5, 0, 0), true, kHeld);
  const auto baseline = e.finish();
  ASSERT_EQ(baseline.size(), 6u);
  e.begin("reassessment");
  EXPECT_EQ(e.phase(), "reassessment");
  e.observe(deg(0, 0, 0), kRest, forces(0, 0, 0), true, kHeld);
  e.observe(deg(40, 1, 0), kRest, forces(8, 0, 0), true, kHeld);  // nowhere near the baseline's
  const auto re = e.finish();
  ASSERT_EQ(re.size(), 1u);
  EXPECT_EQ(re[0].phase, "reassessment");
  EXPECT_NEAR(find(re, "flexion").angle_deg, 40, 1e-9);
  EXPECT_EQ(find(re, "flexion").force_n, 8.0);
  EXPECT_EQ(maybe(re, "extension"), nullptr);
  // finish() twice: the second has nothing.
  EXPECT_TRUE(e.finish().empty());
}

TEST(Exploration, SummaryNamesEveryDirectionWithItsChangeSinceBaseline) {
  const std::vector<SessionStore::Reach> baseline = {
      {"baseline", "flexion", 60.0, 11.0},   {"baseline", "extension", -30.0, 6.0},
      {"baseline", "abduction", 15.0, 2.5},  {"baseline", "adduction", -12.0, 2.0},
      {"baseline", "supination", 12.0, 7.0}, {"baseline", "pronation", -8.0, 5.0}};
  std::vector<SessionStore::Reach> now = baseline;
  for (auto& r : now) r.phase = "reassessment";
  now[0].angle_deg = 72.14;  // +12.14
  now[1].angle_deg = -27.5;  // +2.5 (less extension)
  const std::string s = Exploration::summary(now, baseline);
  EXPECT_THAT(s, AllOf(HasSubstr("flexion 72.1 deg (+12.1 vs baseline)"),
                       HasSubstr("extension -27.5 deg (+2.5 vs baseline)"),
                       HasSubstr("abduction 15.0 deg (+0.0 vs baseline)"),
                       HasSubstr("adduction -12.0 deg"), HasSubstr("supination 12.0 deg"),
                       HasSubstr("pronation -8.0 deg (+0.0 vs baseline)")));
  // In finish() order, comma separated, each direction once.
  EXPECT_EQ(s.find("flexion"), 0u);
  EXPECT_LT(s.find("extension"), s.find("abduction"));
  EXPECT_LT(s.find("supination"), s.find("pronation"));
  EXPECT_EQ(std::count(s.begin(), s.end(), ','), 5);
  std::size_t deltas = 0;
  for (auto at = s.find("vs baseline"); at != std::string::npos;
       at = s.find("vs baseline", at + 1)) {
    ++deltas;
  }
  EXPECT_EQ(deltas, 6u);

  // A loss of range shows as a negative delta.
  now[0].angle_deg = 55.0;
  EXPECT_THAT(Exploration::summary(now, baseline),
              HasSubstr("flexion 55.0 deg (-5.0 vs baseline)"));
}

TEST(Exploration, SummaryWithoutBaselineHasNoDeltas) {
  const std::vector<SessionStore::Reach> now = {{"baseline", "flexion", 60.0, 11.0},
                                                {"baseline", "extension", -30.0, 6.0}};
  const std::string s = Exploration::summary(now, {});
  EXPECT_THAT(s, ::testing::StartsWith("flexion 60.0 deg, extension -30.0 deg, abduction not "
                                       "reached"));
  EXPECT_THAT(s, Not(HasSubstr("baseline")));
  EXPECT_THAT(Exploration::summary({}, now),
              AllOf(::testing::StartsWith("flexion not reached, extension not reached"),
                    Not(HasSubstr("deg"))));
  // A baseline missing a direction: only the directions it has get a delta.
  const std::vector<SessionStore::Reach> partial = {{"baseline", "extension", -20.0, 1.0}};
  EXPECT_THAT(Exploration::summary(now, partial),
              ::testing::StartsWith("flexion 60.0 deg, extension -30.0 deg (-10.0 vs baseline), "
                                    "abduction not reached"));
}

/// The authoritative hand explored by a scripted student: the pinch closes at the joint's rest
/// pose, carries the thimbles slowly (20 deg/s) to 85 % of the way from rest to the range end
/// in one direction (abduction and axial rotation from `flexion_deg` of flexion when given),
/// holds 1.5 s and comes back to rest. Each reach is its own phase, observed as the server's
/// hand runner observes it.
struct HandReach {
  Vec3 goal = Vec3::Zero();
  std::vector<SessionStore::Reach> reaches;
};
HandReach exploreOneDirection(const sim::HandModel& hand, const JointModelParams& params,
                              std::size_t direction, double flexion_deg) {
  sim::HandSim sim(hand, params);
  const JointModel model(params);
  const Vec3 rest(model.restAngleRad(kFlexion), model.restAngleRad(kAbduction),
                  model.restAngleRad(kAxial));
  const int axis = Exploration::kDirectionAxis[direction];
  const CubicCurve& c = params.axes[static_cast<std::size_t>(axis)];
  const double end = degToRad(Exploration::kDirectionSign[direction] > 0 ? c.max_deg : c.min_deg);
  HandReach out;
  out.goal = rest;
  out.goal[axis] += 0.85 * (end - rest[axis]);
  if (axis != kFlexion && !std::isnan(flexion_deg)) out.goal[kFlexion] = degToRad(flexion_deg);
  sim.resetMcp(rest);
  Exploration e;
  e.begin("baseline");
  auto drive = [&](const Vec3& a) {
    sim.setFingerTargets(model.gripFromAngles(a, 0.008), true);
    sim.step();
    observeHand(e, sim, model, DriftOptions{}.min_grip_n);
  };
  auto move = [&](const Vec3& from, const Vec3& to) {
    const int steps =
        static_cast<int>(std::ceil(radToDeg((to - from).cwiseAbs().maxCoeff()) / 20.0 * 1000.0));
    for (int i = 1; i <= steps; ++i) drive(from + (to - from) * (static_cast<double>(i) / steps));
  };
  for (int i = 0; i < 300; ++i) drive(rest);
  move(rest, out.goal);
  for (int i = 0; i < 1500; ++i) drive(out.goal);
  move(out.goal, rest);
  out.reaches = e.finish();
  return out;
}

/// Each direction's force is the joint model's holding force on that axis at the angle
/// reached, within 3 % + 0.1 N: held still, the pads' torque on the axis is the MCP's passive
/// torque up to what the solver leaves unconverged and the last of the filtered settling
/// (measured: 0.05 N at most). The pads' whole torque, the other axes included, is several
/// times the abduction force on the reaches taken from 40 deg of flexion.
TEST(Exploration, HandReachesReportTheAxisHoldingForceAndOnlyTheDirectionExplored) {
  const sim::HandModel hand =
      sim::HandModel::load(std::string(TELEHAND_DEPLOY_DIR) + "/hand/hand24.urdf");
  for (const char* name : {"healthy", "stiff", "lax"}) {
    const JointModelParams params =
        loadPatientCaseByName(std::string(TELEHAND_DEPLOY_DIR) + "/cases", name).model;
    const JointModel model(params);
    for (double flexion_deg : {std::nan(""), 40.0}) {
      for (std::size_t d = 0; d < Exploration::kDirections.size(); ++d) {
        const int axis = Exploration::kDirectionAxis[d];
        if (axis == kFlexion && !std::isnan(flexion_deg)) continue;
        const HandReach h = exploreOneDirection(hand, params, d, flexion_deg);
        const std::string what = std::string(name) + " " + Exploration::kDirections[d] +
                                 (std::isnan(flexion_deg) ? "" : " at 40 deg flexion");
        const auto* r = maybe(h.reaches, Exploration::kDirections[d]);
        ASSERT_NE(r, nullptr) << what;
        EXPECT_NEAR(r->angle_deg, radToDeg(h.goal[axis]), 1.0) << what;
        const double want =
            Exploration::kDirectionSign[d] * model.holdingForceN(axis, degToRad(r->angle_deg));
        EXPECT_NEAR(r->force_n, want, 0.03 * std::abs(want) + 0.1) << what;
        // The opposite direction and the axes left at rest were not explored.
        for (const auto& other : h.reaches) {
          if (other.direction == r->direction) continue;
          const bool flexion_offset = other.direction == std::string("flexion") ||
                                      other.direction == std::string("extension");
          EXPECT_TRUE(flexion_offset && !std::isnan(flexion_deg))
              << what << ": also reached " << other.direction << " " << other.angle_deg;
        }
      }
    }
  }
}

}  // namespace
}  // namespace telehand::server::session
