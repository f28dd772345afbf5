// telehand-records report: the lesson page holds its plots (inline SVG, nothing fetched, long
// series decimated) and the CSV one row per trial with that trial's figures.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>

#include "file_output.h"
#include "report.h"
#include "telehand/core/error.h"

namespace telehand::records {
namespace {

technique::Series mobilization(double freq_hz, double bias_n, double seconds) {
  technique::Series s;
  const int n = static_cast<int>(std::lround(seconds * 1000.0));
  for (int i = 0; i < n; ++i) {
    const double t = i * 1e-3;
    const double f = smoothRamp(t, 1.0) * (14.0 + bias_n + 2.0 * std::sin(2.0 * kPi * freq_hz * t));
    s.t_s.push_back(t);
    s.force_ref_n.push_back(f);
    s.angles_rad.emplace_back(degToRad(10.0 + 1.5 * f), 0.0, 0.0);
  }
  return s;
}

ReportInput lesson() {
  ReportInput in;
  in.title = "Lesson 3: MCP mobilization";
  in.subtitle = "student 7, healthy case";
  in.demonstration = mobilization(3.0, 0.0, 10.0);
  in.targets = technique::deriveTargets(in.demonstration);
  const struct {
    const char* label;
    double freq, bias, seconds;
  } trials[] = {{"trial 1", 3.6, 1.5, 10.0},
                {"trial 2, <retry> & more", 3.2, 0.5, 10.0},
                {"trial 3", 3.0, 0.1, 20.0}};
  for (const auto& t : trials) {
    ReportTrial r;
    r.label = t.label;
    r.series = mobilization(t.freq, t.bias, t.seconds);
    r.score = technique::score(r.series, in.targets);
    in.trials.push_back(std::move(r));
  }
  in.ranges = {{"flexion", 70.0, 78.0}, {"extension", 20.0, 22.5}, {"abduction", 15.0, 15.0}};
  in.history = {{"lesson 1", 41.0}, {"lesson 2", 55.5}};
  return in;
}

std::size_t count(const std::string& text, const std::string& what) {
  std::size_t n = 0;
  for (std::size_t p = text.find(what); p != std::string::npos; p = text.find(what, p + 1)) ++n;
  return n;
}

TEST(RecordsReport, HtmlHoldsEveryPlotAndNothingExternal) {
  const ReportInput in = lesson();
  const std::string html = renderReportHtml(in);
  EXPECT_EQ(html.rfind("<!DOCTYPE html>", 0), 0u);
  for (const char* id : {"force-0", "force-1", "force-2", "flexion-0", "flexion-1", "flexion-2",
                         "frequency", "scores", "ranges", "learning"}) {
    EXPECT_NE(html.find(std::string("id=\"") + id + "\""), std::string::npos) << id;
  }
  EXPECT_EQ(count(html, "<svg"), 10u);
  EXPECT_EQ(count(html, "</svg>"), 10u);
  EXPECT_EQ(html.find("<script"), std::string::npos);
  EXPECT_EQ(html.find("http"), std::string::npos);
  EXPECT_EQ(html.find("src="), std::string::npos);
  EXPECT_EQ(html.find("href="), std::string::npos);
  EXPECT_EQ(html.find("no data"), std::string::npos);
  // Labels are text, not markup.
  EXPECT_NE(html.find("trial 2, &lt;retry&gt; &amp; more"), std::string::npos);
  EXPECT_EQ(html.find("<retry>"), std::string::npos);
  // Per trial: the band, the demonstration and the trial on the force plot; two ranges bars
  // per direction; the learning curve's three points (two lessons and this one).
  EXPECT_EQ(count(html, "fill-opacity=\"0.18\""), 3u);
  EXPECT_EQ(count(html, "class=\"bar\""), 6u);
  const std::size_t learning = html.find("id=\"learning\"");
  EXPECT_EQ(count(html.substr(learning), "<circle"), 3u);
  EXPECT_NE(html.find("this lesson"), std::string::npos);

  // No plotted line has more than kMaxPlotPoints points (the 20 s trial has 20,000 samples).
  std::size_t lines = 0, longest = 0;
  for (std::size_t p = html.find("points=\""); p != std::string::npos;
       p = html.find("points=\"", p + 1)) {
    const std::size_t end = html.find('"', p + 8);
    const std::string pts = html.substr(p + 8, end - p - 8);
    const std::size_t n = pts.empty() ? 0 : count(pts, " ") + 1;
    longest = std::max(longest, n);
    ++lines;
  }
  EXPECT_EQ(lines, 3u * 4u + 2u + 1u + 1u);  // force, flexion x2 each; frequency 2; scores; curve
  EXPECT_LE(longest, kMaxPlotPoints);
  EXPECT_GT(longest, kMaxPlotPoints / 2);
}

std::vector<std::string> splitCsv(const std::string& line) {
  std::vector<std::string> out;
  std::string field;
  bool quoted = false;
  for (std::size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (quoted) {
      if (c == '"' && i + 1 < line.size() && line[i + 1] == '"') {
        field += '"';
        ++i;
      } else if (c == '"') {
        quoted = false;
      } else {
        field += c;
      }
    } else if (c == '"') {
      quoted = true;
    } else if (c == ',') {
      out.push_back(field);
      field.clear();
    } else {
      field += c;
    }
  }
  out.push_back(field);
  return out;
}

TEST(RecordsReport, CsvHasOneRowPerTrialWithItsFigures) {
  const ReportInput in = lesson();
  std::istringstream csv(renderScoresCsv(in));
  std::string line;
  ASSERT_TRUE(std::getline(csv, line));
  const std::vector<std::string> header = splitCsv(line);
  auto column = [&](const std::string& name) {
    const auto it = std::find(header.begin(), header.end(), name);
    EXPECT_NE(it, header.end()) << name;
    return static_cast<std::size_t>(it - header.begin());
  };
  std::size_t rows = 0;
  while (std::getline(csv, line)) {
    const std::vector<std::string> f = splitCsv(line);
    ASSERT_EQ(f.size(), header.size()) << line;
    ASSERT_LT(rows, in.trials.size());
    const technique::TrialScore& s = in.trials[rows].score;
    EXPECT_EQ(f[column("label")], in.trials[rows].label);
    EXPECT_EQ(std::stoul(f[column("oscillations")]), s.figures.oscillations.size());
    EXPECT_NEAR(std::stod(f[column("force_peak_n")]), s.figures.force_peak_n, 1e-4);
    EXPECT_NEAR(std::stod(f[column("peak_error_n")]), s.peak_error_n, 1e-4);
    EXPECT_NEAR(std::stod(f[column("frequency_hz")]), s.figures.frequency_spectrum_hz, 1e-5);
    EXPECT_NEAR(std::stod(f[column("frequency_error_hz")]), s.frequency_error_hz, 1e-5);
    EXPECT_NEAR(std::stod(f[column("time_in_band")]), s.time_in_band, 1e-4);
    EXPECT_NEAR(std::stod(f[column("overall")]), s.overall, 0.01);
    ++rows;
  }
  EXPECT_EQ(rows, in.trials.size());
  // The figures are the trials' own: trial 1 pushed 1.5 N too hard at +0.6 Hz.
  EXPECT_NEAR(in.trials[0].score.peak_error_n, 1.5, 0.1);
  EXPECT_NEAR(in.trials[0].score.frequency_error_hz, 0.6, 0.05);

  std::istringstream osc(renderOscillationsCsv(in));
  std::size_t osc_rows = 0, expected = 0;
  for (const ReportTrial& t : in.trials) expected += t.score.figures.oscillations.size();
  std::getline(osc, line);  // header
  while (std::getline(osc, line)) ++osc_rows;
  EXPECT_EQ(osc_rows, expected);
}

/// The fields of the CSV's rows by column name (its header's).
std::vector<std::map<std::string, std::string>> csvRows(const std::string& text) {
  std::istringstream csv(text);
  std::string line;
  std::vector<std::map<std::string, std::string>> rows;
  if (!std::getline(csv, line)) return rows;
  const std::vector<std::string> header = splitCsv(line);
  while (std::getline(csv, line)) {
    const std::vector<std::string> f = splitCsv(line);
    EXPECT_EQ(f.size(), header.size()) << line;
    std::map<std::string, std::string> row;
    for (std::size_t i = 0; i < std::min(f.size(), header.size()); ++i) row[header[i]] = f[i];
    rows.push_back(std::move(row));
  }
  return rows;
}

// A trial the record lacks keeps its row saying so and is neither plotted nor scored (not
// scored 0 either); a trial with gaps says how many samples it lacks, in the table and in the
// CSV; a whole trial says how many it has.
TEST(RecordsReport, ATrialTheRecordLacksKeepsItsRowAndGapsAreCounted) {
  ReportInput in = lesson();
  in.trials[0].samples = {10000, 10000, true};
  in.trials[1].samples = {10000, 0, false};
  in.trials[1].series = {};
  in.trials[1].score = {};
  in.trials[2].samples = {20000, 15000, true};
  EXPECT_EQ(in.trials[0].samples.note(), "");
  EXPECT_EQ(in.trials[1].samples.note(), "not in the record (0 of 10000 samples)");
  EXPECT_EQ(in.trials[2].samples.note(), "5000 of 20000 samples missing");
  EXPECT_EQ((TrialSamples{4000, 1, false}.note()), "not scored: 3999 of 4000 samples missing");

  const std::string html = renderReportHtml(in);
  EXPECT_NE(html.find("<td>not in the record (0 of 10000 samples)</td><td colspan=\"9\">not "
                      "scored</td>"),
            std::string::npos);
  EXPECT_NE(html.find("<td>5000 of 20000 samples missing</td>"), std::string::npos);
  EXPECT_NE(html.find("<td>10000</td>"), std::string::npos);
  EXPECT_NE(html.find("trial 2, &lt;retry&gt; &amp; more: not in the record (0 of 10000 "
                      "samples)."),
            std::string::npos);
  for (const char* id : {"force-0", "flexion-0", "force-2", "flexion-2"}) {
    EXPECT_NE(html.find(std::string("id=\"") + id + "\""), std::string::npos) << id;
  }
  EXPECT_EQ(html.find("id=\"force-1\""), std::string::npos);
  EXPECT_EQ(html.find("id=\"flexion-1\""), std::string::npos);
  // The scores and frequencies: a point per scored trial, every trial on the axis; the
  // learning curve's "this lesson" the mean of the scored ones.
  const std::size_t scores = html.find("id=\"scores\"");
  const std::size_t ranges = html.find("id=\"ranges\"");
  ASSERT_NE(scores, std::string::npos);
  EXPECT_EQ(count(html.substr(scores, ranges - scores), "<circle"), 2u);
  EXPECT_NE(html.substr(scores, ranges - scores).find(">trial 2, &lt;retry&gt; &amp; more<"),
            std::string::npos);

  const auto rows = csvRows(renderScoresCsv(in));
  ASSERT_EQ(rows.size(), 3u);
  EXPECT_EQ(rows[0].at("samples_expected"), "10000");
  EXPECT_EQ(rows[0].at("samples_missing"), "0");
  EXPECT_EQ(rows[0].at("note"), "");
  EXPECT_EQ(rows[1].at("trial"), "1");
  EXPECT_EQ(rows[1].at("label"), in.trials[1].label);
  EXPECT_EQ(rows[1].at("samples_expected"), "10000");
  EXPECT_EQ(rows[1].at("samples_missing"), "10000");
  EXPECT_EQ(rows[1].at("note"), "not in the record (0 of 10000 samples)");
  EXPECT_EQ(rows[1].at("overall"), "") << "not scored, not scored 0";
  EXPECT_EQ(rows[1].at("oscillations"), "");
  EXPECT_EQ(rows[2].at("samples_missing"), "5000");
  EXPECT_EQ(rows[2].at("note"), "5000 of 20000 samples missing");
  EXPECT_NEAR(std::stod(rows[2].at("overall")), in.trials[2].score.overall, 0.01);
  for (const auto& row : csvRows(renderOscillationsCsv(in))) EXPECT_NE(row.at("trial"), "1");
}

// A trial whose record holds too little to judge (the scorer's not_scored: what is left of it
// between gaps is too short) keeps its row, not scored and saying why; not scored 0.
TEST(RecordsReport, ATrialTooShortToJudgeAfterItsGapsSaysWhy) {
  ReportInput in = lesson();
  technique::Series scraps;
  for (std::size_t i = 0; i < in.trials[1].series.t_s.size(); ++i) {
    if (i >= 1900 && i + 200 < in.trials[1].series.t_s.size()) continue;
    scraps.t_s.push_back(in.trials[1].series.t_s[i]);
    scraps.force_ref_n.push_back(in.trials[1].series.force_ref_n[i]);
    scraps.angles_rad.push_back(in.trials[1].series.angles_rad[i]);
  }
  const technique::TrialScore sc = technique::score(scraps, in.targets, 2.0);
  ASSERT_FALSE(sc.not_scored.empty());
  EXPECT_EQ(sc.overall, 0.0);
  in.trials[1].samples = {10000, 2100, false, sc.not_scored};
  in.trials[1].series = {};
  in.trials[1].score = {};
  const std::string note = in.trials[1].samples.note();
  EXPECT_EQ(note, "not scored: 7900 of 10000 samples missing: " + sc.not_scored);
  EXPECT_NE(note.find("none of its 2 stretches between gaps is long enough to judge"),
            std::string::npos)
      << note;
  EXPECT_EQ((TrialSamples{4000, 4000, false, "its samples span 2.2 s"}.note()),
            "not scored: its samples span 2.2 s");
  const std::string html = renderReportHtml(in);
  EXPECT_NE(html.find("<td>7900 of 10000 samples missing</td><td colspan=\"9\">not scored</td>"),
            std::string::npos);
  EXPECT_NE(html.find("<p>trial 2, &lt;retry&gt; &amp; more: " + note + ".</p>"),
            std::string::npos);
  EXPECT_EQ(html.find("id=\"force-1\""), std::string::npos);
  const auto rows = csvRows(renderScoresCsv(in));
  ASSERT_EQ(rows.size(), 3u);
  EXPECT_EQ(rows[1].at("overall"), "") << "not scored, not scored 0";
  EXPECT_EQ(rows[1].at("samples_missing"), "7900");
  EXPECT_EQ(rows[1].at("note"), note);
}

// The massage page and CSV: the same rows for a trial the record lacks.
TEST(RecordsReport, AMassageTrialTheRecordLacksKeepsItsRow) {
  MassageReportInput in;
  in.title = "massage";
  MassageReportTrial whole, gone;
  whole.label = "trial 1 (attempt)";
  whole.samples = {6001, 5001, true};
  whole.score.overall = 71.0;
  gone.label = "trial 2 (attempt)";
  gone.samples = {6001, 0, false};
  in.trials = {whole, gone};
  const std::string html = renderMassageReportHtml(in);
  EXPECT_NE(html.find("<td>1000 of 6001 samples missing</td>"), std::string::npos);
  EXPECT_NE(html.find("<td>not in the record (0 of 6001 samples)</td><td colspan=\"9\">not "
                      "scored</td>"),
            std::string::npos);
  EXPECT_NE(html.find("id=\"press-0\""), std::string::npos);
  EXPECT_EQ(html.find("id=\"press-1\""), std::string::npos);
  const auto rows = csvRows(renderMassageScoresCsv(in));
  ASSERT_EQ(rows.size(), 2u);
  EXPECT_EQ(rows[0].at("overall"), "71.00");
  EXPECT_EQ(rows[0].at("samples_missing"), "1000");
  EXPECT_EQ(rows[0].at("note"), "1000 of 6001 samples missing");
  EXPECT_EQ(rows[1].at("overall"), "");
  EXPECT_EQ(rows[1].at("samples_missing"), "6001");
  EXPECT_EQ(rows[1].at("note"), "not in the record (0 of 6001 samples)");
}

TEST(RecordsReport, DecimationKeepsTheExtremes) {
  std::vector<double> x, y;
  for (int i = 0; i < 50000; ++i) {
    x.push_back(i * 1e-3);
    y.push_back(std::sin(0.01 * i) + (i == 31234 ? 5.0 : 0.0) - (i == 777 ? 4.0 : 0.0));
  }
  const auto pts = decimate(x, y, 2000);
  EXPECT_LE(pts.size(), 2000u);
  double lo = 1e9, hi = -1e9;
  for (std::size_t i = 0; i < pts.size(); ++i) {
    lo = std::min(lo, pts[i].second);
    hi = std::max(hi, pts[i].second);
    if (i > 0) {
      EXPECT_GT(pts[i].first, pts[i - 1].first);
    }
  }
  EXPECT_DOUBLE_EQ(hi, y[31234]);
  EXPECT_DOUBLE_EQ(lo, y[777]);
  EXPECT_EQ(decimate({0.0, 1.0}, {2.0, 3.0}).size(), 2u);
}

TEST(RecordsReport, AnEmptyLessonStillRenders) {
  ReportInput in;
  in.title = "empty";
  const std::string html = renderReportHtml(in);
  EXPECT_NE(html.find("No trials."), std::string::npos);
  EXPECT_NE(html.find("id=\"learning\""), std::string::npos);
  EXPECT_EQ(renderScoresCsv(in).find('\n'), renderScoresCsv(in).size() - 1);  // header only
}

TEST(RecordsFiles, AFileIsWrittenWholeOrNotAtAll) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / ("telehand-files-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  const fs::path file = dir / "sub" / "case.toml";
  writeFileAtomically(file, "a = 1\n");  // its directory made
  const auto read = [](const fs::path& p) {
    std::ifstream f(p);
    std::stringstream ss;
    ss << f.rdbuf();
    return ss.str();
  };
  EXPECT_EQ(read(file), "a = 1\n");
  writeFileAtomically(file, "b = 2\n");  // replaced whole
  EXPECT_EQ(read(file), "b = 2\n");
  EXPECT_FALSE(fs::exists(file.string() + ".partial"));
  // Where the file cannot be put (a directory of that name): an error naming it, nothing left
  // behind.
  fs::create_directories(dir / "taken");
  try {
    writeFileAtomically(dir / "taken", "c = 3\n");
    ADD_FAILURE() << "written over a directory";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("cannot write '" + (dir / "taken").string() + "'"),
              std::string::npos)
        << e.what();
    EXPECT_NE(std::string(e.what()).find("nothing was written"), std::string::npos) << e.what();
  }
  EXPECT_TRUE(fs::is_directory(dir / "taken"));
  EXPECT_FALSE(fs::exists((dir / "taken").string() + ".partial"));
  // Under a file where its directory should be: the same.
  EXPECT_THROW(writeFileAtomically(file / "x.toml", "d = 4\n"), Error);
  EXPECT_EQ(read(file), "b = 2\n");
  fs::remove_all(dir);
}

}  // namespace
}  // namespace telehand::records
