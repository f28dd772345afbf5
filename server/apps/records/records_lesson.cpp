#include "records_lesson.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <map>
#include <optional>
#include <sstream>

#include "file_output.h"
#include "lesson_history.h"
#include "report.h"
#include "telehand/config/config.h"
#include "telehand/core/clock.h"
#include "telehand/core/error.h"
#include "telehand/protocol/lesson_plan.h"
#include "telehand/server/lesson/lesson.h"
#include "telehand/server/store/open_store.h"

namespace telehand::records {

using namespace server::store;

namespace {

/// The case's file in the cases directory, when there is one: a file that is there but
/// cannot be read is an error (naming the file and key), not a fall-back to built-in values
/// the server, which refuses such a file, never renders.
std::optional<PatientCase> caseFileOf(const std::string& cases_dir, const std::string& case_name) {
  if (!std::filesystem::exists(std::filesystem::path(cases_dir) / (case_name + ".toml"))) {
    return std::nullopt;
  }
  return loadPatientCaseByName(cases_dir, case_name);
}

/// The force scale of a case (the demonstration's rendering), from the cases directory; the
/// healthy joint's when the case is not there.
double forceScaleOf(const std::string& cases_dir, const std::string& case_name) {
  const auto c = caseFileOf(cases_dir, case_name);
  return c ? c->model.force_scale : healthyIndexMcp().force_scale;
}

/// The web of a case: its file's [tissue] when the cases directory has one, else the built-in
/// web of that name (as the server renders it, docs/massage.md "Cases").
TissueParams webOf(const std::string& cases_dir, const std::string& case_name) {
  const auto c = caseFileOf(cases_dir, case_name);
  if (c && c->tissue_given) return c->tissue;
  return tissueCase(case_name.c_str());
}

/// Refuses, before it is stored, a lesson whose run the server or the client would refuse
/// (its plan as the session's status carries it) or whose trials are too short to judge: a
/// trial is scored after `settle_s` and over at least one of the demonstration's periods.
void checkLesson(const LessonInfo& l, const LessonPlan& plan, double settle_s) {
  std::string why;
  LessonPlan stored = plan;
  if (stored.lesson_id == 0) stored.lesson_id = 1;  // the id the record gives it, not yet known
  if (!decodePlan(encodePlan(stored), &why)) {
    throw Error("the demonstration gives a lesson that cannot be run: " + why);
  }
  const double need_s = settle_s + 1.0 / plan.frequency_hz;
  if (l.trial_s < need_s) {
    char text[200];
    std::snprintf(text, sizeof text,
                  "--trial-seconds %.1f: a trial is judged after %.1f s of settling and over at "
                  "least one of the demonstration's periods (%.1f s at %.2f Hz): give %.1f s or "
                  "more",
                  l.trial_s, settle_s, 1.0 / plan.frequency_hz, plan.frequency_hz,
                  std::ceil(need_s * 10.0) / 10.0);
    throw Error(text);
  }
}

int createMassageLesson(SessionStore& store, const LessonRequest& r, const SessionInfo& demo) {
  if (r.takeover) {
    throw Error("--takeover: session " + std::to_string(r.demo) +
                " is a massage, and a take-over follows a supervisor's mobilization; a massage "
                "lesson's guided trials follow its demonstration");
  }
  const double scale = forceScaleOf(r.cases_dir, demo.case_name);
  const TissueParams web = webOf(r.cases_dir, demo.case_name);
  const technique::MassageTargets t =
      server::lesson::massageTargetsFromRecord(store, r.demo, scale, web);
  LessonInfo l;
  l.name = r.name.empty() ? "massage by " + demo.user + " on " + demo.case_name : r.name;
  l.demo_session = r.demo;
  l.case_name = demo.case_name;
  l.technique = "massage";
  l.schedule = r.schedule;
  l.guided = r.guided;
  l.attempts = r.attempts;
  l.trial_s = r.trial_s;
  l.assessment = false;
  l.takeover = false;
  l.targets = server::lesson::encodeMassageTargets(t);
  checkLesson(l, server::lesson::planOf(l, server::lesson::decodeMassageTargets(l.targets), 0.0),
              server::lesson::kMassageSettleS);
  l.created_ns = wallNs();
  const uint64_t id = store.createLesson(l);
  std::cout << std::fixed << std::setprecision(2) << "lesson " << id << " '" << l.name
            << "' from session " << r.demo << " (" << demo.case_name << ", massage): press "
            << t.normal_mean_n << " N (band " << t.band_min_n << "-" << t.band_max_n
            << " N), circles of " << 1000.0 * t.radius_m << " mm at " << t.frequency_hz
            << " Hz, circularity " << t.circularity << ", tangential/normal " << t.tangential_ratio
            << ", " << std::setprecision(0) << t.laps << " laps; " << std::setprecision(2)
            << l.guided << " guided + " << l.attempts << " attempts of " << l.trial_s << " s, "
            << l.schedule << " feedback (no exploration: it measures the joint's range)\n"
            << "run it: telehand-client --technique massage --lesson " << id << "\n";
  return 0;
}

std::vector<Sample> samplesIn(SessionStore& store, uint64_t session, uint64_t first,
                              uint64_t last) {
  std::vector<Sample> out;
  store.forEachSampleIn(session, first, last, [&](const Sample& s, bool valid) {
    if (valid) out.push_back(s);
  });
  return out;
}

std::vector<Sample> allSamples(SessionStore& store, uint64_t session) {
  return samplesIn(store, session, 0, UINT64_MAX);
}

/// A stored trial's samples: the valid ones (what it is scored on), and what the record holds
/// of its stretch of sequence numbers against what that stretch should hold. A trial with
/// under 2 valid samples is not scored, nor one whose samples the scorer finds too short to
/// judge (TrialScore::not_scored, the server's rule).
struct TrialRead {
  std::vector<Sample> valid;
  TrialSamples samples;
};

TrialRead readTrial(SessionStore& store, uint64_t session, const TrialRecord& t) {
  TrialRead out;
  out.samples.expected = t.last_seq >= t.first_seq ? t.last_seq - t.first_seq + 1 : 0;
  store.forEachSampleIn(session, t.first_seq, t.last_seq, [&](const Sample& s, bool valid) {
    ++out.samples.found;
    if (valid) out.valid.push_back(s);
  });
  out.samples.scored = out.valid.size() >= 2;
  return out;
}

/// Trials the record lacks samples of, as the report says them; empty when it has all.
struct Shortfall {
  std::string indices;  ///< "2, 3"
  std::string lines;    ///< "  trial 2 (attempt): not in the record (0 of 4001 samples)\n"...
  std::string details;  ///< "trial 2: not in the record (0 of 4001 samples), not scored; ..."
  std::size_t trials = 0, not_scored = 0;
};

void addShortfall(Shortfall& f, int index, const std::string& label, const TrialSamples& s) {
  if (s.missing() == 0 && s.scored) return;
  const std::string sep = f.trials++ ? ", " : "";
  f.indices += sep + std::to_string(index);
  f.lines += "  " + label + ": " + s.note() + "\n";
  std::string detail = "trial " + std::to_string(index) + ": " + s.note();
  if (s.scored) {
    detail += ", scored on the rest";
  } else if (s.found == 0) {
    detail += ", not scored";  // the note says so otherwise
  }
  f.details += (f.details.empty() ? "" : "; ") + detail;
  if (!s.scored) ++f.not_scored;
}

/// The trial count of the summary line: "3 trials" or "3 trials, 1 not scored".
std::string trialCount(std::size_t trials, const Shortfall& f) {
  std::string text = std::to_string(trials) + " trials";
  if (f.not_scored > 0) text += ", " + std::to_string(f.not_scored) + " not scored";
  return text;
}

/// Once the report is written: 0 when the record holds every trial whole; else a warning
/// naming the trials it lacks samples of, and 3, the record not complete (docs/manual.md,
/// exit codes).
int reportExit(uint64_t session, const Shortfall& f) {
  if (f.trials == 0) return 0;
  std::cerr << "telehand-records: warning: the record of session " << session
            << " lacks samples of trial" << (f.trials > 1 ? "s " : " ") << f.indices << " ("
            << f.details << "); the report says so (exit 3)\n";
  return 3;
}

/// Every stored trial of `session` as a row of the report, scored again from its record by
/// `rescore(valid samples, row)` (which sets the row's series and score) where the record holds
/// enough of it; a trial the record lacks samples of says how many, and one too short to judge
/// says so, not scored 0.
template <class Row, class Rescore>
void trialRows(SessionStore& store, uint64_t session, Shortfall& shortfall, std::vector<Row>& rows,
               const Rescore& rescore) {
  for (const auto& t : store.trials(session)) {
    Row rt;
    rt.label = server::lesson::trialLabel(t.index, t.phase, t.authority);
    TrialRead read = readTrial(store, session, t);
    rt.samples = read.samples;
    if (rt.samples.scored) {
      rescore(read.valid, rt);
      if (!rt.score.not_scored.empty()) {
        rt.samples.scored = false;
        rt.samples.why_not = rt.score.not_scored;
        rt.series = {};
        rt.score = {};
      }
    }
    addShortfall(shortfall, t.index, rt.label, rt.samples);
    rows.push_back(std::move(rt));
  }
}

}  // namespace

int runLessonCreate(const LessonRequest& r) {
  if (!validSchedule(r.schedule)) {
    throw Error("--schedule '" + r.schedule + "': one of concurrent, terminal, faded, self");
  }
  const auto opened = openStore(r.db, SessionStore::Mode::kReadWrite);
  SessionStore& store = *opened;
  const auto demo = store.session(r.demo);
  if (!demo) throw Error("no session " + std::to_string(r.demo) + " in " + store.location());
  if (demo->mode == "massage") return createMassageLesson(store, r, *demo);
  if (demo->mode != "mobilization") {
    throw Error("session " + std::to_string(r.demo) + " is a " + demo->mode +
                " session: a demonstration is a mobilization or a massage");
  }
  const double scale = forceScaleOf(r.cases_dir, demo->case_name);
  const technique::Targets t = server::lesson::targetsFromRecord(store, r.demo, scale);
  LessonInfo l;
  l.name = r.name.empty() ? "mobilization by " + demo->user + " on " + demo->case_name : r.name;
  l.demo_session = r.demo;
  l.case_name = demo->case_name;
  l.schedule = r.schedule;
  l.guided = r.guided;
  l.attempts = r.attempts;
  l.trial_s = r.trial_s;
  l.assessment = r.assessment;
  l.takeover = r.takeover;
  l.targets = server::lesson::encodeTargets(t);
  checkLesson(l, server::lesson::planOf(l, server::lesson::decodeTargets(l.targets), 0.0),
              server::lesson::kSettleS);
  l.created_ns = wallNs();
  const uint64_t id = store.createLesson(l);
  std::cout << std::fixed << std::setprecision(2) << "lesson " << id << " '" << l.name
            << "' from session " << r.demo << " (" << demo->case_name << "): force " << t.band_min_n
            << "-" << t.band_max_n << " N, " << t.frequency_hz << " Hz, amplitude "
            << t.amplitude_deg << " deg, " << t.oscillations << " oscillations; " << l.guided
            << " guided + " << l.attempts << " attempts of " << l.trial_s << " s, " << l.schedule
            << " feedback" << (l.assessment ? ", with assessment" : "")
            << (l.takeover ? ", a supervisor may take over" : "") << "\n"
            << "run it: telehand-client --lesson " << id << "\n";
  return 0;
}

int runLessonList(SessionStore& store) {
  const auto lessons = store.listLessons();
  if (lessons.empty()) {
    std::cout << "no lessons in " << store.location()
              << " (make one: telehand-records lesson create --demo SESSION)\n";
    return 0;
  }
  std::cout << std::left << std::setw(6) << "id" << std::setw(8) << "demo" << std::setw(10)
            << "case" << std::setw(12) << "schedule" << std::setw(8) << "trials" << std::setw(6)
            << "runs" << std::setw(14) << "technique"
            << "name\n";
  for (const auto& l : lessons) {
    std::cout << std::left << std::setw(6) << l.id << std::setw(8) << l.demo_session
              << std::setw(10) << l.case_name << std::setw(12) << l.schedule << std::setw(8)
              << (std::to_string(l.guided) + "+" + std::to_string(l.attempts)) << std::setw(6)
              << runsOf(store, l.id).size() << std::setw(14) << l.technique << l.name << "\n";
  }
  return 0;
}

int runLessonShow(SessionStore& store, uint64_t lesson_id) {
  const auto l = store.lesson(lesson_id);
  if (!l) throw Error("no lesson " + std::to_string(lesson_id) + " in the record");
  if (l->technique == "massage") {
    const technique::MassageTargets m = server::lesson::decodeMassageTargets(l->targets);
    std::cout << std::fixed << std::setprecision(2) << "lesson " << l->id << ": " << l->name
              << "\n  demonstration: session " << l->demo_session << " on case " << l->case_name
              << " (massage)\n  targets: press " << m.normal_mean_n << " N (sd " << m.normal_sd_n
              << ", band " << m.band_min_n << "-" << m.band_max_n << " N), circles of "
              << 1000.0 * m.radius_m << " mm at " << m.frequency_hz << " Hz, circularity "
              << m.circularity << ", tangential/normal " << m.tangential_ratio
              << "\n  plan: " << l->guided << " guided trial(s), " << l->attempts
              << " attempt(s) of " << l->trial_s << " s, " << l->schedule << " feedback\n";
  } else {
    const technique::Targets t = server::lesson::decodeTargets(l->targets);
    std::cout << std::fixed << std::setprecision(2) << "lesson " << l->id << ": " << l->name
              << "\n  demonstration: session " << l->demo_session << " on case " << l->case_name
              << " (" << l->technique << ")\n  targets: force " << t.band_min_n << "-"
              << t.band_max_n << " N (peak " << t.force_peak_n << ", mean " << t.force_mean_n
              << "), " << t.frequency_hz << " Hz, amplitude " << t.amplitude_deg << " deg, flexion "
              << t.rom_min_deg[0] << ".." << t.rom_max_deg[0] << " deg, path period "
              << t.path_period_s << " s\n  plan: " << l->guided << " guided trial(s), "
              << l->attempts << " attempt(s) of " << l->trial_s << " s, " << l->schedule
              << " feedback" << (l->assessment ? ", exploration before and after" : "")
              << (l->takeover ? ", a supervisor may take over the demonstration" : "") << "\n";
  }
  const auto runs = runsOf(store, l->id);
  if (runs.empty()) std::cout << "  runs: none yet\n";
  for (const auto& s : runs) {
    const auto trials = store.trials(s.id);
    std::cout << "  run: session " << s.id << " by " << s.user << ", " << s.state << ", "
              << trials.size() << " trials scored, mean overall " << std::setprecision(0)
              << meanOverall(trials) << std::setprecision(2) << "\n";
  }
  return 0;
}

int runReport(SessionStore& store, const ReportRequest& r) {
  uint64_t session = r.session;
  std::optional<LessonInfo> lesson;
  if (r.lesson != 0) {
    lesson = store.lesson(r.lesson);
    if (!lesson) throw Error("no lesson " + std::to_string(r.lesson) + " in the record");
    const auto runs = runsOf(store, r.lesson);
    if (runs.empty()) throw Error("lesson " + std::to_string(r.lesson) + " has not been run yet");
    session = runs.back().id;
  }
  const auto info = store.session(session);
  if (!info) throw Error("no session " + std::to_string(session) + " in the record");
  const uint64_t lesson_id = store.sessionLesson(session);
  if (lesson_id == 0) {
    throw Error("session " + std::to_string(session) + " is not a lesson run (mode " + info->mode +
                ")");
  }
  if (!lesson) lesson = store.lesson(lesson_id);
  if (!lesson) throw Error("the lesson of session " + std::to_string(session) + " is missing");
  const double scale = forceScaleOf(r.cases_dir, lesson->case_name);
  {
    std::error_code ec;
    std::filesystem::create_directories(r.out_dir, ec);
    if (ec || !std::filesystem::is_directory(r.out_dir)) {
      throw Error("cannot write the report into '" + r.out_dir +
                  "': " + (ec ? ec.message() : std::string("it is not a directory")));
    }
  }
  const std::string base =
      (std::filesystem::path(r.out_dir) /
       ("lesson-" + std::to_string(lesson->id) + "-session-" + std::to_string(session)))
          .string();
  if (lesson->technique == "massage") {
    MassageReportInput in;
    in.targets = server::lesson::decodeMassageTargets(lesson->targets);
    in.web = webOf(r.cases_dir, lesson->case_name);
    in.demonstration =
        technique::massageSeriesFromSamples(allSamples(store, lesson->demo_session), scale);
    in.title = "Lesson " + std::to_string(lesson->id) + ": " + lesson->name;
    in.subtitle = "massage run: session " + std::to_string(session) + " by " + info->user +
                  " on case " + info->case_name + " (" + info->state + "), " + lesson->schedule +
                  " feedback";
    Shortfall shortfall;
    trialRows(store, session, shortfall, in.trials, [&](const auto& valid, MassageReportTrial& rt) {
      rt.series = technique::massageSeriesFromSamples(valid, scale);
      rt.score =
          technique::scoreMassage(rt.series, in.targets, in.web, server::lesson::kMassageSettleS);
    });
    in.history = learningHistory(store, info->user, session);
    writeFileAtomically(base + ".html", renderMassageReportHtml(in));
    writeFileAtomically(base + "-scores.csv", renderMassageScoresCsv(in));
    std::cout << "report: " << base << ".html (massage, " << trialCount(in.trials.size(), shortfall)
              << ", " << in.history.size() << " runs in the learning curve)\n"
              << shortfall.lines << "scores: " << base << "-scores.csv\n";
    return reportExit(session, shortfall);
  }
  ReportInput in;
  in.targets = server::lesson::decodeTargets(lesson->targets);
  {
    const auto demo = allSamples(store, lesson->demo_session);
    in.demonstration = technique::seriesFromSamples(demo, scale);
  }
  in.title = "Lesson " + std::to_string(lesson->id) + ": " + lesson->name;
  in.subtitle = "run: session " + std::to_string(session) + " by " + info->user + " on case " +
                info->case_name + " (" + info->state + "), " + lesson->schedule + " feedback";
  // Each trial scored again from its record (the scores are a function of the record).
  Shortfall shortfall;
  trialRows(store, session, shortfall, in.trials, [&](const auto& valid, ReportTrial& rt) {
    rt.series = technique::seriesFromSamples(valid, scale);
    rt.score = technique::score(rt.series, in.targets, server::lesson::kSettleS);
  });
  // Ranges before and after, per direction reached in both phases.
  std::map<std::string, double> before, after;
  for (const auto& reach : store.reaches(session)) {
    (reach.phase == "baseline" ? before : after)[reach.direction] = reach.angle_deg;
  }
  for (const auto& [dir, deg] : before) {
    if (after.count(dir)) in.ranges.push_back({dir, deg, after[dir]});
  }
  // The learning curve: this user's earlier runs of lessons, oldest first (this one is added
  // by the page as "this lesson").
  in.history = learningHistory(store, info->user, session);
  writeFileAtomically(base + ".html", renderReportHtml(in));
  writeFileAtomically(base + "-scores.csv", renderScoresCsv(in));
  writeFileAtomically(base + "-oscillations.csv", renderOscillationsCsv(in));
  std::cout << "report: " << base << ".html (" << trialCount(in.trials.size(), shortfall) << ", "
            << in.ranges.size() << " ranges, " << in.history.size() << " runs in the learning "
            << "curve)\n"
            << shortfall.lines << "scores: " << base << "-scores.csv, " << base
            << "-oscillations.csv\n";
  return reportExit(session, shortfall);
}

}  // namespace telehand::records
