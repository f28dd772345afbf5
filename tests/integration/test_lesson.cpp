// A whole lesson as real processes over loopback DDS (docs/lessons.md): a clinician's client
// demonstrates, telehand-records makes the lesson, a student's client runs it (baseline,
// watch, guided trial, attempts, reassessment) while a supervisor replays the demonstration;
// then the record is checked end to end and the report written. Stopped by PID, reaped.
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <algorithm>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <memory>
#include <regex>
#include <sstream>
#include <vector>

#include "process.h"
#include "process_test.h"
#include "telehand/server/store/sqlite_store.h"

namespace telehand::test {
namespace {

using namespace std::chrono_literals;
using server::store::SqliteStore;

/// Runs `sql` on the SQLite file `db` (bound to `args` in order); the rows it changed.
int64_t sqlite(const std::string& db, const std::string& sql, std::vector<int64_t> args = {},
               int flags = SQLITE_OPEN_READWRITE) {
  sqlite3* c = nullptr;
  int64_t changed = -1;
  if (sqlite3_open_v2(db.c_str(), &c, flags, nullptr) == SQLITE_OK) {
    sqlite3_stmt* st = nullptr;
    if (sqlite3_prepare_v2(c, sql.c_str(), -1, &st, nullptr) == SQLITE_OK) {
      for (std::size_t i = 0; i < args.size(); ++i) {
        sqlite3_bind_int64(st, static_cast<int>(i + 1), args[i]);
      }
      if (sqlite3_step(st) == SQLITE_DONE) changed = sqlite3_changes(c);
    }
    sqlite3_finalize(st);
  }
  EXPECT_GE(changed, 0) << sql << ": " << sqlite3_errmsg(c);
  sqlite3_close(c);
  return changed;
}

std::string readFile(const std::string& path) {
  std::ifstream f(path);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

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
  // The only run in the record: nothing earlier in the student's learning curve.
  EXPECT_NE(report.output().find("0 runs in the learning curve"), std::string::npos)
      << report.output();
  EXPECT_NE(report.output().find("(3 trials, "), std::string::npos) << report.output();
  EXPECT_EQ(report.output().find("missing"), std::string::npos) << report.output();
  EXPECT_EQ(report.output().find("warning"), std::string::npos) << report.output();

  // The report of a copy of the record that lacks trial 2's samples and 1000 of trial 3's:
  // trial 2 keeps its row, not in the record and not scored; trial 3 is scored on the rest
  // saying how many it lacks; a warning names both; exit 3, the record not complete.
  {
    const std::string copy = path("damaged.db");
    sqlite(db, "VACUUM INTO '" + copy + "'", {}, SQLITE_OPEN_READONLY);
    const auto& gone = trials[1];
    const auto& gaps = trials[2];
    const int64_t r = static_cast<int64_t>(run);
    EXPECT_EQ(
        sqlite(copy, "DELETE FROM samples WHERE session_id = ? AND seq BETWEEN ? AND ?",
               {r, static_cast<int64_t>(gone.first_seq), static_cast<int64_t>(gone.last_seq)}),
        static_cast<int64_t>(gone.last_seq - gone.first_seq + 1));
    const auto gap_from = static_cast<int64_t>(gaps.first_seq + 1000);
    EXPECT_EQ(sqlite(copy, "DELETE FROM samples WHERE session_id = ? AND seq BETWEEN ? AND ?",
                     {r, gap_from, gap_from + 999}),
              1000);
    const std::string gone_note = "not in the record (0 of " +
                                  std::to_string(gone.last_seq - gone.first_seq + 1) + " samples)";
    const std::string gaps_note =
        "1000 of " + std::to_string(gaps.last_seq - gaps.first_seq + 1) + " samples missing";
    Process damaged({TELEHAND_RECORDS_BIN, "--db", copy, "report", std::to_string(run), "-o",
                     path("report-damaged")},
                    path("report-damaged.log"));
    EXPECT_EQ(damaged.wait(30s), 3) << damaged.output();
    const std::string said = damaged.output();
    for (const std::string& want :
         {std::string("(3 trials, 1 not scored, "), "  trial 2 (attempt): " + gone_note + "\n",
          "  trial 3 (attempt): " + gaps_note + "\n",
          "warning: the record of session " + std::to_string(run) +
              " lacks samples of trials 2, 3 (trial 2: " + gone_note +
              ", not scored; trial 3: " + gaps_note + ", scored on the rest)"}) {
      EXPECT_NE(said.find(want), std::string::npos) << want << "\n" << said;
    }
    const std::string damaged_base = path("report-damaged") + "/lesson-" + std::to_string(lesson) +
                                     "-session-" + std::to_string(run);
    const std::string page_text = readFile(damaged_base + ".html");
    EXPECT_NE(page_text.find("<td>" + gone_note + "</td><td colspan=\"9\">not scored</td>"),
              std::string::npos);
    EXPECT_NE(page_text.find("<td>" + gaps_note + "</td>"), std::string::npos);
    EXPECT_NE(page_text.find("id=\"force-2\""), std::string::npos);
    EXPECT_EQ(page_text.find("id=\"force-1\""), std::string::npos);
    // The scores CSV: three rows, trial 2's with no score (not 0) and its note, trial 3's
    // with a score and its missing count.
    std::istringstream scores(readFile(damaged_base + "-scores.csv"));
    std::vector<std::string> lines;
    for (std::string l; std::getline(scores, l);) lines.push_back(l);
    ASSERT_EQ(lines.size(), 4u) << "a header and three trials";
    EXPECT_NE(lines[0].find(",overall,samples_expected,samples_missing,note"), std::string::npos)
        << lines[0];
    EXPECT_NE(lines[2].find(",,," + std::to_string(gone.last_seq - gone.first_seq + 1) + "," +
                            std::to_string(gone.last_seq - gone.first_seq + 1) + "," + gone_note),
              std::string::npos)
        << lines[2];
    EXPECT_TRUE(
        std::regex_search(lines[3], std::regex(",\\d+\\.\\d\\d,\\d+,1000," + gaps_note + "$")))
        << lines[3];
  }

  // The lesson as the record lists and shows it: its id, demonstration, plan, targets (those
  // `lesson create` derived) and its run.
  Process list({TELEHAND_RECORDS_BIN, "--db", db, "lesson", "list"}, path("list.log"));
  ASSERT_EQ(list.wait(30s), 0) << list.output();
  const std::string listed = list.output();
  EXPECT_NE(listed.find("schedule"), std::string::npos) << listed;
  std::smatch row;
  ASSERT_TRUE(
      std::regex_search(listed, row,
                        std::regex(R"((?:^|\n)(\d+) +(\d+) +(\S+) +terminal +1\+2 +1 +)"
                                   R"(mobilization +mobilization by clinician on (\S+)\n)")))
      << listed;
  EXPECT_EQ(std::stoull(row[1]), lesson);
  EXPECT_EQ(std::stoull(row[2]), demo);
  EXPECT_EQ(row[3], row[4]) << "the case, in its column and in the name";
  const std::string case_name = row[3];

  Process show({TELEHAND_RECORDS_BIN, "--db", db, "lesson", "show", std::to_string(lesson)},
               path("show.log"));
  ASSERT_EQ(show.wait(30s), 0) << show.output();
  const std::string shown = show.output();
  for (const std::string& want :
       {"lesson " + std::to_string(lesson) + ": mobilization by clinician on " + case_name + "\n",
        "  demonstration: session " + std::to_string(demo) + " on case " + case_name +
            " (mobilization)\n",
        std::string("  plan: 1 guided trial(s), 2 attempt(s) of 4.00 s, terminal feedback, "
                    "exploration before and after\n"),
        "  run: session " + std::to_string(run) + " by student, closed, 3 trials scored"}) {
    EXPECT_NE(shown.find(want), std::string::npos) << want << "\n" << shown;
  }
  // The targets: the band and frequency `lesson create` printed.
  const std::regex targets(R"(force (\d+\.\d\d)-(\d+\.\d\d) N.*?, (\d+\.\d\d) Hz, amplitude )"
                           R"((\d+\.\d\d) deg)");
  std::smatch made, held;
  const std::string created = create.output();
  ASSERT_TRUE(std::regex_search(created, made, targets)) << created;
  ASSERT_TRUE(std::regex_search(shown, held, targets)) << shown;
  for (int i = 1; i <= 4; ++i) EXPECT_EQ(made[i], held[i]) << i << "\n" << created << shown;
  EXPECT_NE(shown.find("  targets: force " + made[1].str() + "-" + made[2].str() + " N (peak "),
            std::string::npos)
      << shown;
  // The run's mean overall score: the record's trials'.
  double mean = 0.0;
  for (const auto& t : trials) mean += t.overall / static_cast<double>(trials.size());
  std::smatch m;
  ASSERT_TRUE(std::regex_search(shown, m, std::regex(R"(mean overall (\d+)\n)"))) << shown;
  EXPECT_NEAR(std::stod(m[1]), mean, 0.51) << shown;

  // A report refused: exit 2, saying why.
  const auto refused = [&](uint64_t session, const std::string& into, const std::string& log,
                           const std::string& why) {
    Process p({TELEHAND_RECORDS_BIN, "--db", db, "report", std::to_string(session), "-o", into},
              path(log));
    const auto code = p.wait(30s);
    ASSERT_TRUE(code.has_value());
    EXPECT_EQ(*code, 2) << p.output();
    EXPECT_NE(p.output().find(why), std::string::npos) << p.output();
  };
  // Of a session that ran no lesson.
  refused(demo, path("report"), "not-a-run.log",
          "session " + std::to_string(demo) + " is not a lesson run (mode mobilization)");
  EXPECT_FALSE(std::filesystem::exists(path("report") + "/lesson-" + std::to_string(lesson) +
                                       "-session-" + std::to_string(demo) + ".html"));
  // Into something that is not a directory: saying where (not aborted), the file kept.
  { std::ofstream(path("a-file")) << "kept\n"; }
  refused(run, path("a-file"), "into-file.log",
          "cannot write the report into '" + path("a-file") + "'");
  std::ifstream kept(path("a-file"));
  std::string kept_line;
  EXPECT_TRUE(std::getline(kept, kept_line) && kept_line == "kept");
}

/// One concurrent-feedback bar the student's client printed during a trial.
struct Bar {
  std::string bar;
  double trough_n = 0.0, peak_n = 0.0, frequency_hz = 0.0, error_hz = 0.0;
};

std::vector<Bar> barsIn(const std::string& out) {
  static const std::regex line(
      R"(\n  force ([-\[\]|.]+) +(\d+\.\d)- *(\d+\.\d) N   frequency (\d+\.\d\d) Hz \(([+-]\d+\.\d\d)\)(?=\n))");
  std::vector<Bar> bars;
  for (std::sregex_iterator it(out.begin(), out.end(), line), end; it != end; ++it) {
    const std::smatch& m = *it;
    bars.push_back({m[1], std::stod(m[2]), std::stod(m[3]), std::stod(m[4]), std::stod(m[5])});
  }
  return bars;
}

// The other feedback schedules on the student's side: concurrent (the aim and a bar of the
// last oscillation against the band once a second during every trial, the scores only after
// the last) and self-requested (the scores after the trials the student asked for only).
TEST_F(LessonRunTest, ConcurrentBarsDuringTrialsAndSelfRequestedFeedbackAfterAskedTrials) {
  const std::string db = path("records.db");
  Process server(cmd(TELEHAND_SERVER_BIN, {"--db", db, "--seconds", "120"}), path("server.log"));
  Process clinician(
      cmd(TELEHAND_CLIENT_BIN, {"--seconds", "5", "-q", "--user", "clinician", "--no-fault-stop"}),
      path("clinician.log"));
  ASSERT_EQ(clinician.wait(40s), 0) << clinician.output();
  const uint64_t demo = matchNumber(clinician.output(), R"(session (\d+) open)");
  ASSERT_GT(demo, 0u);
  // Trials of 4 s as above: a trial is scored from 2 s of record, which a loop slowed by a busy
  // machine takes longer to send.
  auto create = [&](const std::string& schedule) {
    Process p({TELEHAND_RECORDS_BIN, "--db", db, "lesson", "create", "--demo", std::to_string(demo),
               "--guided", "0", "--attempts", "2", "--trial-seconds", "4", "--schedule", schedule,
               "--no-assessment"},
              path("create-" + schedule + ".log"));
    EXPECT_EQ(p.wait(30s), 0) << p.output();
    return p.output();
  };
  const std::string concurrent = create("concurrent");
  const std::string self = create("self");
  const uint64_t concurrent_id = matchNumber(concurrent, R"(lesson (\d+) )");
  const uint64_t self_id = matchNumber(self, R"(lesson (\d+) )");
  ASSERT_GT(concurrent_id, 0u) << concurrent;
  ASSERT_GT(self_id, 0u) << self;
  std::smatch band;
  ASSERT_TRUE(std::regex_search(concurrent, band,
                                std::regex(R"(force (\d+\.\d\d)-(\d+\.\d\d) N, (\d+\.\d\d) Hz)")))
      << concurrent;
  const double band_min = std::stod(band[1]), band_max = std::stod(band[2]),
               target_hz = std::stod(band[3]);
  // A student 2 N too hard and 0.5 Hz too fast (--no-fault-stop: see the test above).
  auto student = [&](uint64_t lesson, std::vector<std::string> extra, const std::string& log) {
    std::vector<std::string> args{"--lesson",
                                  std::to_string(lesson),
                                  "--user",
                                  "student",
                                  "--watch-speed",
                                  "2",
                                  "--force-bias",
                                  "2",
                                  "--frequency-error",
                                  "0.5",
                                  "--no-fault-stop"};
    args.insert(args.end(), extra.begin(), extra.end());
    return std::make_unique<Process>(cmd(TELEHAND_CLIENT_BIN, args), path(log));
  };
  auto finish = [](Process& p) {
    const auto rc = p.wait(60s);
    EXPECT_TRUE(rc.has_value()) << "the run did not finish\n" << p.output();
    EXPECT_EQ(rc.value_or(-1), 0) << p.output();
    return p.output();
  };
  // Both runs at the same time, each a session of its own on the one server.
  const auto c_run = student(concurrent_id, {}, "student-concurrent.log");
  const auto s_run = student(self_id, {"--request-feedback", "2"}, "student-self.log");
  const std::string c_out = finish(*c_run);
  const std::string s_out = finish(*s_run);

  // Concurrent: the aim at each trial's start, the demonstration's band and frequency.
  const std::regex aim(R"(aim: (\d+\.\d)-(\d+\.\d) N at (\d+\.\d\d) Hz \(the demonstration's\))");
  std::size_t aims = 0;
  for (std::sregex_iterator it(c_out.begin(), c_out.end(), aim), end; it != end; ++it, ++aims) {
    // The same figures, to the digits each prints.
    EXPECT_NEAR(std::stod((*it)[1]), band_min, 0.051) << it->str();
    EXPECT_NEAR(std::stod((*it)[2]), band_max, 0.051) << it->str();
    EXPECT_NEAR(std::stod((*it)[3]), target_hz, 0.011) << it->str();
  }
  EXPECT_EQ(aims, 2u) << c_out;
  // Bars during both trials (once a second from the first oscillation on).
  const std::size_t trial2 = c_out.find("trial 2: attempt 2 of 2");
  ASSERT_NE(trial2, std::string::npos) << c_out;
  const auto bars = barsIn(c_out);
  const auto bars_late = barsIn(c_out.substr(trial2));
  EXPECT_GE(bars.size() - bars_late.size(), 1u) << "bars during trial 1\n" << c_out;
  EXPECT_GE(bars_late.size(), 1u) << "bars during trial 2\n" << c_out;
  // Each bar: 30 columns from 0 to 1.5x the band's top; the last peak '|' where it belongs,
  // the frequency error against the target, the band's bottom '[' unless a mark covers it.
  // The band printed at lesson creation is rounded to 0.01 N and the client draws the exact
  // one, so a column is only known to within one either side.
  const double full = 1.5 * band_max;
  auto col = [&](double n) { return std::clamp(static_cast<int>(n / full * 30), 0, 29); };
  for (const Bar& b : bars) {
    ASSERT_EQ(b.bar.size(), 30u) << b.bar;
    const auto peak = static_cast<int>(b.bar.find('|'));
    EXPECT_NEAR(peak, col(b.peak_n), 1) << b.bar << " peak " << b.peak_n;
    EXPECT_LE(b.trough_n, b.peak_n) << b.bar;
    EXPECT_NEAR(b.frequency_hz - target_hz, b.error_hz, 0.011) << b.bar;
    const auto open = b.bar.find('[');
    if (open != std::string::npos) {
      EXPECT_NEAR(static_cast<int>(open), col(band_min), 1) << b.bar << " band " << band_min;
    } else {
      const bool covered = std::abs(col(b.peak_n) - col(band_min)) <= 1 ||
                           std::abs(col(b.trough_n) - col(band_min)) <= 1;
      EXPECT_TRUE(covered) << "no '[' and no mark near the band's bottom: " << b.bar;
    }
  }
  // The scores: after the last trial only.
  EXPECT_EQ(c_out.find("feedback: trial 1 ("), std::string::npos) << c_out;
  EXPECT_NE(c_out.find("feedback: trial 2 (attempt)"), std::string::npos) << c_out;
  EXPECT_NE(c_out.find("2 of 2 trials run"), std::string::npos) << c_out;

  // Self-requested: the student asks after trial 2 only.
  EXPECT_TRUE(barsIn(s_out).empty()) << s_out;
  EXPECT_EQ(s_out.find("aim: "), std::string::npos) << s_out;
  EXPECT_EQ(s_out.find("feedback: trial 1 ("), std::string::npos) << s_out;
  EXPECT_NE(s_out.find("feedback: trial 2 (attempt)"), std::string::npos) << s_out;
  EXPECT_NE(s_out.find("2 of 2 trials run"), std::string::npos) << s_out;
  EXPECT_EQ(server.stop(), 0) << server.output();

  // Both runs scored both trials in the record, whatever the client showed.
  SqliteStore store(db, SqliteStore::Mode::kReadOnly);
  for (const std::string& out : {c_out, s_out}) {
    const uint64_t run = matchNumber(out, R"(session (\d+) open: lesson)");
    ASSERT_GT(run, 0u) << out;
    EXPECT_EQ(store.trials(run).size(), 2u) << out;
  }
}

}  // namespace
}  // namespace telehand::test
