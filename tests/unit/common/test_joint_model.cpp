// The reduced index MCP model: paper eqs. 3-5, kinematics, torque mapping and the proxy's
// cross-fade (docs/facts.md "The paper", "Rendering").
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "telehand/core/clock.h"
#include "telehand/core/joint_model.h"

namespace telehand {
namespace {

/// A joint frame that is neither at the origin nor aligned with the device axes, so that
/// frame mistakes cannot cancel out.
JointModelParams offsetJoint() {
  JointModelParams p = healthyIndexMcp();
  p.joint_origin_m = Vec3(0.12, -0.03, 0.05);
  p.joint_orientation =
      Quat(Eigen::AngleAxisd(0.4, Vec3::UnitZ()) * Eigen::AngleAxisd(-0.3, Vec3::UnitX()) *
           Eigen::AngleAxisd(0.2, Vec3::UnitY()));
  return p;
}

std::vector<Vec3> angleGrid(const JointModelParams& p) {
  std::vector<Vec3> out;
  const auto& ax = p.axes;
  constexpr int kN = 7;
  for (int i = 0; i < kN; ++i) {
    for (int j = 0; j < kN; ++j) {
      for (int k = 0; k < kN; ++k) {
        auto at = [](const CubicCurve& c, int n) {
          return degToRad(c.min_deg + (c.max_deg - c.min_deg) * n / (kN - 1));
        };
        out.emplace_back(at(ax[kFlexion], i), at(ax[kAbduction], j), at(ax[kAxial], k));
      }
    }
  }
  return out;
}

// ---- Paper eqs. 3-5 ------------------------------------------------------------------------

TEST(HealthyIndexMcp, FlexionIsEquation3) {
  const JointModel m(healthyIndexMcp());
  // Eq. 3 at alpha = 30 deg, by hand from the printed coefficients.
  const double a = 30.0;
  const double expected = 1.834e-5 * a * a * a + 0.0010338 * a * a + 0.046382 * a + 0.59057;
  EXPECT_NEAR(expected, 3.40763, 1e-5);  // 0.49518 + 0.93042 + 1.39146 + 0.59057
  EXPECT_NEAR(m.holdingForceN(kFlexion, degToRad(a)), expected, 1e-9);
  // And at an extension angle.
  const double b = -30.0;
  EXPECT_NEAR(m.holdingForceN(kFlexion, degToRad(b)),
              1.834e-5 * b * b * b + 0.0010338 * b * b + 0.046382 * b + 0.59057, 1e-9);
}

TEST(HealthyIndexMcp, AbductionIsEquation4) {
  const JointModel m(healthyIndexMcp());
  // Eq. 4 at beta = 10 deg: 0.17 + 0.12 + 1.3 - 0.49 = 1.1 N.
  EXPECT_NEAR(m.holdingForceN(kAbduction, degToRad(10.0)), 1.1, 1e-9);
  const double b = -15.0;
  EXPECT_NEAR(m.holdingForceN(kAbduction, degToRad(b)),
              0.00017 * b * b * b + 0.0012 * b * b + 0.13 * b - 0.49, 1e-9);
}

TEST(HealthyIndexMcp, AxialIsEquation5) {
  const JointModel m(healthyIndexMcp());
  // Eq. 5 at gamma = -5 deg: -0.175 - 0.35 - 3.25 + 0.09 = -3.685 N.
  EXPECT_NEAR(m.holdingForceN(kAxial, degToRad(-5.0)), -3.685, 1e-9);
  const double g = 12.0;
  EXPECT_NEAR(m.holdingForceN(kAxial, degToRad(g)),
              0.0014 * g * g * g - 0.014 * g * g + 0.65 * g + 0.09, 1e-9);
}

TEST(HealthyIndexMcp, RangesAndScaleAsStated) {
  const JointModelParams p = healthyIndexMcp();
  EXPECT_EQ(p.axes[kFlexion].min_deg, -45.0);
  EXPECT_EQ(p.axes[kFlexion].max_deg, 90.0);
  EXPECT_EQ(p.axes[kAbduction].min_deg, -20.0);
  EXPECT_EQ(p.axes[kAbduction].max_deg, 20.0);
  EXPECT_EQ(p.axes[kAxial].min_deg, -10.0);
  EXPECT_EQ(p.axes[kAxial].max_deg, 15.0);
  EXPECT_DOUBLE_EQ(p.lever_arm_m, 0.01);  // paper: forces about 1 cm from the joint centre
  EXPECT_DOUBLE_EQ(p.force_scale, 0.25);  // paper: 1:4, 16 N reference -> 4 N device
  EXPECT_STREQ(p.case_name.data(), "healthy");
}

TEST(HealthyIndexMcp, MobilizationBandLiesInsideTheFlexionRange) {
  // The paper's 12-16 N oscillation must be reachable before the end-of-range wall.
  const JointModel m(healthyIndexMcp());
  EXPECT_LT(m.holdingForceN(kFlexion, degToRad(60.0)), 12.0);
  EXPECT_GT(m.holdingForceN(kFlexion, degToRad(75.0)), 16.0);
}

// ---- Curve shape --------------------------------------------------------------------------

TEST(CubicCurve, MonotonicIncreasingInsideAndBeyondTheRange) {
  const JointModel m(healthyIndexMcp());
  for (int axis = 0; axis < kAxes; ++axis) {
    const CubicCurve& c = m.params().axes[axis];
    double prev = c.eval(c.min_deg - 20.0);
    for (double deg = c.min_deg - 20.0 + 0.25; deg <= c.max_deg + 20.0; deg += 0.25) {
      const double f = c.eval(deg);
      EXPECT_GT(f, prev) << kAxisNames[axis] << " at " << deg << " deg";
      EXPECT_GT(c.slope(deg), 0.0) << kAxisNames[axis] << " at " << deg << " deg";
      prev = f;
    }
  }
}

TEST(CubicCurve, SlopeIsTheDerivative) {
  const JointModelParams p = healthyIndexMcp();
  const CubicCurve& c = p.axes[kFlexion];
  for (double deg : {-40.0, -10.0, 0.0, 25.0, 80.0}) {
    const double h = 1e-5;
    const double numeric = (c.eval(deg + h) - c.eval(deg - h)) / (2 * h);
    EXPECT_NEAR(c.slope(deg), numeric, 1e-7) << deg;
  }
}

TEST(CubicCurve, EndOfRangeWallIsContinuousAndStiff) {
  const JointModelParams p = healthyIndexMcp();
  for (const CubicCurve& c : p.axes) {
    // Continuous at both ends.
    EXPECT_NEAR(c.eval(c.max_deg + 1e-9), c.eval(c.max_deg), 1e-8);
    EXPECT_NEAR(c.eval(c.min_deg - 1e-9), c.eval(c.min_deg), 1e-8);
    // Beyond the range: the end slope plus the wall, linear.
    const double up = c.eval(c.max_deg + 3.0) - c.eval(c.max_deg);
    EXPECT_NEAR(up, 3.0 * (c.slope(c.max_deg) + kWallNPerDeg), 1e-9);
    const double down = c.eval(c.min_deg) - c.eval(c.min_deg - 3.0);
    EXPECT_NEAR(down, 3.0 * (c.slope(c.min_deg) + kWallNPerDeg), 1e-9);
    // The wall is stiffer than the curve at its end.
    EXPECT_GT(c.eval(c.max_deg + 1.0) - c.eval(c.max_deg),
              c.eval(c.max_deg) - c.eval(c.max_deg - 1.0));
  }
}

TEST(JointModel, RestAngleIsWhereTheHoldingForceVanishes) {
  const JointModel m(healthyIndexMcp());
  for (int axis = 0; axis < kAxes; ++axis) {
    const double rest = m.restAngleRad(axis);
    const CubicCurve& c = m.params().axes[axis];
    EXPECT_GT(radToDeg(rest), c.min_deg) << kAxisNames[axis];
    EXPECT_LT(radToDeg(rest), c.max_deg) << kAxisNames[axis];
    EXPECT_NEAR(m.holdingForceN(axis, rest), 0.0, 1e-9) << kAxisNames[axis];
  }
  // Eq. 3's root, by hand: F(-17) = +0.0108 N, F(-18) = -0.0163 N.
  EXPECT_GT(radToDeg(m.restAngleRad(kFlexion)), -18.0);
  EXPECT_LT(radToDeg(m.restAngleRad(kFlexion)), -17.0);
}

TEST(JointModel, RestAngleFallsBackToTheRangeEndWhenNoRootInside) {
  JointModelParams p = healthyIndexMcp();
  p.axes[kFlexion].coeffs = {0.0, 0.0, 0.1, 50.0};     // positive throughout -45..90
  p.axes[kAbduction].coeffs = {0.0, 0.0, 0.1, -50.0};  // negative throughout -20..20
  const JointModel m(p);
  EXPECT_DOUBLE_EQ(m.restAngleRad(kFlexion), degToRad(-45.0));
  EXPECT_DOUBLE_EQ(m.restAngleRad(kAbduction), degToRad(20.0));
}

TEST(JointModel, PassiveTorqueRestoresTowardTheRestAngle) {
  const JointModel m(healthyIndexMcp());
  for (int axis = 0; axis < kAxes; ++axis) {
    const double rest = m.restAngleRad(axis);
    for (double off_deg : {0.5, 5.0, 15.0, 60.0}) {
      Vec3 above = Vec3::Zero();
      Vec3 below = Vec3::Zero();
      for (int i = 0; i < kAxes; ++i) above[i] = below[i] = m.restAngleRad(i);
      above[axis] = rest + degToRad(off_deg);
      below[axis] = rest - degToRad(off_deg);
      EXPECT_LT(m.passiveTorqueNm(above, Vec3::Zero())[axis], 0.0)
          << kAxisNames[axis] << " +" << off_deg;
      EXPECT_GT(m.passiveTorqueNm(below, Vec3::Zero())[axis], 0.0)
          << kAxisNames[axis] << " -" << off_deg;
    }
  }
}

TEST(JointModel, PassiveTorqueIsForceTimesLeverPlusDamping) {
  const JointModel m(healthyIndexMcp());
  const Vec3 angles(degToRad(40.0), degToRad(-8.0), degToRad(6.0));
  const Vec3 rates(2.0, -1.0, 0.5);
  const Vec3 tau = m.passiveTorqueNm(angles, rates);
  for (int i = 0; i < kAxes; ++i) {
    EXPECT_NEAR(tau[i], -m.holdingForceN(i, angles[i]) * 0.01 - 0.002 * rates[i], 1e-12);
  }
  // Damping opposes motion.
  const Vec3 still = m.passiveTorqueNm(angles, Vec3::Zero());
  EXPECT_LT(tau[kFlexion], still[kFlexion]);
  EXPECT_GT(tau[kAbduction], still[kAbduction]);
}

// ---- Kinematics ---------------------------------------------------------------------------

TEST(JointModel, GripAnglesRoundTripOverTheRange) {
  for (const JointModelParams& p : {healthyIndexMcp(), offsetJoint()}) {
    const JointModel m(p);
    for (const Vec3& a : angleGrid(p)) {
      for (double half_width : {0.004, 0.008, 0.015}) {
        const Vec3 back = m.anglesFromGrip(m.gripFromAngles(a, half_width));
        EXPECT_LT((back - a).cwiseAbs().maxCoeff(), 1e-9)
            << "angles " << radToDeg(a.x()) << ", " << radToDeg(a.y()) << ", " << radToDeg(a.z())
            << " deg, half width " << half_width;
      }
    }
  }
}

TEST(JointModel, GripGeometryMatchesTheFrameConvention) {
  const JointModelParams p = offsetJoint();
  const JointModel m(p);
  const Vec3 a(degToRad(35.0), degToRad(-7.0), degToRad(4.0));
  const double hw = 0.008;
  const PerFinger<Vec3> g = m.gripFromAngles(a, hw);
  // R_J · Ry(alpha) · Rx(gamma) · Rz(beta), written out.
  const Mat3 r = p.joint_orientation.toRotationMatrix() *
                 Eigen::AngleAxisd(a[kFlexion], Vec3::UnitY()).toRotationMatrix() *
                 Eigen::AngleAxisd(a[kAxial], Vec3::UnitX()).toRotationMatrix() *
                 Eigen::AngleAxisd(a[kAbduction], Vec3::UnitZ()).toRotationMatrix();
  const Vec3 mid = p.joint_origin_m + r.col(0) * p.lever_arm_m;
  EXPECT_LT((g[kThumb] - (mid + hw * r.col(2))).norm(), 1e-12) << "thumb on the dorsal side";
  EXPECT_LT((g[kIndex] - (mid - hw * r.col(2))).norm(), 1e-12) << "index on the palmar side";
  // Positive flexion moves the grip toward the palm (-z of the joint frame).
  const JointModel neutral(healthyIndexMcp());
  const PerFinger<Vec3> flexed = neutral.gripFromAngles(Vec3(degToRad(30.0), 0, 0), hw);
  EXPECT_LT(0.5 * (flexed[0] + flexed[1]).z(), 0.0);
}

TEST(JointModel, ThimbleOrientationPadsFaceThePhalanx) {
  const JointModelParams p = offsetJoint();
  const JointModel m(p);
  const Vec3 a(degToRad(20.0), degToRad(5.0), degToRad(-3.0));
  const PerFinger<Vec3> g = m.gripFromAngles(a, 0.008);
  const Vec3 axis_point = 0.5 * (g[kThumb] + g[kIndex]);
  for (int k : {kThumb, kIndex}) {
    const Mat3 t = m.thimbleOrientation(k, a).toRotationMatrix();
    EXPECT_NEAR(t.determinant(), 1.0, 1e-12);
    // Pad normal (+z) points from the thimble into the phalanx.
    EXPECT_GT(t.col(2).dot((axis_point - g[k]).normalized()), 1.0 - 1e-12) << k;
    // x along the phalanx.
    EXPECT_GT(t.col(0).dot((axis_point - p.joint_origin_m).normalized()), 1.0 - 1e-12) << k;
  }
}

// ---- Torque mapping -----------------------------------------------------------------------

/// tau_i = e_i . sum_k (p_k - c) x F_k, with e_alpha = R_J y, e_gamma = R_J Ry(alpha) x,
/// e_beta = R_J Ry(alpha) Rx(gamma) z, written out independently of the product code.
Vec3 axisTorqueByHand(const JointModelParams& p, const PerFinger<Vec3>& pos, const Vec3& a,
                      const PerFinger<Vec3>& f) {
  const Vec3 c = p.joint_origin_m;
  const Vec3 tau = (pos[0] - c).cross(f[0]) + (pos[1] - c).cross(f[1]);
  const Quat rj = p.joint_orientation;
  const Quat ry(Eigen::AngleAxisd(a[kFlexion], Vec3::UnitY()));
  const Quat rx(Eigen::AngleAxisd(a[kAxial], Vec3::UnitX()));
  const Vec3 e_alpha = rj * Vec3::UnitY();
  const Vec3 e_gamma = rj * (ry * Vec3::UnitX());
  const Vec3 e_beta = rj * (ry * (rx * Vec3::UnitZ()));
  Vec3 out;
  out[kFlexion] = e_alpha.dot(tau);
  out[kAbduction] = e_beta.dot(tau);
  out[kAxial] = e_gamma.dot(tau);
  return out;
}

/// Angular velocity (device frame) of the phalanx when only angle `axis` moves, by finite
/// differences of phalanxRotation: it must be the basis column the torques act about.
Vec3 angularVelocityOf(const JointModel& m, const Vec3& a, int axis) {
  const double h = 1e-6;
  Vec3 da = Vec3::Zero();
  da[axis] = h;
  const Mat3 w = (m.phalanxRotation(a + da) - m.phalanxRotation(a - da)) / (2 * h) *
                 m.phalanxRotation(a).transpose();  // skew-symmetric [omega]x
  return {w(2, 1), w(0, 2), w(1, 0)};
}

TEST(JointModel, EulerRotationRoundTripsAndMatchesTheStatedOrder) {
  for (const Vec3& a : angleGrid(healthyIndexMcp())) {
    const Mat3 r = eulerToRotation(a);
    const Mat3 want = Eigen::AngleAxisd(a[kFlexion], Vec3::UnitY()).toRotationMatrix() *
                      Eigen::AngleAxisd(a[kAxial], Vec3::UnitX()).toRotationMatrix() *
                      Eigen::AngleAxisd(a[kAbduction], Vec3::UnitZ()).toRotationMatrix();
    EXPECT_LT((r - want).cwiseAbs().maxCoeff(), 1e-12);
    EXPECT_LT((eulerFromRotation(r) - a).cwiseAbs().maxCoeff(), 1e-9);
  }
}

TEST(JointModel, AxisBasisIsTheAngularVelocityPerAngleRate) {
  for (const JointModelParams& p : {healthyIndexMcp(), offsetJoint()}) {
    const JointModel m(p);
    for (const Vec3& a : angleGrid(p)) {
      const Mat3 e = m.axisBasis(a);
      for (int axis = 0; axis < kAxes; ++axis) {
        EXPECT_LT((e.col(axis) - angularVelocityOf(m, a, axis)).norm(), 1e-7)
            << kAxisNames[axis] << " at " << a.transpose();
      }
      // And the torque vector inverts the projection.
      const Vec3 tau_gen(0.02, -0.01, 0.005);
      EXPECT_LT((e.transpose() * m.torqueVector(a, tau_gen) - tau_gen).norm(), 1e-12);
    }
  }
}

TEST(JointModel, AxisTorqueIsTheMomentOfTheFingertipForces) {
  const JointModelParams p = offsetJoint();
  const JointModel m(p);
  const Vec3 a(degToRad(50.0), degToRad(-12.0), degToRad(7.0));
  const PerFinger<Vec3> pos = m.gripFromAngles(a, 0.009);
  const PerFinger<Vec3> f{Vec3(0.7, -1.2, 0.4), Vec3(-0.3, 0.9, 1.5)};
  const Vec3 got = m.axisTorque(pos, a, f);
  const Vec3 want = axisTorqueByHand(p, pos, a, f);
  EXPECT_LT((got - want).norm(), 1e-12) << got.transpose() << " vs " << want.transpose();
}

TEST(JointModel, FlexionForceAtTheLeverGivesForceTimesLever) {
  // 1 N pushing the grip in +alpha with the joint at neutral: 0.01 N·m about e_alpha only.
  const JointModel m(healthyIndexMcp());
  const Vec3 a = Vec3::Zero();
  const PerFinger<Vec3> pos = m.gripFromAngles(a, 0.008);
  const Vec3 push = Vec3::UnitY().cross(Vec3::UnitX());  // d(grip)/d(alpha) direction: -z
  const Vec3 tau = m.axisTorque(pos, a, {0.5 * push, 0.5 * push});
  EXPECT_NEAR(tau[kFlexion], 0.01, 1e-12);
  EXPECT_NEAR(tau[kAbduction], 0.0, 1e-12);
  EXPECT_NEAR(tau[kAxial], 0.0, 1e-12);
}

TEST(JointModel, FingertipForcesReproduceTheRequestedTorque) {
  for (const JointModelParams& p : {healthyIndexMcp(), offsetJoint()}) {
    const JointModel m(p);
    for (const Vec3& a : angleGrid(p)) {
      const PerFinger<Vec3> pos = m.gripFromAngles(a, 0.008);
      for (const Vec3& tau : {Vec3(0.03, 0.0, 0.0), Vec3(0.0, -0.02, 0.0), Vec3(0.0, 0.0, 0.01),
                              Vec3(-0.04, 0.015, -0.006)}) {
        const PerFinger<Vec3> f = m.fingertipForces(pos, a, tau);
        const Vec3 back = m.axisTorque(pos, a, f);
        EXPECT_LT((back - tau).cwiseAbs().maxCoeff(), 1e-9)
            << "angles " << radToDeg(a.x()) << ", " << radToDeg(a.y()) << ", " << radToDeg(a.z())
            << " deg, tau " << tau.transpose() << " -> " << back.transpose();
        EXPECT_LT((axisTorqueByHand(p, pos, a, f) - tau).cwiseAbs().maxCoeff(), 1e-9);
      }
    }
  }
}

TEST(JointModel, FingertipForcesReproduceTheTorqueForAMeasuredSkewedGrip) {
  // Real thimbles are never exactly where gripFromAngles puts them: the pinch line may lean
  // along the phalanx and the grip centre may sit off the lever arm. The forces must still
  // exert the requested torque.
  const JointModelParams p = offsetJoint();
  const JointModel m(p);
  const Vec3 a(degToRad(45.0), degToRad(6.0), degToRad(-4.0));
  PerFinger<Vec3> pos = m.gripFromAngles(a, 0.008);
  pos[kThumb] += Vec3(0.002, -0.001, 0.0015);
  pos[kIndex] += Vec3(-0.0015, 0.0005, 0.001);
  const Vec3 measured = m.anglesFromGrip(pos);
  for (const Vec3& tau : {Vec3(0.03, 0.0, 0.0), Vec3(0.0, 0.0, 0.01), Vec3(-0.04, 0.015, -0.006)}) {
    const PerFinger<Vec3> f = m.fingertipForces(pos, measured, tau);
    const Vec3 back = m.axisTorque(pos, measured, f);
    EXPECT_LT((back - tau).cwiseAbs().maxCoeff(), 1e-9)
        << "tau " << tau.transpose() << " -> " << back.transpose();
  }
}

TEST(JointModel, FingertipForcesPutTheLoadOnThePushingFinger) {
  // Through the band (12-16 N reference, 3-4 N at the device) and its mirror: the finger whose
  // pad the force presses carries it up to kFingerLoadN, the other the rest; exact torque.
  for (const JointModelParams& p : {healthyIndexMcp(), offsetJoint()}) {
    const JointModel m(p);
    const Vec3 a(degToRad(30.0), degToRad(4.0), degToRad(-3.0));
    const PerFinger<Vec3> pos = m.gripFromAngles(a, 0.008);
    const Vec3 dorsal = (pos[kThumb] - pos[kIndex]).normalized();
    for (double ref_n : {12.0, 14.0, 16.0}) {
      for (double sign : {-1.0, 1.0}) {
        // The joint resisting a flexion push (sign -1: torque toward extension) or an
        // extension push, at device scale.
        const Vec3 tau(sign * ref_n * p.lever_arm_m * p.force_scale, 0.0, 0.0);
        const PerFinger<Vec3> f = m.fingertipForces(pos, a, tau);
        EXPECT_LT((m.axisTorque(pos, a, f) - tau).cwiseAbs().maxCoeff(), 1e-12);
        const int pusher = sign < 0.0 ? kThumb : kIndex;  // the force points dorsally: thumb
        // The net force carries the torque across the phalanx: its size is the band's force
        // within the cosine of the abduction and axial angles.
        const Vec3 net = f[0] + f[1];
        EXPECT_NEAR(net.norm(), ref_n * p.force_scale, 0.01 * ref_n * p.force_scale);
        // Along the pinch line the pushing finger takes the load up to kFingerLoadN (less the
        // small share the smooth blend through zero leaves, under 2 %), the other the rest;
        // across it both share equally, and the part of the torque along the phalanx (the
        // flexion axis leans on it when abducted or rotated) is an equal and opposite couple.
        const double along = std::abs(net.dot(dorsal));
        const double across = (net - dorsal * net.dot(dorsal)).norm();
        const Vec3 mid = 0.5 * (pos[kThumb] + pos[kIndex]);
        const Vec3 u = (mid - p.joint_origin_m).normalized();
        const Vec3 s_perp = (pos[kIndex] - mid) - u * u.dot(pos[kIndex] - mid);
        const double couple = std::abs(u.dot(m.torqueVector(a, tau))) / (2.0 * s_perp.norm());
        EXPECT_GE(f[pusher].norm(), 0.98 * std::min(along, kFingerLoadN) - couple) << ref_n;
        EXPECT_LE(f[1 - pusher].norm(),
                  std::max(along - kFingerLoadN, 0.02 * along) + 0.5 * across + couple + 1e-9)
            << ref_n;
        EXPECT_GT(f[pusher].dot(pusher == kThumb ? dorsal : Vec3(-dorsal)), 0.0)
            << "the pad is pressed, not pulled";
        EXPECT_LE(f[pusher].norm(), 4.0);
      }
    }
  }
}

TEST(JointModel, FingertipForcesStayContinuousThroughAReversal) {
  // The flexion torque sweeps through zero in small steps: no finger's force steps.
  const JointModel m(healthyIndexMcp());
  const Vec3 a(degToRad(10.0), 0.0, 0.0);
  const PerFinger<Vec3> pos = m.gripFromAngles(a, 0.008);
  constexpr double kStep = 1e-6;  // N·m: 0.1 mN of net force at the lever
  PerFinger<Vec3> last = m.fingertipForces(pos, a, Vec3(-0.02, 0.0, 0.0));
  double worst = 0.0;
  for (double t = -0.02 + kStep; t <= 0.02; t += kStep) {
    const PerFinger<Vec3> f = m.fingertipForces(pos, a, Vec3(t, 0.0, 0.0));
    for (int k = 0; k < 2; ++k) worst = std::max(worst, (f[k] - last[k]).norm());
    last = f;
  }
  // Net force changes by kStep / lever per step; a finger by at most ~1.2 times that.
  EXPECT_LT(worst, 1.25 * kStep / 0.01);
}

TEST(JointModel, FingertipForcesAreZeroForADegenerateGrip) {
  const JointModelParams p = offsetJoint();
  const JointModel m(p);
  const PerFinger<Vec3> at_centre{p.joint_origin_m, p.joint_origin_m};
  const PerFinger<Vec3> f = m.fingertipForces(at_centre, Vec3::Zero(), Vec3(0.02, 0.01, 0.0));
  EXPECT_TRUE(f[0].isZero());
  EXPECT_TRUE(f[1].isZero());
  const double nan = std::nan("");
  const PerFinger<Vec3> g =
      m.fingertipForces(m.gripFromAngles(Vec3::Zero(), 0.008), Vec3::Zero(), Vec3(nan, 0.0, 0.0));
  EXPECT_TRUE(allFinite(g[0]) && allFinite(g[1]));
}

// ---- Proxy --------------------------------------------------------------------------------

/// A slow flexion sweep of the grip (1 Hz, 20 deg amplitude around 40 deg) at 1 kHz.
PerFinger<Vec3> sweep(const JointModel& m, int64_t t_ns) {
  const double t = static_cast<double>(t_ns) * 1e-9;
  const Vec3 a(degToRad(40.0 + 20.0 * std::sin(2 * kPi * 1.0 * t)), degToRad(3.0), degToRad(1.0));
  return m.gripFromAngles(a, 0.008);
}

/// The same joint, a very different (stiff, offset) passive curve.
JointModelParams stiffModel() {
  JointModelParams p = healthyIndexMcp();
  p.version = 2;
  p.axes[kFlexion].coeffs = {6e-5, 0.004, 0.2, 5.0};
  p.axes[kAbduction].coeffs = {0.0005, 0.004, 0.5, 1.0};
  p.damping_nms_per_rad = 0.006;
  return p;
}

double maxStep(const std::vector<PerFinger<Vec3>>& f, std::size_t from, std::size_t to) {
  double m = 0.0;
  for (std::size_t i = std::max<std::size_t>(from, 1); i < to; ++i) {
    for (int k = 0; k < 2; ++k) m = std::max(m, (f[i][k] - f[i - 1][k]).norm());
  }
  return m;
}

TEST(JointProxy, RendersThePassiveTorqueAtTheDeviceScale) {
  const JointModelParams p = healthyIndexMcp();
  JointProxy proxy(p);
  const JointModel m(p);
  const Vec3 a(degToRad(50.0), degToRad(-5.0), degToRad(3.0));
  const PerFinger<Vec3> grip = m.gripFromAngles(a, 0.008);
  ProxyOutput out;
  for (int64_t t = 0; t <= 100 * kNsPerMs; t += kNsPerMs) out = proxy.render(grip, t);
  EXPECT_LT((out.angles_rad - a).norm(), 1e-9);
  EXPECT_FALSE(out.blending);
  // Still grip: no damping term after the rate filter settles.
  EXPECT_LT((out.torque_ref_nm - m.passiveTorqueNm(a, Vec3::Zero())).norm(), 1e-12);
  const Vec3 exerted = m.axisTorque(grip, a, out.force_device_n);
  EXPECT_LT((exerted - 0.25 * out.torque_ref_nm).norm(), 1e-9);
}

TEST(JointProxy, CrossFadeHasNoForceStepAndEndsOnTheNewModel) {
  const JointModelParams old_p = healthyIndexMcp();
  const JointModelParams new_p = stiffModel();
  const JointModel geom(old_p);
  constexpr int64_t kBlendNs = 200 * kNsPerMs;
  constexpr int64_t kSwitchNs = 300 * kNsPerMs;
  constexpr int kTicks = 800;

  JointProxy proxy(old_p, kBlendNs);
  JointProxy only_old(old_p, kBlendNs);
  JointProxy only_new(new_p, kBlendNs);
  std::vector<PerFinger<Vec3>> f, f_old, f_new;
  std::vector<bool> blending;
  double max_gap = 0.0;  // |new - old| while blending: the step a hard switch would cause
  for (int i = 0; i < kTicks; ++i) {
    const int64_t t = i * kNsPerMs;
    if (t == kSwitchNs) proxy.setModel(new_p);
    const PerFinger<Vec3> g = sweep(geom, t);
    const ProxyOutput out = proxy.render(g, t);
    if (t == kSwitchNs) {
      EXPECT_EQ(proxy.version(), 2u) << "adopted on the tick it arrived";
    }
    f.push_back(out.force_device_n);
    blending.push_back(out.blending);
    f_old.push_back(only_old.render(g, t).force_device_n);
    f_new.push_back(only_new.render(g, t).force_device_n);
    if (t >= kSwitchNs && t < kSwitchNs + kBlendNs) {
      for (int k = 0; k < 2; ++k) max_gap = std::max(max_gap, (f_new[i][k] - f_old[i][k]).norm());
    }
  }
  const std::size_t sw = kSwitchNs / kNsPerMs;
  const std::size_t end = (kSwitchNs + kBlendNs) / kNsPerMs;

  // The models really differ: switching without a fade would jump by this much in one tick.
  const double normal = std::max(maxStep(f_old, 0, kTicks), maxStep(f_new, 0, kTicks));
  ASSERT_GT(max_gap, 10.0 * normal) << "the test models are not different enough";

  // Before the switch, the old model exactly.
  for (std::size_t i = 0; i < sw; ++i) {
    EXPECT_EQ(f[i][0], f_old[i][0]) << i;
    EXPECT_FALSE(blending[i]) << i;
  }
  // During the fade: no tick-to-tick step beyond the trajectory's own change plus the fade's
  // share (smoothstep's steepest slope is 1.5 / blend).
  const double fade_share = 1.5 * max_gap / static_cast<double>(kBlendNs / kNsPerMs);
  EXPECT_LE(maxStep(f, sw - 1, end + 1), normal + fade_share + 1e-9);
  EXPECT_LT(maxStep(f, sw - 1, end + 1), 0.1 * max_gap);
  for (std::size_t i = sw; i < end; ++i) EXPECT_TRUE(blending[i]) << i;
  // After the fade: the new model exactly, and no longer blending.
  for (std::size_t i = end; i < static_cast<std::size_t>(kTicks); ++i) {
    EXPECT_FALSE(blending[i]) << i;
    for (int k = 0; k < 2; ++k) EXPECT_LT((f[i][k] - f_new[i][k]).norm(), 1e-12) << i;
  }
}

TEST(JointProxy, ZeroBlendSwitchesAtOnce) {
  const JointModelParams new_p = stiffModel();
  JointProxy proxy(healthyIndexMcp(), 0);
  JointProxy only_new(new_p, 0);
  const JointModel geom(new_p);
  for (int i = 0; i < 20; ++i) {
    const int64_t t = i * kNsPerMs;
    if (i == 10) proxy.setModel(new_p);
    const PerFinger<Vec3> g = sweep(geom, t);
    const ProxyOutput out = proxy.render(g, t);
    const ProxyOutput ref = only_new.render(g, t);
    if (i >= 10) {
      EXPECT_FALSE(out.blending);
      EXPECT_LT((out.force_device_n[0] - ref.force_device_n[0]).norm(), 1e-12) << i;
    }
  }
}

GuideParams testGuide(double authority) {
  GuideParams g;
  g.authority = authority;
  g.period_s = 0.5;
  for (int k = 0; k < GuideParams::kPoints; ++k) {
    const double ph = 2.0 * M_PI * k / GuideParams::kPoints;
    g.path_rad[static_cast<std::size_t>(k)] =
        Vec3(degToRad(10.0 + 5.0 * std::sin(ph)), degToRad(1.0), 0.0);
  }
  return g;
}

TEST(Guide, LeadsTowardThePathBoundedByItsAuthority) {
  JointModelParams p = healthyIndexMcp();
  p.guide = testGuide(1.0);
  const JointModel m(p);
  // On the path, moving with it: no force.
  Vec3 rates;
  const Vec3 on = m.guideTargetRad(0.125, &rates);
  EXPECT_NEAR(radToDeg(on[kFlexion]), 15.0, 0.05) << "a quarter period: the swing's top";
  EXPECT_LT(m.guideTorqueNm(on, rates, 0.125).norm(), 1e-9);
  // Periodic.
  EXPECT_LT((m.guideTargetRad(0.125 + 3 * 0.5) - on).norm(), 1e-9);
  // Behind the path: pulled toward it, k per degree, then bounded.
  Vec3 behind = on;
  behind[kFlexion] -= degToRad(2.0);
  const Vec3 pull = m.guideTorqueNm(behind, rates, 0.125);
  EXPECT_NEAR(pull[kFlexion], 2.0 * p.guide.stiffness_n_per_deg * p.lever_arm_m, 1e-9);
  Vec3 far = on;
  far[kFlexion] -= degToRad(60.0);
  EXPECT_NEAR(m.guideTorqueNm(far, rates, 0.125)[kFlexion], p.guide.max_force_n * p.lever_arm_m,
              1e-12);
  // Authority scales it; none is no force; a guide asking beyond the limits is held to them.
  JointModelParams half = p;
  half.guide.authority = 0.5;
  EXPECT_NEAR(JointModel(half).guideTorqueNm(far, rates, 0.125)[kFlexion],
              0.5 * p.guide.max_force_n * p.lever_arm_m, 1e-12);
  JointModelParams none = p;
  none.guide.authority = 0.0;
  EXPECT_EQ(JointModel(none).guideTorqueNm(far, rates, 0.125), Vec3::Zero());
  JointModelParams greedy = p;
  greedy.guide.max_force_n = 1e6;
  greedy.guide.stiffness_n_per_deg = 1e6;
  EXPECT_LE(std::abs(JointModel(greedy).guideTorqueNm(far, rates, 0.125)[kFlexion]),
            GuideParams::kMaxForceN * p.lever_arm_m + 1e-12);
}

TEST(Guide, TheProxyRendersItAndFadesItsAuthority) {
  JointModelParams p = healthyIndexMcp();
  const JointModel m(p);
  const Vec3 at(degToRad(10.0), 0.0, 0.0);
  const PerFinger<Vec3> grip = m.gripFromAngles(at, 0.008);
  JointProxy proxy(p, 200'000'000);
  int64_t t = 1'000'000'000;
  const ProxyOutput plain = proxy.render(grip, t);
  EXPECT_EQ(plain.guide_ref_nm, Vec3::Zero());
  JointModelParams guided = p;
  guided.version = 2;
  guided.guide = testGuide(1.0);
  proxy.setModel(guided);
  double last = 0.0, largest_step = 0.0;
  for (int i = 0; i < 400; ++i) {
    t += 1'000'000;
    const ProxyOutput o = proxy.render(grip, t);
    const double g = o.guide_ref_nm.norm();
    largest_step = std::max(largest_step, std::abs(g - last));
    last = g;
  }
  EXPECT_GT(last, 0.0) << "after the fade the guide acts";
  // Faded in, not stepped: no tick changes the guide by more than the update bound allows.
  EXPECT_LT(largest_step * p.force_scale / p.lever_arm_m, 0.15);
}

}  // namespace
}  // namespace telehand
