// Paper eqs. 1-2 (docs/facts.md "The paper"): F_tangential = F2 - F3, F_normal = sqrt(F4^2 + F1^2).
#include <gtest/gtest.h>

#include <cmath>

#include "telehand/core/thimble.h"

namespace telehand {
namespace {

TEST(Thimble, TangentialIsSensorTwoMinusSensorThree) {
  // Index 0..3 = sensors 1..4; values exactly representable in float.
  const ThimbleForces f = thimbleForces({1.0f, 2.5f, 0.75f, 4.0f});
  EXPECT_DOUBLE_EQ(f.tangential_n, 2.5 - 0.75);
  const ThimbleForces g = thimbleForces({0.0f, 0.5f, 3.0f, 0.0f});
  EXPECT_DOUBLE_EQ(g.tangential_n, -2.5) << "eq. 1 is signed: F3 > F2 gives a negative force";
}

TEST(Thimble, NormalIsHypotOfEndAndPadSensors) {
  const ThimbleForces f = thimbleForces({3.0f, 7.0f, 7.0f, 4.0f});
  EXPECT_DOUBLE_EQ(f.normal_n, 5.0);  // sqrt(4^2 + 3^2)
  EXPECT_DOUBLE_EQ(f.tangential_n, 0.0);
  const ThimbleForces pad_only = thimbleForces({0.0f, 0.0f, 0.0f, 10.0f});
  EXPECT_DOUBLE_EQ(pad_only.normal_n, 10.0);
  const ThimbleForces end_only = thimbleForces({6.0f, 0.0f, 0.0f, 0.0f});
  EXPECT_DOUBLE_EQ(end_only.normal_n, 6.0);
  const ThimbleForces both = thimbleForces({1.0f, 0.0f, 0.0f, 4.0f});
  EXPECT_DOUBLE_EQ(both.normal_n, std::sqrt(17.0));
}

TEST(Thimble, SidesDoNotEnterTheNormalForce) {
  const ThimbleForces a = thimbleForces({1.0f, 0.0f, 0.0f, 2.0f});
  const ThimbleForces b = thimbleForces({1.0f, 9.0f, 5.0f, 2.0f});
  EXPECT_DOUBLE_EQ(a.normal_n, b.normal_n);
  EXPECT_DOUBLE_EQ(b.tangential_n, 4.0);
}

TEST(Thimble, ZeroReadingsGiveZeroForce) {
  const ThimbleForces f = thimbleForces({0.0f, 0.0f, 0.0f, 0.0f});
  EXPECT_EQ(f.tangential_n, 0.0);
  EXPECT_EQ(f.normal_n, 0.0);
  EXPECT_TRUE(thimbleForceVector(f, Quat::Identity()).isZero());
}

TEST(Thimble, VectorInThimbleFrameIsTangentialAlongYNormalAlongZ) {
  ThimbleForces f;
  f.tangential_n = 1.5;
  f.normal_n = 3.0;
  const Vec3 v = thimbleForceVector(f, Quat::Identity());
  EXPECT_DOUBLE_EQ(v.x(), 0.0);
  EXPECT_DOUBLE_EQ(v.y(), 1.5);
  EXPECT_DOUBLE_EQ(v.z(), 3.0);
}

TEST(Thimble, VectorRotatesWithTheThimbleOrientation) {
  ThimbleForces f;
  f.tangential_n = 2.0;
  f.normal_n = 5.0;
  // +90 deg about x: thimble y -> device z, thimble z -> device -y.
  const Quat about_x(Eigen::AngleAxisd(kPi / 2, Vec3::UnitX()));
  const Vec3 v = thimbleForceVector(f, about_x);
  EXPECT_NEAR(v.x(), 0.0, 1e-12);
  EXPECT_NEAR(v.y(), -5.0, 1e-12);
  EXPECT_NEAR(v.z(), 2.0, 1e-12);

  // +90 deg about y: thimble z (pad normal) -> device +x.
  const Quat about_y(Eigen::AngleAxisd(kPi / 2, Vec3::UnitY()));
  const Vec3 w = thimbleForceVector(f, about_y);
  EXPECT_NEAR(w.x(), 5.0, 1e-12);
  EXPECT_NEAR(w.y(), 2.0, 1e-12);
  EXPECT_NEAR(w.z(), 0.0, 1e-12);
}

TEST(Thimble, VectorMagnitudeIsIndependentOfOrientation) {
  const ThimbleForces f = thimbleForces({1.0f, 3.0f, 1.0f, 2.0f});
  const double expected = std::hypot(f.tangential_n, f.normal_n);
  for (double angle : {0.1, 0.7, 1.9, -2.4}) {
    const Quat q(Eigen::AngleAxisd(angle, Vec3(1.0, -2.0, 0.5).normalized()));
    EXPECT_NEAR(thimbleForceVector(f, q).norm(), expected, 1e-12) << "angle " << angle;
  }
}

}  // namespace
}  // namespace telehand
