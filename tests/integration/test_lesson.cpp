// A whole lesson as real processes over loopback DDS (docs/lessons.md): a clinician's client
// demonstrates, telehand-records makes the lesson, a student's client runs it (baseline,
// watch, guided trial, attempts, reassessment) while a supervisor replays the demonstration;
// then the record is checked end to end and the report written. Stopped by PID, reaped.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "process.h"
#include "process_test.h"
#include "telehand/server/store/sqlite_store.h"

namespace telehand::test {
namespace {

using namespace std::chrono_literals;
using server::store::SqliteStore;

class LessonRunTest : public ProcessTest {
 protected:
  LessonRunTest() : ProcessTest("lesson", TELEHAND_LOOPBACK_XML) {}
};

TEST_F(LessonRunTest, ClinicianDemonstratesStudentRunsItAndTheRecordHoldsTheLesson) {
  const std::string db = path("records.db");
  Process server(cmd(TELEHAND_SERVER_BIN, {"--db", db, "--seconds", "170"}), path("server.log"));
  Process clinician(cmd(TELEHAND_CLIENT_BIN, {"--seconds", "6", "-q", "--user", "clinician"}),
                    path("clinician.log"));
  ASSERT_EQ(clinician.wait(40s), 0) << clinician.output();
  const uint64_t demo = matchNumber(clinician.output(), R"(session (\d+) open)");
  ASSERT_GT(demo, 0u);

  Process create(
      {TELEHAND_RECORDS_BIN, "--db", db, "lesson", "create", "--demo", std::to_string(demo),
       "--guided", "1", "--attempts", "2", "--trial-seconds", "4", "--schedule", "terminal"},
      path("create.log"));
  ASSERT_EQ(create.wait(30s), 0) << create.output();
  const uint64_t lesson = matchNumber(create.output(), R"(lesson (\d+) )");
  ASSERT_GT(lesson, 0u) << create.output();
  EXPECT_NE(create.output().find(" Hz,"), std::string::npos) << create.output();

  // --no-fault-stop: a machine busy enough to stall the loop for 100 ms lets the simulated
  // MF-2 integrate that long on one stale force and fling the phalanx (a fault, rightly);
  // what this test checks is the lesson's record, the fault detector has tests of its own.
  Process student(cmd(TELEHAND_CLIENT_BIN,
                      {"--lesson", std::to_string(lesson), "--user", "student", "--explore-seconds",
                       "6", "--force-bias", "2", "--frequency-error", "0.5", "--no-fault-stop"}),
                  path("student.log"));
  // A supervisor replays the demonstration meanwhile: a session of its own that ends with
  // the record.
  Process replay(cmd(TELEHAND_WATCH_BIN,
                     {"--replay", std::to_string(demo), "--speed", "2", "--plain", "--wait", "20"}),
                 path("replay.log"));
  const auto rc = student.wait(120s);
  ASSERT_TRUE(rc.has_value()) << "the student's run did not finish\n" << student.output();
  EXPECT_EQ(*rc, 0) << student.output() << "\n" << server.output();
  const auto replay_rc = replay.wait(30s);
  ASSERT_TRUE(replay_rc.has_value()) << replay.output();
  EXPECT_EQ(*replay_rc, 0) << replay.output();
  EXPECT_EQ(server.stop(), 0) << server.output();

  const std::string out = student.output();
  const uint64_t run = matchNumber(out, R"(session (\d+) open: lesson)");
  const uint64_t sent = matchNumber(out, R"((\d+) samples sent)");
  ASSERT_GT(run, 0u) << out;
  for (const char* phase : {"exploration baseline", "watch the demonstration", "trial 1: guided",
                            "trial 3: attempt 2 of 2", "reassessment"}) {
    EXPECT_NE(out.find(phase), std::string::npos) << phase << "\n" << out;
  }
  EXPECT_NE(out.find("feedback: trial 1 (guided 100 %)"), std::string::npos) << out;
  EXPECT_NE(out.find("3 of 3 trials run"), std::string::npos) << out;
  const uint64_t replayed = matchNumber(replay.output(), R"(as session (\d+))");
  EXPECT_GT(replayed, 0u) << replay.output();
  EXPECT_GT(matchNumber(replay.output(), R"(hand_states=(\d+))"), 50u) << replay.output();

  // The record: every sample, three scored trials in order, the phases, the ranges.
  SqliteStore store(db, SqliteStore::Mode::kReadOnly);
  const auto info = store.session(run);
  ASSERT_TRUE(info.has_value());
  EXPECT_EQ(info->state, "closed");
  EXPECT_EQ(info->mode, "lesson");
  EXPECT_EQ(info->samples, sent);
  EXPECT_EQ(store.sessionLesson(run), lesson);
  const auto trials = store.trials(run);
  ASSERT_EQ(trials.size(), 3u);
  EXPECT_EQ(trials[0].phase, "guided");
  EXPECT_DOUBLE_EQ(trials[0].authority, 1.0);
  EXPECT_EQ(trials[1].phase, "attempt");
  EXPECT_EQ(trials[2].phase, "attempt");
  for (std::size_t i = 0; i < trials.size(); ++i) {
    EXPECT_GT(trials[i].last_seq, trials[i].first_seq + 3000) << i;  // about 4 s each
    if (i > 0) {
      EXPECT_EQ(trials[i].first_seq, trials[i - 1].last_seq + 1) << i;
    }
    EXPECT_NE(trials[i].figures.find("missing=0;"), std::string::npos) << trials[i].figures;
  }
  std::string events;
  for (const auto& e : store.events(run)) events += e.kind + ": " + e.text + "\n";
  for (const char* want : {"phase: watch", "watch: the demonstration ended", "trial 2 (attempt):",
                           "oscillation", "reassessment:", "3 trials scored"}) {
    EXPECT_NE(events.find(want), std::string::npos) << want << "\n" << events;
  }
  bool baseline = false, after = false;
  for (const auto& r : store.reaches(run)) {
    baseline = baseline || r.phase == "baseline";
    after = after || r.phase == "reassessment";
  }
  EXPECT_TRUE(baseline && after) << "the range before and after the treatment";
  // The replay session is recorded as one, closed, with nothing of its own.
  const auto rs = store.session(replayed);
  ASSERT_TRUE(rs.has_value());
  EXPECT_EQ(rs->mode, "replay");
  EXPECT_EQ(rs->state, "closed");

  // The report.
  Process report(
      {TELEHAND_RECORDS_BIN, "--db", db, "report", std::to_string(run), "-o", path("report")},
      path("report.log"));
  ASSERT_EQ(report.wait(30s), 0) << report.output();
  const std::string base =
      path("report") + "/lesson-" + std::to_string(lesson) + "-session-" + std::to_string(run);
  std::ifstream html(base + ".html");
  std::stringstream page;
  page << html.rdbuf();
  EXPECT_NE(page.str().find("<svg"), std::string::npos);
  std::ifstream csv(base + "-scores.csv");
  std::string line;
  int rows = 0;
  while (std::getline(csv, line)) ++rows;
  EXPECT_EQ(rows, 4) << "a header and three trials";
}

}  // namespace
}  // namespace telehand::test
