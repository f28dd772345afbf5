// telehand-records report's learning curve, read from a record: a student's earlier lesson runs
// (of any lesson) in the order they ran, each its trials' mean overall score; not this run, not
// another student's, not a session that ran no lesson, not a run without scored trials.
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <initializer_list>
#include <memory>
#include <string>

#include "lesson_history.h"
#include "telehand/server/store/sqlite_store.h"

namespace telehand::records {
namespace {

namespace fs = std::filesystem;
using namespace server::store;

class LessonHistoryTest : public ::testing::Test {
 protected:
  void SetUp() override {
    static std::atomic<int> counter{0};
    dir_ = fs::temp_directory_path() /
           ("telehand-history-" + std::to_string(::getpid()) + "-" + std::to_string(counter++));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    store_ = std::make_unique<SqliteStore>((dir_ / "records.db").string());
  }
  void TearDown() override {
    store_.reset();
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }

  uint64_t lesson(const std::string& name) {
    LessonInfo l;
    l.name = name;
    l.demo_session = 1;
    l.case_name = "healthy";
    l.targets = "band_min_n=12;";
    return store_->createLesson(l);
  }
  uint64_t session(const std::string& user, const std::string& mode) {
    SessionInfo s;
    s.user = user;
    s.case_name = "healthy";
    s.mode = mode;
    s.state = "active";
    s.started_ns = 1'700'000'000'000'000'000;
    return store_->createSession(s);
  }
  /// A run of `lesson` by `user` whose trials score `overall`, in that order.
  uint64_t run(uint64_t lesson_id, const std::string& user, std::initializer_list<double> overall) {
    const uint64_t id = session(user, "lesson");
    store_->setSessionLesson(id, lesson_id);
    int index = 0;
    for (const double o : overall) {
      TrialRecord t;
      t.session_id = id;
      t.index = ++index;
      t.phase = "attempt";
      t.first_seq = static_cast<uint64_t>(index) * 4000;
      t.last_seq = t.first_seq + 3999;
      t.overall = o;
      t.figures = "missing=0;";
      store_->appendTrial(t);
    }
    store_->closeSession(id, 1'700'000'010'000'000'000, 0, "closed");
    return id;
  }

  fs::path dir_;
  std::unique_ptr<SqliteStore> store_;
};

TEST_F(LessonHistoryTest, TheLearningCurveHoldsTheStudentsEarlierRunsInOrder) {
  const uint64_t a = lesson("wrist, gentle"), b = lesson("wrist, firmer");
  const uint64_t first = run(a, "student", {40.0, 50.0});
  session("student", "mobilization");  // no lesson: not in the curve
  run(a, "other", {90.0});             // another student's
  const uint64_t unscored = run(a, "student", {});
  const uint64_t second = run(b, "student", {60.0, 70.0, 80.0});  // another lesson: in it
  const uint64_t third = run(a, "student", {75.0});
  const uint64_t later = run(b, "student", {95.0});

  const auto curve = learningHistory(*store_, "student", third);
  ASSERT_EQ(curve.size(), 2u) << "the first and second runs; not this one, nor the unscored run "
                              << unscored;
  EXPECT_EQ(curve[0].first, "session " + std::to_string(first));
  EXPECT_DOUBLE_EQ(curve[0].second, 45.0);
  EXPECT_EQ(curve[1].first, "session " + std::to_string(second));
  EXPECT_DOUBLE_EQ(curve[1].second, 70.0);

  // The latest run's curve holds every earlier one, oldest first.
  const auto all = learningHistory(*store_, "student", later);
  ASSERT_EQ(all.size(), 3u);
  EXPECT_EQ(all[0].first, "session " + std::to_string(first));
  EXPECT_EQ(all[1].first, "session " + std::to_string(second));
  EXPECT_EQ(all[2].first, "session " + std::to_string(third));
  EXPECT_DOUBLE_EQ(all[2].second, 75.0);
  // A student's first run has nothing before it.
  EXPECT_TRUE(learningHistory(*store_, "student", first).empty());
  EXPECT_EQ(learningHistory(*store_, "other", later).size(), 1u);

  // A lesson's runs, oldest first, whoever ran them.
  const auto runs_a = runsOf(*store_, a);
  ASSERT_EQ(runs_a.size(), 4u);
  EXPECT_EQ(runs_a.front().id, first);
  EXPECT_EQ(runs_a.back().id, third);
  EXPECT_EQ(runsOf(*store_, b).size(), 2u);
}

}  // namespace
}  // namespace telehand::records
