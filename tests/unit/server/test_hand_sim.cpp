// The authoritative hand: URDF loading, conventions, limits, the 1-DoF ODE ground truth and
// torque agreement with the client proxy (docs/facts.md "Bullet").
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <iostream>
#include <memory>
#include <optional>
#include <utility>
#include <vector>

#include "telehand/config/config.h"
#include "telehand/core/error.h"
#include "telehand/server/sim/hand_sim.h"

namespace telehand::server::sim {
namespace {

const std::string kHand = std::string(TELEHAND_DEPLOY_DIR) + "/hand/hand24.urdf";

/// One finger reduced to the index metacarpal (fixed) and a 30 g proximal phalanx on the
/// three-axis MCP: the 1-DoF ground truth of docs/facts.md.
const char* kOnePhalanx = R"(<?xml version="1.0"?>
<robot name="one">
  <link name="carpus"/>
  <link name="index_metacarpal">
    <inertial><origin xyz="0.0225 0 0"/><mass value="0.036"/><inertia ixx="1e-6" ixy="0" ixz="0" iyy="6e-6" iyz="0" izz="6e-6"/></inertial>
    <collision><origin xyz="0.0225 0 0"/><geometry><cylinder radius="0.005" length="0.045"/></geometry></collision>
  </link>
  <joint name="index_cmc" type="revolute"><parent link="carpus"/><child link="index_metacarpal"/>
    <axis xyz="0 1 0"/><limit lower="0" upper="0.17" effort="1" velocity="1"/></joint>
  <link name="f"/>
  <link name="a"/>
  <link name="index_proximal">
    <inertial><origin xyz="0.0185 0 0"/><mass value="0.030"/><inertia ixx="1.2e-6" ixy="0" ixz="0" iyy="3.6e-6" iyz="0" izz="3.6e-6"/></inertial>
    <collision><origin xyz="0.0185 0 0"/><geometry><cylinder radius="0.005" length="0.037"/></geometry></collision>
  </link>
  <joint name="index_mcp_flexion" type="revolute"><parent link="index_metacarpal"/><child link="f"/>
    <origin xyz="0.045 0 0"/><axis xyz="0 1 0"/><limit lower="-0.785" upper="1.571" effort="1" velocity="1"/></joint>
  <joint name="index_mcp_axial" type="revolute"><parent link="f"/><child link="a"/>
    <axis xyz="1 0 0"/><limit lower="-0.175" upper="0.262" effort="1" velocity="1"/></joint>
  <joint name="index_mcp_abduction" type="revolute"><parent link="a"/><child link="index_proximal"/>
    <axis xyz="0 0 1"/><limit lower="-0.349" upper="0.349" effort="1" velocity="1"/></joint>
</robot>)";

TEST(HandModel, LoadsTheTwentyFourDofHandPlusAxialRotation) {
  const HandModel m = HandModel::load(kHand);
  EXPECT_EQ(m.dofCount(), 25u);
  const auto names = m.dofNames();
  for (const char* n : {"thumb_cmc_flexion", "thumb_cmc_abduction", "thumb_mcp", "thumb_ip",
                        "index_cmc", "index_mcp_flexion", "index_mcp_axial", "index_mcp_abduction",
                        "index_pip", "index_dip", "little_dip"}) {
    EXPECT_NE(std::find(names.begin(), names.end(), n), names.end()) << n;
  }
  // docs/facts.md: index bones 45/37/30/15 mm.
  EXPECT_NEAR(m.bones()[m.bone("index_metacarpal")].length_m, 0.045, 1e-6);
  EXPECT_NEAR(m.bones()[m.bone("index_proximal")].length_m, 0.037, 1e-6);
  EXPECT_NEAR(m.bones()[m.bone("index_middle")].length_m, 0.030, 1e-6);
  EXPECT_NEAR(m.bones()[m.bone("index_distal")].length_m, 0.015, 1e-6);
  // The MCP is one joint with three axes in flexion, axial, abduction order.
  const Joint& mcp = m.joints()[m.joint("index_mcp_flexion")];
  ASSERT_EQ(mcp.dofs.size(), 3u);
  EXPECT_EQ(mcp.dofs[0].axis, 1);
  EXPECT_EQ(mcp.dofs[1].axis, 0);
  EXPECT_EQ(mcp.dofs[2].axis, 2);
  EXPECT_NEAR(radToDeg(mcp.dofs[0].lower_rad), -45.0, 0.01);
  EXPECT_NEAR(radToDeg(mcp.dofs[0].upper_rad), 90.0, 0.01);
  const Joint& pip = m.joints()[m.joint("index_pip")];
  EXPECT_NEAR(radToDeg(pip.dofs[0].upper_rad), 110.0, 0.01);
}

void expectConfigError(const std::string& xml, const std::string& needle) {
  try {
    HandModel::parse(xml, "bad.urdf");
    FAIL() << "no error for " << needle;
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("bad.urdf"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
  }
}

TEST(HandModel, MalformedFilesNameTheElement) {
  expectConfigError("<robot name='x'><link name='a'/>", "not a valid URDF");
  std::string no_limit = kOnePhalanx;
  no_limit.replace(
      no_limit.find("<limit lower=\"-0.175\""),
      std::string("<limit lower=\"-0.175\" upper=\"0.262\" effort=\"1\" velocity=\"1\"/>").size(),
      "");
  expectConfigError(no_limit, "index_mcp_axial");
  std::string bad_axis = kOnePhalanx;
  bad_axis.replace(bad_axis.find("<axis xyz=\"0 0 1\"/>"), 19, "<axis xyz=\"0 1 1\"/>");
  expectConfigError(bad_axis, "index_mcp_abduction");
  std::string no_geometry = kOnePhalanx;
  const auto at = no_geometry.find("<collision><origin xyz=\"0.0185");
  no_geometry.erase(at, no_geometry.find("</collision>", at) + 12 - at);
  expectConfigError(no_geometry, "index_proximal");
  std::string bad_order = kOnePhalanx;  // abduction before flexion breaks the Euler convention
  bad_order.replace(bad_order.find("<origin xyz=\"0.045 0 0\"/><axis xyz=\"0 1 0\"/>"), 44,
                    "<origin xyz=\"0.045 0 0\"/><axis xyz=\"0 0 1\"/>");
  bad_order.replace(bad_order.find("<axis xyz=\"0 0 1\"/><limit lower=\"-0.349\""), 19,
                    "<axis xyz=\"0 1 0\"/>");
  expectConfigError(bad_order, "order");
  EXPECT_THROW(HandModel::load("/nonexistent/hand.urdf"), ConfigError);
}

class OnePhalanx : public ::testing::Test {
 protected:
  OnePhalanx() : model_(HandModel::parse(kOnePhalanx, "one")), params_(healthyIndexMcp()) {}
  HandModel model_;
  JointModelParams params_;
};

TEST_F(OnePhalanx, SignConventionsOfEveryAxis) {
  HandSim sim(model_, params_);
  const int bone = model_.bone("index_proximal");
  for (int axis = 0; axis < kAxes; ++axis) {
    Vec3 a = Vec3::Zero();
    a[axis] = 0.1;
    sim.resetMcp(a);
    const Vec3 read = sim.mcpAngles();
    EXPECT_NEAR(read[axis], 0.1, 1e-9) << kAxisNames[static_cast<std::size_t>(axis)];
    // Where the phalanx went, in the joint frame (= the model's device frame here).
    const Pose p = sim.deviceToWorld().inverse() * sim.bonePose(bone);
    if (axis == kFlexion) {
      EXPECT_LT(p.linear().col(0).z(), -0.09);  // toward the palm
    } else if (axis == kAbduction) {
      EXPECT_GT(p.linear().col(0).y(), 0.09);  // radial
    } else {
      EXPECT_LT(p.linear().col(2).y(), -0.09);  // the back of the finger turns ulnar
    }
    // A positive external torque on an axis moves that angle up.
    sim.resetMcp(Vec3::Zero());
    Vec3 push = Vec3::Zero();
    push[axis] = 0.01;
    sim.setExternalMcpTorque(push);
    const double before = sim.mcpAngles()[axis];
    for (int i = 0; i < 20; ++i) sim.step();
    EXPECT_GT(sim.mcpAngles()[axis], before + 1e-4) << kAxisNames[static_cast<std::size_t>(axis)];
    sim.setExternalMcpTorque(Vec3::Zero());
  }
}

TEST_F(OnePhalanx, LimitsHoldUnderHalfANewtonMetre) {
  HandSim sim(model_, params_);
  for (int axis = 0; axis < kAxes; ++axis) {
    const CubicCurve& c = params_.axes[static_cast<std::size_t>(axis)];
    for (double sign : {1.0, -1.0}) {
      sim.resetMcp(Vec3::Zero());
      Vec3 push = Vec3::Zero();
      push[axis] = 0.5 * sign;
      sim.setExternalMcpTorque(push);
      for (int i = 0; i < 1500; ++i) sim.step();
      const double deg = radToDeg(sim.mcpAngles()[axis]);
      const double limit = sign > 0 ? c.max_deg : c.min_deg;
      EXPECT_NEAR(deg, limit, 0.5) << kAxisNames[static_cast<std::size_t>(axis)] << " " << sign;
    }
  }
}

/// RK4 on I·θ'' = τ_ext(t) + τ_passive(θ) − b·θ' (flexion only), 10 µs steps.
std::vector<double> groundTruth(const JointModel& m, double inertia, double theta0,
                                const std::function<double(double)>& tau_ext, double seconds) {
  const double b = m.params().damping_nms_per_rad;
  auto acc = [&](double t, double th, double w) {
    return (tau_ext(t) + m.passiveTorqueNm(Vec3(th, 0, 0), Vec3::Zero())[kFlexion] - b * w) /
           inertia;
  };
  std::vector<double> out;
  double th = theta0, w = 0.0, t = 0.0;
  constexpr double h = 1e-5;
  const int per_ms = 100;
  for (int ms = 0; ms < static_cast<int>(seconds * 1000); ++ms) {
    for (int i = 0; i < per_ms; ++i) {
      const double k1t = w, k1w = acc(t, th, w);
      const double k2t = w + 0.5 * h * k1w,
                   k2w = acc(t + 0.5 * h, th + 0.5 * h * k1t, w + 0.5 * h * k1w);
      const double k3t = w + 0.5 * h * k2w,
                   k3w = acc(t + 0.5 * h, th + 0.5 * h * k2t, w + 0.5 * h * k2w);
      const double k4t = w + h * k3w, k4w = acc(t + h, th + h * k3t, w + h * k3w);
      th += h / 6 * (k1t + 2 * k2t + 2 * k3t + k4t);
      w += h / 6 * (k1w + 2 * k2w + 2 * k3w + k4w);
      t += h;
    }
    out.push_back(th);
  }
  return out;
}

void compareWithOde(const HandModel& model, const JointModelParams& params,
                    const std::function<double(double)>& tau_ext, const char* what) {
  HandSim sim(model, params);
  const JointModel jm(params);
  // Start at rest on the other axes so that only flexion moves.
  const Vec3 start(0.0, jm.restAngleRad(kAbduction), jm.restAngleRad(kAxial));
  sim.resetMcp(start);
  const auto truth = groundTruth(jm, sim.mcpFlexionInertia(), 0.0, tau_ext, 2.0);
  const double range = degToRad(params.axes[kFlexion].max_deg - params.axes[kFlexion].min_deg);
  double worst = 0.0, swing = 0.0;
  for (std::size_t ms = 0; ms < truth.size(); ++ms) {
    sim.setExternalMcpTorque(Vec3(tau_ext(static_cast<double>(ms) * 1e-3), 0, 0));
    sim.step();
    worst = std::max(worst, std::abs(sim.mcpAngles()[kFlexion] - truth[ms]));
    swing = std::max(swing, std::abs(truth[ms]));
  }
  EXPECT_GT(swing, 0.1 * range) << what
                                << ": the push must move the joint for the test to mean anything";
  EXPECT_LT(worst, 0.01 * range) << what << ": worst error " << radToDeg(worst) << " deg";
  ::testing::Test::RecordProperty(std::string(what) + "_worst_error_deg",
                                  std::to_string(radToDeg(worst)));
}

TEST_F(OnePhalanx, StepTorqueFollowsTheAnalyticOde) {
  compareWithOde(
      model_, params_, [](double) { return 0.06; }, "step");
}

TEST_F(OnePhalanx, ThreeHertzPushFollowsTheAnalyticOde) {
  compareWithOde(
      model_, params_, [](double t) { return 0.05 + 0.03 * std::sin(2 * kPi * 3.0 * t); },
      "3 Hz push");
}

/// Ramps a pinch to each angle like a slow student (30 deg/s), holds it, and compares the
/// torque the pads exert on the phalanx (averaged over the last 0.5 s: skin friction
/// sticks and slips) with the proxy's torque at the angle the simulation reached.
void quasiStatic(const HandSimConfig& config, bool every_axis) {
  const HandModel model = HandModel::load(kHand);
  const JointModelParams params = healthyIndexMcp();
  HandSim sim(model, params, config);
  const JointModel proxy(params);  // what the client renders with
  Vec3 cur(proxy.restAngleRad(kFlexion), 0, 0);
  sim.resetMcp(cur);
  for (double goal_deg : {10.0, 30.0, 50.0, 70.0}) {
    const double goal = degToRad(goal_deg);
    while (cur[kFlexion] < goal) {
      cur[kFlexion] = std::min(goal, cur[kFlexion] + degToRad(0.03));
      sim.setFingerTargets(proxy.gripFromAngles(cur, 0.008), true);
      sim.step();
    }
    Vec3 applied = Vec3::Zero(), expected = Vec3::Zero(), angles = Vec3::Zero();
    constexpr int kSteps = 1000, kAveraged = 500;
    for (int i = 0; i < kSteps; ++i) {
      sim.setFingerTargets(proxy.gripFromAngles(cur, 0.008), true);
      sim.step();
      if (i < kSteps - kAveraged) continue;
      const auto on_spheres = sim.contactForcesDevice();
      angles = sim.mcpAngles();
      applied +=
          proxy.axisTorque(sim.contactPointsDevice(), angles, {-on_spheres[0], -on_spheres[1]}) /
          kAveraged;
      expected += -proxy.passiveTorqueNm(angles, Vec3::Zero()) / kAveraged;
    }
    EXPECT_NEAR(applied[kFlexion], expected[kFlexion], 0.01 * std::abs(expected[kFlexion]))
        << "at " << goal_deg << " deg (sim " << radToDeg(angles[kFlexion]) << ")";
    if (every_axis) {
      for (int axis : {kAbduction, kAxial}) {
        // 1 % of the torque the joint carries (these axes hold only a few mN·m here).
        EXPECT_NEAR(applied[axis], expected[axis], 0.01 * expected.norm())
            << kAxisNames[static_cast<std::size_t>(axis)] << " at " << goal_deg << " deg";
      }
    }
    EXPECT_NEAR(radToDeg(angles[kFlexion]), goal_deg, 2.0);
  }
}

TEST(HandSim, QuasiStaticTorqueMatchesTheClientProxy) { quasiStatic(HandSimConfig{}, false); }

TEST(HandSim, QuasiStaticTorqueMatchesOnEveryAxisWithoutSkinFriction) {
  HandSimConfig frictionless;
  frictionless.skin_friction = 0.0;
  quasiStatic(frictionless, true);
}

/// Fingers nobody touches fall asleep (the server's idle cost); every input must still reach
/// a sleeping finger. Each case idles a hand until it sleeps, applies one input, and compares
/// with a hand that never slept started from the same rest pose.
TEST(HandSim, SleepingFingersWakeForEveryInput) {
  const HandModel model = HandModel::load(kHand);
  const JointModelParams params = healthyIndexMcp();
  const JointModel proxy(params);
  const PerFinger<Vec3> none{Vec3::Zero(), Vec3::Zero()};
  auto asleep = [&](HandSim& sim) {
    for (int i = 0; i < 5000; ++i) {  // settles in ~1.5 s, sleeps after 2 s at rest
      sim.setFingerTargets(none, false);
      sim.step();
    }
  };
  auto fresh = [&](const Vec3& angles) {  // awake from construction, same rest pose
    auto sim = std::make_unique<HandSim>(model, params);
    sim->resetMcp(angles);
    return sim;
  };
  {  // a push on the MCP
    HandSim sim(model, params);
    asleep(sim);
    const Vec3 rest = sim.mcpAngles();
    auto ref = fresh(rest);
    sim.setExternalMcpTorque(Vec3(0.06, 0, 0));
    ref->setExternalMcpTorque(Vec3(0.06, 0, 0));
    for (int i = 0; i < 300; ++i) {
      sim.step();
      ref->step();
    }
    EXPECT_GT(sim.mcpAngles()[kFlexion], rest[kFlexion] + degToRad(5.0));
    EXPECT_NEAR(radToDeg(sim.mcpAngles()[kFlexion]), radToDeg(ref->mcpAngles()[kFlexion]), 0.01);
  }
  {  // resetMcp away from rest: the passive torque pulls the phalanx back
    HandSim sim(model, params);
    asleep(sim);
    const Vec3 moved = sim.mcpAngles() + Vec3(degToRad(20.0), 0, 0);
    sim.resetMcp(moved);
    auto ref = fresh(moved);
    for (int i = 0; i < 300; ++i) {
      sim.step();
      ref->step();
    }
    EXPECT_LT(sim.mcpAngles()[kFlexion], moved[kFlexion] - degToRad(5.0));
    EXPECT_NEAR(radToDeg(sim.mcpAngles()[kFlexion]), radToDeg(ref->mcpAngles()[kFlexion]), 0.01);
  }
  {  // a new model whose rest angle lies elsewhere
    HandSim sim(model, params);
    asleep(sim);
    const double before = sim.mcpAngles()[kFlexion];
    JointModelParams stiffer = params;
    stiffer.version = 2;
    stiffer.axes[kFlexion].coeffs[3] -= 1.0;  // 1 N more flexing pull everywhere
    sim.setMcpModel(stiffer);
    for (int i = 0; i < 1000; ++i) sim.step();
    EXPECT_GT(std::abs(sim.mcpAngles()[kFlexion] - before), degToRad(1.0));
    EXPECT_NEAR(radToDeg(sim.mcpAngles()[kFlexion]),
                radToDeg(JointModel(stiffer).restAngleRad(kFlexion)), 1.0);
  }
  {  // the pinch: contacts reach a sleeping phalanx
    HandSim sim(model, params);
    asleep(sim);
    const Vec3 goal = sim.mcpAngles() + Vec3(degToRad(15.0), 0, 0);
    for (int i = 0; i < 1000; ++i) {
      sim.setFingerTargets(proxy.gripFromAngles(goal, 0.008), true);
      sim.step();
    }
    EXPECT_GT(sim.contactForcesDevice()[kIndex].norm(), 1.0);
    EXPECT_NEAR(radToDeg(sim.mcpAngles()[kFlexion]), radToDeg(goal[kFlexion]), 2.0);
  }
}

/// Exploration ground truth: a scripted student pinches the phalanx and carries the grip to
/// known angles in each of the six directions at 30 deg/s; the hand reaches them.
TEST(HandSim, ScriptedPinchReachesKnownAnglesInEveryDirection) {
  const HandModel model = HandModel::load(kHand);
  const JointModelParams params = healthyIndexMcp();
  const JointModel proxy(params);
  struct Reach {
    const char* name;
    double flexion, abduction, axial;
  };
  for (const Reach& r : {Reach{"flexion", 60, 0, 0}, Reach{"extension", -30, 0, 0},
                         Reach{"abduction", 20, 15, 0}, Reach{"adduction", 20, -15, 0},
                         Reach{"supination", 20, 0, 12}, Reach{"pronation", 20, 0, -8}}) {
    HandSim sim(model, params);
    Vec3 cur(proxy.restAngleRad(kFlexion), 0, 0);
    sim.resetMcp(cur);
    Vec3 goal;
    goal[kFlexion] = degToRad(r.flexion);
    goal[kAbduction] = degToRad(r.abduction);
    goal[kAxial] = degToRad(r.axial);
    const Vec3 from = cur;
    const int steps =
        static_cast<int>(std::ceil(radToDeg((goal - from).cwiseAbs().maxCoeff()) / 30.0 * 1000.0));
    for (int i = 1; i <= steps + 300; ++i) {
      cur = from + (goal - from) * std::min(1.0, static_cast<double>(i) / steps);
      sim.setFingerTargets(proxy.gripFromAngles(cur, 0.008), true);
      sim.step();
    }
    const Vec3 got = sim.mcpAngles();
    for (int axis = 0; axis < 3; ++axis) {
      EXPECT_NEAR(radToDeg(got[axis]), radToDeg(goal[axis]), 1.0)
          << r.name << ": " << kAxisNames[static_cast<std::size_t>(axis)];
    }
  }
}

/// One of the six directions of exploration: an axis and which way along it.
struct Direction {
  const char* name;
  int axis;
  double sign;
};
constexpr Direction kSixDirections[] = {
    {"flexion", kFlexion, 1.0},      {"extension", kFlexion, -1.0}, {"abduction", kAbduction, 1.0},
    {"adduction", kAbduction, -1.0}, {"supination", kAxial, 1.0},   {"pronation", kAxial, -1.0}};

/// What a scripted reach ended at: the angles the script held, the hand's (averaged over the
/// last 0.3 s of the hold) and the largest squeeze on the way.
struct ReachResult {
  Vec3 goal = Vec3::Zero();
  Vec3 held = Vec3::Zero();
  double peak_pinch_n = 0.0;
};

/// A scripted student: engages the pinch at the joint's rest pose, carries the thimbles
/// (JointModel::gripFromAngles, 8 mm either side) slowly (20 deg/s) to `fraction` of the range
/// between rest and the range end in direction `d`, and holds there for 1.5 s.
ReachResult scriptedReach(const HandModel& model, const JointModelParams& params,
                          const Direction& d, double fraction, const HandSimConfig& config = {},
                          double flexion_deg = std::nan(""), double speed_deg_s = 20.0) {
  HandSim sim(model, params, config);
  const JointModel jm(params);
  const Vec3 rest(jm.restAngleRad(kFlexion), jm.restAngleRad(kAbduction), jm.restAngleRad(kAxial));
  sim.resetMcp(rest);
  const CubicCurve& c = params.axes[static_cast<std::size_t>(d.axis)];
  const double end = degToRad(d.sign > 0 ? c.max_deg : c.min_deg);
  ReachResult out;
  out.goal = rest;
  out.goal[d.axis] = rest[d.axis] + fraction * (end - rest[d.axis]);
  if (d.axis != kFlexion && !std::isnan(flexion_deg)) out.goal[kFlexion] = degToRad(flexion_deg);
  auto drive = [&](const Vec3& a) {
    sim.setFingerTargets(jm.gripFromAngles(a, 0.008), true);
    sim.step();
    out.peak_pinch_n = std::max(out.peak_pinch_n, sim.pinchForce());
  };
  for (int i = 0; i < 300; ++i) drive(rest);  // the pads settle on the skin
  const int ramp = static_cast<int>(
      std::ceil(radToDeg((out.goal - rest).cwiseAbs().maxCoeff()) / speed_deg_s * 1000.0));
  for (int i = 1; i <= ramp; ++i) {
    drive(rest + (out.goal - rest) * (static_cast<double>(i) / ramp));
  }
  constexpr int kHold = 1500, kAveraged = 300;
  for (int i = 0; i < kHold; ++i) {
    drive(out.goal);
    if (i >= kHold - kAveraged) out.held += sim.mcpAngles() / kAveraged;
  }
  return out;
}

JointModelParams patientCase(const char* name) {
  return loadPatientCaseByName(std::string(TELEHAND_DEPLOY_DIR) + "/cases", name).model;
}

/// Exploration's ground truth on patient cases: every direction, from rest and from flexed
/// poses, held within 1 deg on all three axes with the squeeze within its limit. The pads
/// carry up to 20 N (the stiff joint's extension) and 10 N of friction each (axial rotation
/// at 60 deg of flexion, the squeeze near its 20 N limit). Tuned on healthy and stiff; lax
/// and spasm were not looked at while tuning.
TEST(HandSim, ScriptedReachesHoldWithinOneDegreeInEveryDirection) {
  const HandModel model = HandModel::load(kHand);
  const HandSimConfig config;
  double worst = 0.0;
  for (const char* name : {"healthy", "stiff", "lax", "spasm"}) {
    const JointModelParams params = patientCase(name);
    // A spasm resists fast moves harder (1.8 times at 30 deg/s): carried from rest to 60 deg
    // of flexion at that speed it needs more than the squeeze can give, and the pads slip.
    const bool spasm = params.speed_gain_s_per_rad > 0.0;
    for (double flexion : {std::nan(""), 20.0, 60.0}) {
      if (spasm && flexion == 60.0) continue;
      for (const Direction& d : kSixDirections) {
        if (d.axis == kFlexion && !std::isnan(flexion)) continue;
        const ReachResult r = scriptedReach(model, params, d, 0.85, config, flexion, 30.0);
        const Vec3 err = radToDeg(1.0) * (r.held - r.goal);
        for (int axis = 0; axis < 3; ++axis) {
          EXPECT_NEAR(err[axis], 0.0, 1.0)
              << name << " " << d.name << (std::isnan(flexion) ? " from rest" : " flexed") << ": "
              << kAxisNames[static_cast<std::size_t>(axis)];
        }
        EXPECT_LE(r.peak_pinch_n, config.max_pinch_n + 1e-9);
        worst = std::max(worst, err.cwiseAbs().maxCoeff());
      }
    }
  }
  ::testing::Test::RecordProperty("worst_error_deg", std::to_string(worst));
}

/// The reach the simulated clinician's exploration asks of the hand in direction `d`
/// (planExploration pushes up to the paper's 16 N band top and stops at the range end): 85 %
/// of the way from rest to the range end, or less where the joint's holding force there would
/// pass the band. From a flexed pose (`flexion_deg`) only while that pose is inside the range
/// and the force holding the joint there, all axes together, is within the band: the flexion
/// load goes through one pad's face and takes that much squeeze off the other pad, whose
/// friction then carries less of the side and twist loads, and no exploration asks the pads
/// for more. nullopt: not asked.
std::optional<double> reachFraction(const JointModelParams& params, const Direction& d,
                                    double flexion_deg, double band_n = 16.0) {
  const JointModel jm(params);
  const CubicCurve& c = params.axes[static_cast<std::size_t>(d.axis)];
  const double rest = jm.restAngleRad(d.axis);
  const double end = degToRad(d.sign > 0 ? c.max_deg : c.min_deg);
  double fraction = 0.85;
  while (fraction > 0.05 &&
         std::abs(jm.holdingForceN(d.axis, rest + fraction * (end - rest))) > band_n) {
    fraction -= 0.01;
  }
  Vec3 goal(jm.restAngleRad(kFlexion), jm.restAngleRad(kAbduction), jm.restAngleRad(kAxial));
  goal[d.axis] = rest + fraction * (end - rest);
  if (d.axis != kFlexion && !std::isnan(flexion_deg)) {
    const CubicCurve& f = params.axes[kFlexion];
    if (flexion_deg < f.min_deg || flexion_deg > f.max_deg) return std::nullopt;
    goal[kFlexion] = degToRad(flexion_deg);
  }
  const Vec3 hold(jm.holdingForceN(kFlexion, goal[kFlexion]),
                  jm.holdingForceN(kAbduction, goal[kAbduction]),
                  jm.holdingForceN(kAxial, goal[kAxial]));
  if (hold.norm() > band_n) return std::nullopt;
  return fraction;
}

/// Every reach reachFraction asks of `cases` (six directions from rest, the four side and
/// twist directions from 20 and 60 deg of flexion), carried at 30 deg/s and held within 1 deg
/// on all three axes. Returns how many were asked and how many could have been.
std::pair<int, int> expectAskedReachesHold(const std::vector<JointModelParams>& cases) {
  const HandModel model = HandModel::load(kHand);
  const HandSimConfig config;
  int asked = 0, candidates = 0;
  for (const JointModelParams& params : cases) {
    for (double flexion : {std::nan(""), 20.0, 60.0}) {
      for (const Direction& d : kSixDirections) {
        if (d.axis == kFlexion && !std::isnan(flexion)) continue;
        ++candidates;
        const std::optional<double> fraction = reachFraction(params, d, flexion);
        if (!fraction) continue;
        ++asked;
        const ReachResult r = scriptedReach(model, params, d, *fraction, config, flexion, 30.0);
        const Vec3 err = radToDeg(1.0) * (r.held - r.goal);
        for (int axis = 0; axis < 3; ++axis) {
          EXPECT_NEAR(err[axis], 0.0, 1.0) << params.case_name.data() << " " << d.name
                                           << (std::isnan(flexion) ? " from rest" : " flexed")
                                           << ": " << kAxisNames[static_cast<std::size_t>(axis)]
                                           << " (squeeze " << r.peak_pinch_n << " N)";
        }
      }
    }
  }
  ::testing::Test::RecordProperty("reaches_asked", std::to_string(asked));
  ::testing::Test::RecordProperty("reaches_left_out", std::to_string(candidates - asked));
  return {asked, candidates};
}

/// The same ground truth on the other shipped cases and on random patients
/// (randomPatientCase 1-32), the reaches an exploration asks for. With the squeeze's time
/// constant at 30 ms instead of 10, 4 of 826 such reaches (random 1-60 and the four shipped
/// cases twice) slip 1.5-3.2 deg short: a pronation or supination from rest whose load comes
/// at the end of a neutral zone faster than the squeeze (random-22, 27 and 32; docs/capture.md
/// "The grip").
TEST(HandSim, ReachesAnExplorationAsksHoldWithinOneDegreeOnTheOtherShippedCases) {
  std::vector<JointModelParams> cases;
  for (const char* name : {"hypertonic", "oedema", "recovery", "scar"}) {
    cases.push_back(patientCase(name));
  }
  for (uint64_t seed = 1; seed <= 12; ++seed) cases.push_back(randomPatientCase(seed).model);
  const auto [asked, candidates] = expectAskedReachesHold(cases);
  // The rule leaves out only loads past the band: recovery's 60 deg is past its range, and a
  // few stiff random patients' twists from a flexed pose.
  EXPECT_GE(asked, 0.9 * candidates);
}

TEST(HandSim, ReachesAnExplorationAsksHoldWithinOneDegreeOnRandomPatients) {
  std::vector<JointModelParams> cases;
  for (uint64_t seed = 13; seed <= 32; ++seed) cases.push_back(randomPatientCase(seed).model);
  const auto [asked, candidates] = expectAskedReachesHold(cases);
  EXPECT_GE(asked, 0.9 * candidates);
}

/// The pads hold the phalanx by friction: the squeeze rises with the load they carry (grip
/// follows load) and relaxes when it goes; a squeeze that may not rise lets the pads slip.
TEST(HandSim, GripFollowsLoadAndPadsSlipPastTheFrictionLimit) {
  const HandModel model = HandModel::load(kHand);
  const JointModelParams params = healthyIndexMcp();
  const JointModel proxy(params);
  auto supinate = [&](const HandSimConfig& config, double* peak_pinch) {
    HandSim sim(model, params, config);
    Vec3 cur(degToRad(20.0), 0, 0);
    sim.resetMcp(cur);
    *peak_pinch = 0.0;
    for (int i = 0; i < 800; ++i) {  // 12 deg of supination at 30 deg/s, then held
      cur[kAxial] = degToRad(12.0) * std::min(1.0, i / 400.0);
      sim.setFingerTargets(proxy.gripFromAngles(cur, 0.008), true);
      sim.step();
      *peak_pinch = std::max(*peak_pinch, sim.pinchForce());
    }
    const double reached = radToDeg(sim.mcpAngles()[kAxial]);
    for (int i = 0; i < 400; ++i) {  // back to neutral rotation: the load goes
      cur[kAxial] = degToRad(12.0) * std::max(0.0, 1.0 - i / 400.0);
      sim.setFingerTargets(proxy.gripFromAngles(cur, 0.008), true);
      sim.step();
    }
    for (int i = 0; i < 1500; ++i) {
      sim.setFingerTargets(proxy.gripFromAngles(cur, 0.008), true);
      sim.step();
    }
    return std::pair{reached, sim.pinchForce()};
  };
  const HandSimConfig normal;
  double peak = 0.0;
  const auto [reached, relaxed] = supinate(normal, &peak);
  // 0.08 N·m of axial torque through two pads 5 mm off the axis: about 8 N each, so the
  // squeeze rose well past the 3 N preload, and fell back once the load was gone.
  EXPECT_NEAR(reached, 12.0, 1.0);
  EXPECT_GT(peak, 2.0 * normal.pinch_preload_n);
  EXPECT_LT(relaxed, 0.5 * peak);
  // The same student who does not squeeze harder: the pads slip and the joint stays short.
  HandSimConfig light;
  light.max_pinch_n = light.pinch_preload_n;
  double light_peak = 0.0;
  const double light_reached = supinate(light, &light_peak).first;
  EXPECT_LE(light_peak, light.pinch_preload_n + 1e-9);
  EXPECT_LT(light_reached, reached - 3.0);
  EXPECT_GT(light_reached, 0.5);  // friction still turned it some way
}

}  // namespace
}  // namespace telehand::server::sim

