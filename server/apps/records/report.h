#pragma once
// telehand-records report: a lesson's trials against the clinician's demonstration as one
// self-contained HTML page (inline SVG plots: no script, nothing fetched) and as CSV.
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "telehand/core/massage_score.h"
#include "telehand/core/technique_score.h"
#include "telehand/core/tissue_model.h"

namespace telehand::records {

/// What the record holds of a trial: the samples its stretch of sequence numbers
/// (first_seq..last_seq) should have, and those the record has in it.
struct TrialSamples {
  uint64_t expected = 0;  ///< last_seq - first_seq + 1; 0: not known (then nothing is said)
  uint64_t found = 0;     ///< samples of that stretch in the record, valid or not
  /// false: too little of it in the record to score (under 2 valid samples, or what the
  /// record holds of it too short to judge: `why_not`): it has no series and no score, and a
  /// score of 0 would say the student failed a trial the record lacks.
  bool scored = true;
  /// Why the scorer did not judge it (TrialScore::not_scored), when that is the reason.
  std::string why_not = {};
  uint64_t missing() const noexcept { return expected > found ? expected - found : 0; }
  /// What the report says of it: "" (the whole trial), "K of M samples missing", "not in the
  /// record (0 of M samples)", "not scored: K of M samples missing", or with why_not
  /// "not scored: K of M samples missing: <why_not>".
  std::string note() const;
};

struct ReportTrial {
  std::string label;
  TrialSamples samples;
  technique::Series series;     ///< empty when not scored
  technique::TrialScore score;  ///< meaningless when not scored
};

/// A direction's range of motion before the lesson and after it.
struct ReportRange {
  std::string direction;
  double baseline_deg = 0.0, after_deg = 0.0;
};

struct ReportInput {
  std::string title, subtitle;
  technique::Series demonstration;
  technique::Targets targets;
  std::vector<ReportTrial> trials;
  std::vector<ReportRange> ranges;
  /// Earlier lessons' overall scores, oldest first (label, 0..100): the learning curve.
  std::vector<std::pair<std::string, double>> history;
};

/// Most points a plotted line keeps: longer series are decimated (the smallest and the
/// largest value of each stretch, in time order, so peaks survive).
inline constexpr std::size_t kMaxPlotPoints = 2000;

/// One self-contained HTML page: the targets and a table of the trials (with what the record
/// holds of each: a trial it lacks samples of says how many, one not scored says so); per
/// scored trial the force and the flexion angle against time over the demonstration's (the
/// force with the band); the frequency per trial against the target; the scores over the
/// trials; the ranges before and after per direction; the learning curve over earlier lessons
/// and this one. Every plot is an inline <svg> with an id (force-N, flexion-N, frequency,
/// scores, ranges, learning), N the trial's row from 0.
std::string renderReportHtml(const ReportInput& in);

/// One row per trial after a header row: the trial's figures and its errors and score, then
/// samples_expected, samples_missing and note (TrialSamples::note); a trial not scored has
/// its figures and score empty.
std::string renderScoresCsv(const ReportInput& in);

/// One row per oscillation of every trial after a header row.
std::string renderOscillationsCsv(const ReportInput& in);

/// (x, y) points of a line decimated to at most max_points (min and max per stretch).
std::vector<std::pair<double, double>> decimate(const std::vector<double>& x,
                                                const std::vector<double>& y,
                                                std::size_t max_points = kMaxPlotPoints);

/// A massage lesson's run (docs/lessons.md "Massage lessons").
struct MassageReportTrial {
  std::string label;
  TrialSamples samples;
  technique::MassageSeries series;  ///< empty when not scored
  technique::MassageScore score;    ///< meaningless when not scored
};

struct MassageReportInput {
  std::string title, subtitle;
  technique::MassageSeries demonstration;
  technique::MassageTargets targets;
  TissueParams web;
  std::vector<MassageReportTrial> trials;
  std::vector<std::pair<std::string, double>> history;  ///< as ReportInput's
};

/// The page of a massage run: the targets and a table of the trials (what the record holds
/// of each as renderReportHtml's); per scored trial the pads' normal force against time over
/// the demonstration's with the band (id press-N) and the contact point's path on the web over
/// the demonstration's (id path-N, millimetres); the frequency and the radius per trial
/// against the targets; the scores; the learning curve.
std::string renderMassageReportHtml(const MassageReportInput& in);
/// One row per trial after a header row: its figures, errors and score, then the samples
/// columns as renderScoresCsv's.
std::string renderMassageScoresCsv(const MassageReportInput& in);

}  // namespace telehand::records
