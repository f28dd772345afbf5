#pragma once
/// telehand-records' lesson commands (docs/lessons.md): lesson create|list|show, and the
/// report of a lesson run (a session) or of a lesson's runs.
#include <cstdint>
#include <string>

#include "telehand/server/store/store.h"

namespace telehand::records {

struct LessonRequest {
  std::string db;
  std::string cases_dir;
  uint64_t demo = 0;  ///< the demonstration session
  std::string name;
  std::string schedule = "terminal";
  int guided = 2, attempts = 3;
  double trial_s = 8.0;
  bool assessment = true;
  bool takeover = false;  ///< a supervisor may take over the demonstration
};
/// Derives the targets from the demonstration and stores the lesson; prints its id.
int runLessonCreate(const LessonRequest& r);
int runLessonList(server::store::SessionStore& store);
int runLessonShow(server::store::SessionStore& store, uint64_t lesson_id);

struct ReportRequest {
  uint64_t session = 0;  ///< a lesson run
  uint64_t lesson = 0;   ///< or a lesson: its latest run, with every run in the learning curve
  std::string out_dir = ".";
  std::string cases_dir;
};
/// Writes lesson-SESSION.html, lesson-SESSION-scores.csv and -oscillations.csv; prints the
/// paths. Every stored trial has a row; one the record lacks samples of says how many (one
/// without 2 valid samples, or with too little left to judge, is not scored and says why):
/// then a warning naming them and 3, else 0.
int runReport(server::store::SessionStore& store, const ReportRequest& r);

}  // namespace telehand::records
