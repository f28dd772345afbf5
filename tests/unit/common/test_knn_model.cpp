// The data-driven joint model: FLANN k-nearest-neighbour regression over captured samples.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <numbers>
#include <random>
#include <span>
#include <string>
#include <vector>

#include "telehand/core/error.h"
#include "telehand/core/joint_model.h"
#include "telehand/core/knn_model.h"
#include "telehand/protocol/wire.h"

namespace telehand {
namespace {

TEST(KnnTorqueModel, NearestSamplesAndInverseDistanceWeights) {
  std::vector<KnnPoint> pts;
  for (int i = -10; i <= 10; ++i) {
    pts.push_back({Vec3(degToRad(3.0 * i), 0, 0), Vec3(0.01 * i, 0, 0)});
  }
  KnnOptions one;
  one.k = 1;
  const KnnTorqueModel m1(pts, one);
  EXPECT_NEAR(m1.torqueNm(Vec3(degToRad(6.2), 0, 0))[0], 0.02, 1e-12) << "the sample at 6 deg";
  // Beyond the samples: the nearest one, no extrapolation.
  EXPECT_NEAR(m1.torqueNm(Vec3(degToRad(80.0), 0, 0))[0], 0.10, 1e-12);
  KnnOptions two;
  two.k = 2;
  const KnnTorqueModel m2(pts, two);
  // Midway between two samples: equal weights.
  EXPECT_NEAR(m2.torqueNm(Vec3(degToRad(4.5), 0, 0))[0], 0.015, 1e-12);
  // A quarter of the way (distances 0.25 and 0.75 cells): weights 1/0.75 and 1/1.25.
  const double w0 = 1.0 / 0.75, w1 = 1.0 / 1.25;
  EXPECT_NEAR(m2.torqueNm(Vec3(degToRad(3.75), 0, 0))[0], (w0 * 0.01 + w1 * 0.02) / (w0 + w1),
              1e-12);
  EXPECT_EQ(m2.size(), 21u);
}

TEST(KnnTorqueModel, CloseToBruteForceNeighbours) {
  // FLANN's kd-tree search (one tree, unlimited checks) bounds its pruning loosely: it
  // returns the exact neighbours for almost every query, and near neighbours otherwise.
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-0.6, 0.6);
  std::vector<KnnPoint> pts;
  for (int i = 0; i < 3000; ++i) {
    const Vec3 a(u(rng), 0.4 * u(rng), 0.3 * u(rng));
    pts.push_back({a, Vec3(std::sin(a[0]), a[1] * a[0], a[2])});
  }
  KnnOptions o;
  o.k = 6;
  const KnnTorqueModel m(pts, o);
  const Vec3 inv = o.cell_deg.unaryExpr([](double d) { return 1.0 / degToRad(d); });
  int exact = 0;
  double worst = 0.0;
  constexpr int kQueries = 400;
  for (int q = 0; q < kQueries; ++q) {
    const Vec3 a(u(rng), 0.4 * u(rng), 0.3 * u(rng));
    std::vector<std::pair<double, std::size_t>> d;
    for (std::size_t i = 0; i < pts.size(); ++i) {
      d.push_back({(pts[i].angles_rad - a).cwiseProduct(inv).norm(), i});
    }
    std::partial_sort(d.begin(), d.begin() + 6, d.end());
    Vec3 sum = Vec3::Zero();
    double ws = 0.0;
    for (int j = 0; j < 6; ++j) {
      const double w = 1.0 / (d[j].first + 0.5);
      sum += w * pts[d[j].second].torque_nm;
      ws += w;
    }
    const double diff = (m.torqueNm(a) - sum / ws).norm();
    exact += diff < 1e-9;
    worst = std::max(worst, diff);
  }
  EXPECT_GE(exact, kQueries * 9 / 10);
  EXPECT_LT(worst, 0.05) << "torques here span about ±0.6";
  std::printf("exact neighbours for %d of %d queries; worst torque difference %.4f\n", exact,
              kQueries, worst);
}

TEST(KnnTorqueModel, BadSamplesAreRefused) {
  EXPECT_THROW(KnnTorqueModel({}), Error);
  std::vector<KnnPoint> nan{{Vec3(std::nan(""), 0, 0), Vec3::Zero()}};
  EXPECT_THROW(KnnTorqueModel{nan}, Error);
}

TEST(KnnTorqueModel, VoxelAverageMeansPerCell) {
  std::vector<KnnPoint> pts;
  for (int i = 0; i < 10; ++i)
    pts.push_back({Vec3(degToRad(0.5 + 0.1 * i), 0.001, 0.001), Vec3(i, 0, 0)});
  pts.push_back({Vec3(degToRad(10.5), 0.001, 0.001), Vec3(100, 0, 0)});  // alone in its cell
  const auto v = voxelAverage(pts, Vec3(3.0, 1.0, 1.0), 3);
  ASSERT_EQ(v.size(), 1u);
  EXPECT_NEAR(v[0].torque_nm[0], 4.5, 1e-12);
  EXPECT_NEAR(radToDeg(v[0].angles_rad[0]), 0.95, 1e-9);
}

TEST(KnnModelWire, AModelFillingTheHealthyRangeFitsUnderTheCap) {
  // The largest model a capture of the healthy joint gives: every cell of its range of motion
  // (as the live refit averages them: KnnOptions' cells, at least 3 samples each) filled.
  const JointModelParams h = healthyIndexMcp();
  const Vec3 cell = KnnOptions{}.cell_deg;
  std::vector<KnnPoint> raw;
  auto centres = [&](int axis) {
    std::vector<double> out;
    const CubicCurve& c = h.axes[static_cast<std::size_t>(axis)];
    for (double d = c.min_deg + 0.5 * cell[axis]; d < c.max_deg; d += cell[axis]) {
      out.push_back(degToRad(d));
    }
    return out;
  };
  for (double f : centres(kFlexion)) {
    for (double b : centres(kAbduction)) {
      for (double g : centres(kAxial)) {
        Vec3 a;
        a[kFlexion] = f;
        a[kAbduction] = b;
        a[kAxial] = g;
        for (int k = 0; k < 3; ++k) raw.push_back({a, -0.01 * a});
      }
    }
  }
  const auto cells = voxelAverage(raw, cell, 3);
  EXPECT_EQ(cells.size(), 45u * 40u * 25u);
  EXPECT_LT(cells.size(), kMaxKnnSamples);
  const KnnTorqueModel model(cells);
  std::vector<telehand_msg_KnnSample> storage;
  telehand_msg_KnnModel w{};
  toWire(model, 1, 2, storage, w);
  std::string why;
  const auto back = fromWire(w, &why);
  ASSERT_NE(back, nullptr) << why;
  EXPECT_EQ(back->size(), cells.size());
}

TEST(KnnModelWire, FromWireRefusesTooManySamplesAndAnglesBeyondPi) {
  using ::testing::AllOf;
  using ::testing::HasSubstr;
  std::vector<telehand_msg_KnnSample> samples(kMaxKnnSamples + 1);
  for (std::size_t i = 0; i < samples.size(); ++i) {
    samples[i].angles_rad[kFlexion] = 1e-5f * static_cast<float>(i);
  }
  telehand_msg_KnnModel w{};
  w.k = 8;
  borrowSequence(w.samples, std::span<telehand_msg_KnnSample>(samples));
  std::string why;
  EXPECT_EQ(fromWire(w, &why), nullptr);
  EXPECT_THAT(why, AllOf(HasSubstr("65537 samples"), HasSubstr("65536")));

  // At the cap it is taken.
  borrowSequence(w.samples, std::span<telehand_msg_KnnSample>(samples.data(), kMaxKnnSamples));
  why.clear();
  EXPECT_NE(fromWire(w, &why), nullptr) << why;

  // Angles are Euler angles: ±π (as a float holds it) is the furthest one may be.
  samples.assign(4, telehand_msg_KnnSample{});
  for (int axis = 0; axis < kAxes; ++axis) {
    const std::string name(kAxisNames[static_cast<std::size_t>(axis)]);
    for (float edge : {std::numbers::pi_v<float>, -std::numbers::pi_v<float>}) {
      samples[2].angles_rad[axis] = edge;
      borrowSequence(w.samples, std::span<telehand_msg_KnnSample>(samples));
      why.clear();
      EXPECT_NE(fromWire(w, &why), nullptr) << name << " " << edge << ": " << why;
    }
    for (float bad : {3.2f, -3.2f, 1e30f}) {
      samples[2].angles_rad[axis] = bad;
      borrowSequence(w.samples, std::span<telehand_msg_KnnSample>(samples));
      why.clear();
      EXPECT_EQ(fromWire(w, &why), nullptr) << name << " " << bad;
      EXPECT_THAT(why, AllOf(HasSubstr("sample 2"), HasSubstr(name), HasSubstr("beyond ±π")));
    }
    samples[2].angles_rad[axis] = 0.0f;
  }
}

TEST(KnnTorqueModel, JointModelRendersItWithWallsAndDamping) {
  // The samples hold a linear spring on every axis; the joint model adds its end walls.
  std::vector<KnnPoint> pts;
  for (double a = -40; a <= 80; a += 2) {
    for (double b = -15; b <= 15; b += 1) {
      pts.push_back({Vec3(degToRad(a), degToRad(b), 0), Vec3(-0.001 * a, -0.002 * b, 0)});
    }
  }
  KnnOptions o;
  o.k = 1;
  const KnnTorqueModel knn(pts, o);
  JointModelParams p = healthyIndexMcp();
  p.knn = &knn;
  p.damping_nms_per_rad = 0.0;
  const JointModel m(p);
  const Vec3 t = m.passiveTorqueNm(Vec3(degToRad(20), degToRad(5), 0), Vec3::Zero());
  EXPECT_NEAR(t[0], -0.02, 1e-12);
  EXPECT_NEAR(t[1], -0.01, 1e-12);
  // 5 deg past the 90 deg flexion limit: the last samples (80 deg) plus 5 N/deg... at 1 cm.
  const Vec3 w = m.passiveTorqueNm(Vec3(degToRad(95), 0, 0), Vec3::Zero());
  EXPECT_NEAR(w[0], -0.08 - kWallNPerDeg * 5.0 * p.lever_arm_m, 1e-9);
  p.damping_nms_per_rad = 0.01;
  EXPECT_NEAR(JointModel(p).passiveTorqueNm(Vec3(degToRad(20), 0, 0), Vec3(2.0, 0, 0))[0],
              -0.02 - 0.02, 1e-12);
}

// A capture spread over more cells than a client takes is sent coarser, never refused: a grid
// of 70,000 cells of 3 samples each, the torque a linear spring's.
TEST(KnnTorqueModel, ACaptureOverMoreCellsThanAClientTakesIsSentCoarser) {
  const Vec3 cell = KnnOptions{}.cell_deg;
  std::vector<KnnPoint> raw;
  for (int i = 0; i < 70; ++i) {
    for (int j = 0; j < 40; ++j) {
      for (int k = 0; k < 25; ++k) {
        const Vec3 deg((i + 0.5) * cell.x() - 60.0, (j + 0.5) * cell.y() - 20.0,
                       (k + 0.5) * cell.z() - 12.0);
        const Vec3 rad = deg.unaryExpr([](double d) { return degToRad(d); });
        for (int n = 0; n < 3; ++n) raw.push_back({rad, -0.01 * rad});
      }
    }
  }
  ASSERT_EQ(voxelAverage(raw, cell, 3).size(), 70'000u);
  Vec3 used = Vec3::Zero();
  const auto sent = voxelAverageAtMost(raw, cell, 3, kMaxKnnSamples, &used);
  EXPECT_LE(sent.size(), kMaxKnnSamples);
  EXPECT_GT(sent.size(), kMaxKnnSamples / 4) << "no coarser than it must be";
  EXPECT_GT(used.x(), cell.x());
  for (const auto& p : sent) {
    for (int a = 0; a < kAxes; ++a) EXPECT_NEAR(p.torque_nm[a], -0.01 * p.angles_rad[a], 1e-12);
  }
  // Under the bound, the cells as they were.
  EXPECT_EQ(voxelAverageAtMost(raw, cell, 3, 70'000).size(), 70'000u);
}

}  // namespace
}  // namespace telehand
