// The link keeps a k-nearest-neighbour model alive for as long as the haptic loop may read it:
// many models arriving during a fade (each replacing the one waiting for the fade to end) must
// not free the model being faded out, and what the loop no longer reads is freed.
#include <gtest/gtest.h>

#include <algorithm>
#include <memory>
#include <vector>

#include "telehand/client/link/knn_keeper.h"
#include "telehand/client/loop/haptic_loop.h"
#include "telehand/core/clock.h"
#include "telehand/devices/simulated_mf2.h"

namespace telehand::client::link {
namespace {

/// A k-NN model of the healthy joint, its torques scaled by `scale`.
std::shared_ptr<const KnnTorqueModel> knnOf(double scale) {
  const JointModel cubic(healthyIndexMcp());
  std::vector<KnnPoint> pts;
  for (double a = -40; a <= 85; a += 5) {
    for (double b = -18; b <= 18; b += 4) {
      for (double g = -9; g <= 14; g += 4) {
        const Vec3 ang(degToRad(a), degToRad(b), degToRad(g));
        pts.push_back({ang, scale * cubic.passiveTorqueNm(ang, Vec3::Zero())});
      }
    }
  }
  return std::make_shared<const KnnTorqueModel>(std::move(pts));
}

class KnnKeeperTest : public ::testing::Test {
 protected:
  /// The link's part: a model built, kept, and handed to the loop as the next version.
  void arrive(double scale) {
    std::shared_ptr<const KnnTorqueModel> m = knnOf(scale);
    watched_.push_back({m.get(), m});
    JointModelParams p = healthyIndexMcp();
    p.version = ++version_;
    p.knn = keeper_.keep(std::move(m));
    ASSERT_TRUE(hl_.models().tryPush(p));
    keeper_.pushed(p, pushed_++);
  }
  /// One loop tick, then the link frees what the loop no longer reads.
  void tick() {
    clock_.advance(kNsPerMs);
    hl_.step();
    Sample s;
    while (hl_.samples().tryPop(s)) {
    }
    keeper_.release(hl_.knnInUse(), nullptr);
    // Whatever the proxy may read is alive.
    for (const KnnTorqueModel* held : hl_.proxy().knnInUse()) {
      if (held == nullptr) continue;
      ASSERT_FALSE(weakOf(held).expired()) << "a model the loop reads was freed";
    }
    max_kept_ = std::max(max_kept_, keeper_.size());
  }
  std::weak_ptr<const KnnTorqueModel> weakOf(const KnnTorqueModel* p) const {
    for (const auto& w : watched_) {
      if (w.first == p) return w.second;
    }
    return {};
  }

  ManualClock clock_{kNsPerS};
  devices::SimulatedMf2 dev_{healthyIndexMcp(), OperatorConfig{}, clock_};
  loop::HapticLoop hl_{dev_, clock_, healthyIndexMcp(), SafetyLimits{}};
  KnnKeeper keeper_;
  std::vector<std::pair<const KnnTorqueModel*, std::weak_ptr<const KnnTorqueModel>>> watched_;
  uint32_t version_ = 1;
  uint64_t pushed_ = 0;
  std::size_t max_kept_ = 0;
};

TEST_F(KnnKeeperTest, AModelFadingOutLivesWhileManyArriveAndIsFreedAfter) {
  arrive(1.0);  // A
  for (int i = 0; i < 1000; ++i) tick();
  ASSERT_FALSE(hl_.proxy().blending());
  const KnnTorqueModel* a = watched_[0].first;
  ASSERT_EQ(hl_.proxy().model().params().knn, a);

  arrive(1.02);  // B: the fade from A starts
  tick();
  ASSERT_TRUE(hl_.proxy().blending());
  // 30 more within the fade, one a tick: each waits for the fade to end and the newest wins.
  for (int i = 0; i < 30; ++i) {
    arrive(1.0 + 0.001 * i);
    tick();
    ASSERT_TRUE(hl_.proxy().blending()) << i;
    EXPECT_FALSE(weakOf(a).expired()) << "A is still faded out, after " << i + 1 << " more";
  }
  // The fades run out; nothing more arrives.
  for (int i = 0; i < 3000; ++i) tick();
  ASSERT_FALSE(hl_.proxy().blending());
  EXPECT_TRUE(weakOf(a).expired()) << "A is no longer read: freed";
  const KnnTorqueModel* rendered = hl_.proxy().model().params().knn;
  EXPECT_EQ(rendered, watched_.back().first) << "the newest won";
  EXPECT_EQ(keeper_.size(), 1u) << "only the rendered model is kept";
  std::size_t alive = 0;
  for (const auto& w : watched_) alive += !w.second.expired();
  EXPECT_EQ(alive, 1u);
  EXPECT_LE(max_kept_, 8u + 3u) << "at most the ring's and the proxy's";
}

TEST_F(KnnKeeperTest, AModelStillInTheRingIsKeptAndOneNeverHandedInIsFreedUnlessPending) {
  // Handed in, not taken by the loop yet: kept.
  arrive(1.0);
  keeper_.release(hl_.knnInUse(), nullptr);
  EXPECT_EQ(keeper_.size(), 1u);
  EXPECT_FALSE(watched_[0].second.expired());
  // Built but waiting for room in the ring: kept while pending, freed once replaced.
  std::shared_ptr<const KnnTorqueModel> m = knnOf(1.1);
  const std::weak_ptr<const KnnTorqueModel> w = m;
  const KnnTorqueModel* pending = keeper_.keep(std::move(m));
  keeper_.release(hl_.knnInUse(), pending);
  EXPECT_FALSE(w.expired());
  keeper_.release(hl_.knnInUse(), nullptr);
  EXPECT_TRUE(w.expired());
  EXPECT_FALSE(watched_[0].second.expired()) << "still in the ring";
}

}  // namespace
}  // namespace telehand::client::link
