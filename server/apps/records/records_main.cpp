// telehand-records: read session records (list, export to CSV).
#include <exception>
#include <iostream>

#include "records_fit.h"
#include "records_lesson.h"
#include "records_read.h"
#include "telehand/app/cli.h"
#include "telehand/core/error.h"
#include "telehand/server/store/open_store.h"

int main(int argc, char** argv) {
  using namespace telehand::server::store;
  CLI::App app{
      "telehand-records: list, show, export and fit telehand session records; lessons "
      "and their reports"};
  std::string db = "records/telehand.db";
  app.add_option("--db", db,
                 "record store: an SQLite file path, or a PostgreSQL URI "
                 "postgresql://[user@]host[:port]/dbname (postgres:// too; the password from "
                 "~/.pgpass or PGPASSWORD rather than the URI)")
      ->capture_default_str();
  app.require_subcommand(1);
  auto* list = app.add_subcommand("list", "list the sessions in the record database");
  auto* exp =
      app.add_subcommand("export", "export one session's samples to CSV (one row per sample)");
  uint64_t session_id = 0;
  std::string out_path;
  auto* show = app.add_subcommand(
      "show", "one session: summary, events (marks, errors, scores) and exploration reaches");
  show->add_option("session", session_id, "session id (see 'list')")->required();
  bool digest = false;
  show->add_flag("--digest", digest,
                 "also read every sample and print the record's digest (telehand-client prints "
                 "the digest of what it sent: equal digests, equal samples)");
  exp->add_option("session", session_id, "session id (see 'list')")->required();
  exp->add_option("-o,--output", out_path, "CSV file to write (default: stdout)");
  telehand::records::FitRequest fit_req;
  fit_req.cases_dir = TELEHAND_DEPLOY_DIR "/cases";
  auto* fit = app.add_subcommand(
      "fit",
      "fit a capture session: a patient-case file (a cubic per axis; for a massage the web's "
      "[tissue]) and a plot per axis (per tissue parameter)");
  fit->add_option("session", fit_req.session, "capture session id (see 'list')")->required();
  fit->add_option("-o,--output", fit_req.output, "case file to write (default: NAME.toml)");
  fit->add_option("--name", fit_req.name, "case name (default: capture-SESSION)");
  fit->add_option("--plots", fit_req.plots_dir,
                  "directory for the plots (default: next to the case file)");
  fit->add_option("--plot-format", fit_req.plot_format, "png or svg")
      ->check(CLI::IsMember({"svg", "png"}))
      ->capture_default_str();
  fit->add_option("--cases", fit_req.cases_dir,
                  "patient cases (the session's case gives the joint frame)")
      ->capture_default_str();
  fit->add_option("--technique", fit_req.technique,
                  "what the capture is of: mobilization (the MCP joint) or massage (the web "
                  "between thumb and index; its case's [tissue] gives the web's place)")
      ->check(CLI::IsMember({"mobilization", "massage"}))
      ->capture_default_str();
  fit->add_flag("-q,--quiet", fit_req.quiet, "no progress lines");
  telehand::records::SynthRequest synth_req;
  synth_req.cases_dir = TELEHAND_DEPLOY_DIR "/cases";
  auto* synth = app.add_subcommand("synth",
                                   "store a synthetic capture: a mobilization of a known joint "
                                   "through the simulated MF-2, with thimble noise");
  synth->add_option("--case", synth_req.case_name, "ground-truth joint (a patient case)")
      ->capture_default_str();
  synth->add_option("--cases", synth_req.cases_dir, "patient cases directory")
      ->capture_default_str();
  synth->add_option("--device", synth_req.device_file, "MF-2 device file (default: built in)")
      ->check(CLI::ExistingFile);
  synth->add_option("--noise", synth_req.noise_n, "thimble error per axis, N RMS (paper: 1.43)")
      ->check(CLI::Range(0.0, 10.0))
      ->capture_default_str();
  synth->add_option("--seconds-per-axis", synth_req.seconds_per_axis, "sweep time per axis")
      ->check(CLI::Range(2.0, 600.0))
      ->capture_default_str();
  synth->add_option("--frequency", synth_req.frequency_hz, "sweep frequency, Hz")
      ->check(CLI::Range(0.05, 6.0))
      ->capture_default_str();
  synth->add_option("--max-force", synth_req.max_force_n, "force the clinician stops at, N")
      ->check(CLI::Range(1.0, 20.0))
      ->capture_default_str();
  synth->add_option("--seed", synth_req.seed, "noise seed")->capture_default_str();
  synth
      ->add_option("--technique", synth_req.technique,
                   "mobilization (a sweep of the case's joint) or massage (circles on the "
                   "case's web, 10 +- 2 N)")
      ->check(CLI::IsMember({"mobilization", "massage"}))
      ->capture_default_str();
  synth->add_option("--seconds", synth_req.massage_seconds, "length of a massage capture")
      ->check(CLI::Range(5.0, 600.0))
      ->capture_default_str();
  synth->add_flag("-q,--quiet", synth_req.quiet, "no progress lines");
  // Lessons (docs/lessons.md).
  telehand::records::LessonRequest lesson_req;
  lesson_req.cases_dir = TELEHAND_DEPLOY_DIR "/cases";
  uint64_t lesson_id = 0;
  auto* lesson =
      app.add_subcommand("lesson", "lessons: create one from a demonstration, list, show");
  lesson->require_subcommand(1);
  auto* lcreate = lesson->add_subcommand(
      "create",
      "a lesson from a demonstration session: its targets (a mobilization's force band, "
      "frequency, amplitude, range, path; a massage's press, circle and friction) and how the "
      "student's run goes");
  lcreate
      ->add_option("--demo", lesson_req.demo,
                   "the demonstration: a mobilization session, or a massage session (a "
                   "massage lesson has no exploration and no take-over)")
      ->required();
  lcreate->add_option("--name", lesson_req.name, "what the lesson is called");
  lcreate
      ->add_option("--schedule", lesson_req.schedule,
                   "feedback: concurrent (live bars), terminal (after each trial), faded "
                   "(ever fewer), self (when the student asks)")
      ->check(CLI::IsMember({"concurrent", "terminal", "faded", "self"}))
      ->capture_default_str();
  lcreate->add_option("--guided", lesson_req.guided, "guided trials (authority full down to low)")
      ->check(CLI::Range(0, 10))
      ->capture_default_str();
  lcreate->add_option("--attempts", lesson_req.attempts, "free attempts after them")
      ->check(CLI::Range(1, 20))
      ->capture_default_str();
  lcreate->add_option("--trial-seconds", lesson_req.trial_s, "length of each trial")
      ->check(CLI::Range(2.0, 120.0))
      ->capture_default_str();
  bool no_assessment = false;
  lcreate->add_flag("--no-assessment", no_assessment,
                    "no exploration before and after (the range change is not measured)");
  lcreate->add_flag("--takeover", lesson_req.takeover,
                    "a supervisor may take over the demonstration: their own MF-2 session's "
                    "movement leads the guided trials (telehand-web)");
  lcreate->add_option("--cases", lesson_req.cases_dir, "patient cases directory")
      ->capture_default_str();
  auto* llist = lesson->add_subcommand("list", "every lesson, with its runs");
  auto* lshow = lesson->add_subcommand("show", "one lesson: targets, plan and runs");
  lshow->add_option("lesson", lesson_id, "lesson id (see 'lesson list')")->required();
  telehand::records::ReportRequest report_req;
  report_req.cases_dir = TELEHAND_DEPLOY_DIR "/cases";
  auto* report = app.add_subcommand(
      "report",
      "a lesson run as an HTML page with plots and CSVs of its scores: SESSION (a run) "
      "or --lesson ID (its latest run)");
  report->add_option("session", report_req.session, "a lesson run's session id");
  report->add_option("--lesson", report_req.lesson, "a lesson: report its latest run");
  report->add_option("-o,--output-dir", report_req.out_dir, "where to write the report")
      ->capture_default_str();
  report->add_option("--cases", report_req.cases_dir, "patient cases directory")
      ->capture_default_str();
  TELEHAND_CLI_PARSE(app, argc, argv)

  try {
    if (*lesson && *lcreate) {
      lesson_req.db = db;
      lesson_req.assessment = !no_assessment;
      return telehand::records::runLessonCreate(lesson_req);
    }
    if (*synth) {
      synth_req.db = db;
      return telehand::records::runSynth(synth_req);
    }
    if (*fit) {
      fit_req.db = db;
      return telehand::records::runFit(fit_req);
    }
    const auto opened = openStore(db, SessionStore::Mode::kReadOnly);
    SessionStore& store = *opened;
    if (*list) return telehand::records::runList(store);
    if (*llist) return telehand::records::runLessonList(store);
    if (*lshow) return telehand::records::runLessonShow(store, lesson_id);
    if (*report) {
      if ((report_req.session == 0) == (report_req.lesson == 0)) {
        std::cerr << "telehand-records report: give a SESSION or --lesson ID (one of them)\n";
        return 2;
      }
      return telehand::records::runReport(store, report_req);
    }
    const auto info = store.session(session_id);
    if (info && *show) return telehand::records::runShow(store, *info, digest);
    if (!info) {
      std::cerr << "telehand-records: no session " << session_id << " in " << store.location()
                << " (run 'telehand-records --db " << store.location() << " list')\n";
      return 2;
    }
    return telehand::records::runExport(store, session_id, out_path);
  } catch (const telehand::Error& e) {
    std::cerr << "telehand-records: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {  // the file system's, or out of memory: said, not aborted
    std::cerr << "telehand-records: " << e.what() << "\n";
    return 2;
  }
}