namespace telehand::server::sim {
namespace {

/// Drives a pinch mobilization at 2 Hz, ±20 deg about 30 deg, from step `from` to `to`.
void mobilize(HandSim& sim, const JointModel& proxy, int from, int to) {
  for (int i = from; i < to; ++i) {
    const double t = i * 1e-3;
    const Vec3 goal(degToRad(30.0 + 20.0 * std::sin(2.0 * kPi * 2.0 * t)), 0, 0);
    sim.setFingerTargets(proxy.gripFromAngles(goal, 0.008), true);
    sim.step();
  }
}

// A server of a pool checkpoints each hand and another one goes on from it (docs/pool.md): the
// restored hand, in another world, follows the same mobilization as the one it was saved
// from, and a state that does not fit is refused without changing anything.
TEST(HandSim, ARestoredCheckpointGoesOnLikeTheHandItWasSavedFrom) {
  const HandModel model = HandModel::load(kHand);
  const JointModelParams params = healthyIndexMcp();
  const JointModel proxy(params);
  HandSim a(model, params);
  a.resetMcp(Vec3(degToRad(30.0), 0, 0));
  mobilize(a, proxy, 0, 1300);  // mid-swing: moving, both pads gripping
  const std::vector<double> saved = a.saveState();
  const Vec3 at_save = a.mcpAngles();

  HandSim b(model, params);
  b.resetMcp(Vec3(degToRad(-10.0), degToRad(5.0), 0));
  EXPECT_FALSE(b.restoreState({}));
  std::vector<double> truncated(saved.begin(), saved.end() - 3);
  EXPECT_FALSE(b.restoreState(truncated));
  std::vector<double> poisoned = saved;
  poisoned[10] = std::nan("");
  EXPECT_FALSE(b.restoreState(poisoned));
  EXPECT_NEAR(radToDeg(b.mcpAngles()[kFlexion]), -10.0, 1e-6) << "a refused state changes nothing";
  ASSERT_TRUE(b.restoreState(saved));
  EXPECT_NEAR(b.timeS(), a.timeS(), 1e-12);
  EXPECT_LT((b.mcpAngles() - at_save).norm(), 1e-9);
  EXPECT_NEAR(b.pinchForce(), a.pinchForce(), 1e-12);

  // A second hand restored from the same state: the state is complete when the two go on
  // exactly alike (neither has a solver warm start).
  HandSim c(model, params);
  ASSERT_TRUE(c.restoreState(saved));

  // Both go on for 1 s of the same mobilization: the solver's warm start is not part of the
  // state, so the restored hand and the original agree to within a small fraction of the
  // 40 deg swing, not bit for bit: 0.54 deg here; saved at eight points of the swing
  // (1.1-2.1 s) 0.18-0.54 deg (0.27-0.43 deg with the squeeze's time constant at 30 ms
  // instead of 10); an exploration measures to 1 deg.
  double worst_deg = 0.0, twins_deg = 0.0;
  for (int k = 0; k < 10; ++k) {
    mobilize(a, proxy, 1300 + 100 * k, 1400 + 100 * k);
    mobilize(b, proxy, 1300 + 100 * k, 1400 + 100 * k);
    mobilize(c, proxy, 1300 + 100 * k, 1400 + 100 * k);
    worst_deg = std::max(worst_deg, radToDeg((a.mcpAngles() - b.mcpAngles()).norm()));
    twins_deg = std::max(twins_deg, radToDeg((b.mcpAngles() - c.mcpAngles()).norm()));
  }
  EXPECT_LT(twins_deg, 1e-9) << "two hands restored from one state went apart";
  EXPECT_LT(worst_deg, 1.0) << "the restored hand went its own way";
  std::cout << "restored hand against the original over 1 s of mobilization: " << worst_deg
            << " deg at worst\n";
}

}  // namespace
}  // namespace telehand::server::sim
