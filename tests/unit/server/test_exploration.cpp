// Assessment by exploration: the extremes reached per direction, the force there, and the
// comparison of a reassessment with its baseline.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <vector>

#include "telehand/core/joint_model.h"
#include "telehand/server/session/exploration.h"

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

TEST(Exploration, RecordsTheExtremeOfEachDirectionAndTheForceThere) {
  Exploration e;
  EXPECT_FALSE(e.active());
  e.begin("baseline");
  EXPECT_TRUE(e.active());
  EXPECT_EQ(e.phase(), "baseline");
  e.observe(deg(0, 0, 0), 0.5);
  e.observe(deg(60, 2, -1), 11.0);  // flexion peak
  e.observe(deg(30, 0, 0), 4.0);
  e.observe(deg(-30, -1, 1), 6.0);         // extension peak
  e.observe(deg(5, 15, 0), 2.5);           // abduction peak
  e.observe(deg(5, -12, 0), 2.0);          // adduction peak
  e.observe(deg(5, 0, 12), 7.0);           // supination peak
  e.observe(deg(5, 0, -8), 5.0);           // pronation peak
  e.observe(deg(59.9, 14.9, 11.9), 99.0);  // close to, not past, three peaks: changes nothing
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

TEST(Exploration, OneSampleIsEveryExtreme) {
  Exploration e;
  e.begin("baseline");
  e.observe(deg(10, 3, -2), 1.5);
  const auto r = e.finish();
  ASSERT_EQ(r.size(), 6u);
  EXPECT_NEAR(find(r, "flexion").angle_deg, 10, 1e-9);
  EXPECT_NEAR(find(r, "extension").angle_deg, 10, 1e-9);
  EXPECT_NEAR(find(r, "abduction").angle_deg, 3, 1e-9);
  EXPECT_NEAR(find(r, "adduction").angle_deg, 3, 1e-9);
  EXPECT_NEAR(find(r, "supination").angle_deg, -2, 1e-9);
  EXPECT_NEAR(find(r, "pronation").angle_deg, -2, 1e-9);
  for (const auto& x : r) EXPECT_EQ(x.force_n, 1.5);
}

TEST(Exploration, NothingObservedOrNotBegunGivesNoReaches) {
  Exploration e;
  e.observe(deg(50, 0, 0), 3.0);  // before begin: ignored
  EXPECT_TRUE(e.finish().empty());
  e.begin("baseline");
  EXPECT_TRUE(e.finish().empty());
  // After finish nothing counts until the next begin.
  e.observe(deg(50, 0, 0), 3.0);
  EXPECT_TRUE(e.finish().empty());
}

TEST(Exploration, EachPhaseStartsAfresh) {
  Exploration e;
  e.begin("baseline");
  e.observe(deg(60, 10, 5), 10.0);
  e.observe(deg(-30, -10, -5), 5.0);
  const auto baseline = e.finish();
  ASSERT_EQ(baseline.size(), 6u);
  e.begin("reassessment");
  EXPECT_EQ(e.phase(), "reassessment");
  e.observe(deg(40, 1, 0), 8.0);  // nowhere near the baseline's extremes
  const auto re = e.finish();
  ASSERT_EQ(re.size(), 6u);
  EXPECT_EQ(re[0].phase, "reassessment");
  EXPECT_NEAR(find(re, "flexion").angle_deg, 40, 1e-9);
  EXPECT_NEAR(find(re, "extension").angle_deg, 40, 1e-9);
  EXPECT_EQ(find(re, "flexion").force_n, 8.0);
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
  EXPECT_EQ(s, "flexion 60.0 deg, extension -30.0 deg");
  EXPECT_THAT(s, Not(HasSubstr("baseline")));
  EXPECT_EQ(Exploration::summary({}, now), "");
  // A baseline missing a direction: only the directions it has get a delta.
  const std::vector<SessionStore::Reach> partial = {{"baseline", "extension", -20.0, 1.0}};
  EXPECT_EQ(Exploration::summary(now, partial),
            "flexion 60.0 deg, extension -30.0 deg (-10.0 vs baseline)");
}

}  // namespace
}  // namespace telehand::server::session
