#include "report.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>

#include "telehand/core/joint_model.h"

namespace telehand::records {

namespace {

using Points = std::vector<std::pair<double, double>>;

constexpr const char* kDemoColor = "#888888";
constexpr const char* kTrialColor = "#1f6fb4";
constexpr const char* kTargetColor = "#c0392b";
constexpr const char* kBandColor = "#2ecc71";
constexpr const char* kAfterColor = "#e67e22";

std::string num(double v, int decimals) {
  if (!std::isfinite(v)) return "";
  if (std::abs(v) < 0.5 * std::pow(10.0, -decimals)) v = 0.0;  // no "-0.0"
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
  return buf;
}

std::string escapeHtml(const std::string& s) {
  std::string out;
  out.reserve(s.size());
  for (char c : s) {
    switch (c) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      case '\'':
        out += "&#39;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

std::string csvField(const std::string& s) {
  if (s.find_first_of(",\"\n\r") == std::string::npos) return s;
  std::string out = "\"";
  for (char c : s) {
    if (c == '"') out += '"';
    out += c;
  }
  return out + "\"";
}

/// A step of 1, 2 or 5 times a power of ten giving about `ticks` intervals over `range`.
double niceStep(double range, int ticks) {
  if (!(range > 0.0)) return 1.0;
  const double raw = range / ticks;
  const double mag = std::pow(10.0, std::floor(std::log10(raw)));
  const double r = raw / mag;
  return (r < 1.5 ? 1.0 : r < 3.5 ? 2.0 : r < 7.5 ? 5.0 : 10.0) * mag;
}

struct Line {
  Points pts;
  std::string color, label;
  double width = 1.5;
  bool dashed = false;
  bool markers = false;  // a dot at each point (few points: per trial)
};

struct Shade {
  double y0, y1;
  std::string color, label;
};

struct Chart {
  std::string id, title, xlabel, ylabel;
  std::vector<Line> lines;
  std::vector<Shade> shades;
  std::vector<std::string> categories;  // x at 0, 1, ... labelled with these
  bool y_from_zero = false;
  double y_min = std::numeric_limits<double>::quiet_NaN(), y_max = y_min;  // fixed if finite
};

constexpr int kW = 760, kH = 260, kLeft = 62, kRight = 18, kTop = 30, kBottom = 46;

std::string svgOpen(const std::string& id, const std::string& title) {
  std::ostringstream o;
  o << "<figure><svg class=\"plot\" id=\"" << escapeHtml(id) << "\" viewBox=\"0 0 " << kW << ' '
    << kH << "\" width=\"" << kW << "\" height=\"" << kH << "\" role=\"img\"><title>"
    << escapeHtml(title) << "</title>\n";
  o << "<text x=\"" << kLeft << "\" y=\"18\" class=\"t\">" << escapeHtml(title) << "</text>\n";
  return o.str();
}

std::string legend(const std::vector<std::pair<std::string, std::string>>& items) {
  std::ostringstream o;
  double x = kW - kRight;
  for (auto it = items.rbegin(); it != items.rend(); ++it) {
    if (it->first.empty()) continue;
    x -= 14.0 + 6.5 * static_cast<double>(it->first.size());
    o << "<rect x=\"" << num(x, 1) << "\" y=\"10\" width=\"10\" height=\"10\" fill=\"" << it->second
      << "\"/><text x=\"" << num(x + 13, 1) << "\" y=\"19\" class=\"l\">" << escapeHtml(it->first)
      << "</text>\n";
    x -= 8.0;
  }
  return o.str();
}

std::string svgChart(const Chart& c) {
  double x0 = std::numeric_limits<double>::infinity(), x1 = -x0, y0 = x0, y1 = -x0;
  for (const Line& l : c.lines) {
    for (const auto& [x, y] : l.pts) {
      if (!std::isfinite(x) || !std::isfinite(y)) continue;
      x0 = std::min(x0, x);
      x1 = std::max(x1, x);
      y0 = std::min(y0, y);
      y1 = std::max(y1, y);
    }
  }
  for (const Shade& s : c.shades) {
    y0 = std::min(y0, s.y0);
    y1 = std::max(y1, s.y1);
  }
  std::ostringstream o;
  o << svgOpen(c.id, c.title);
  if (!(x1 >= x0) || !(y1 >= y0)) {
    o << "<text x=\"" << kW / 2 << "\" y=\"" << kH / 2 << "\" class=\"l\">no data</text></svg>"
      << "</figure>\n";
    return o.str();
  }
  if (!c.categories.empty()) {
    x0 = -0.5;
    x1 = static_cast<double>(c.categories.size()) - 0.5;
  }
  if (c.y_from_zero) y0 = std::min(y0, 0.0);
  if (std::isfinite(c.y_min)) y0 = c.y_min;
  if (std::isfinite(c.y_max)) y1 = c.y_max;
  if (x1 - x0 < 1e-9) {
    x0 -= 0.5;
    x1 += 0.5;
  }
  if (y1 - y0 < 1e-9) {
    y0 -= 0.5;
    y1 += 0.5;
  }
  if (!std::isfinite(c.y_min) && !std::isfinite(c.y_max)) {
    const double pad = 0.05 * (y1 - y0);
    if (!(c.y_from_zero && y0 == 0.0)) y0 -= pad;
    y1 += pad;
  }
  const double pw = kW - kLeft - kRight, ph = kH - kTop - kBottom;
  auto px = [&](double x) { return kLeft + (x - x0) / (x1 - x0) * pw; };
  auto py = [&](double y) { return kTop + (y1 - y) / (y1 - y0) * ph; };

  // Bands, grid and axes.
  for (const Shade& s : c.shades) {
    const double top = py(std::min(s.y1, y1)), bottom = py(std::max(s.y0, y0));
    o << "<rect x=\"" << kLeft << "\" y=\"" << num(top, 1) << "\" width=\"" << num(pw, 1)
      << "\" height=\"" << num(std::max(0.0, bottom - top), 1) << "\" fill=\"" << s.color
      << "\" fill-opacity=\"0.18\"/>\n";
  }
  const double ys = niceStep(y1 - y0, 5);
  for (double y = std::ceil(y0 / ys) * ys; y <= y1 + 1e-9 * ys; y += ys) {
    o << "<line x1=\"" << kLeft << "\" x2=\"" << kW - kRight << "\" y1=\"" << num(py(y), 1)
      << "\" y2=\"" << num(py(y), 1) << "\" class=\"g\"/><text x=\"" << kLeft - 6 << "\" y=\""
      << num(py(y) + 4, 1) << "\" class=\"yt\">" << num(y, ys < 1 ? (ys < 0.1 ? 2 : 1) : 0)
      << "</text>\n";
  }
  if (!c.categories.empty()) {
    for (std::size_t i = 0; i < c.categories.size(); ++i) {
      o << "<text x=\"" << num(px(static_cast<double>(i)), 1) << "\" y=\"" << kH - kBottom + 16
        << "\" class=\"xt\">" << escapeHtml(c.categories[i]) << "</text>\n";
    }
  } else {
    const double xs = niceStep(x1 - x0, 8);
    for (double x = std::ceil(x0 / xs) * xs; x <= x1 + 1e-9 * xs; x += xs) {
      o << "<text x=\"" << num(px(x), 1) << "\" y=\"" << kH - kBottom + 16 << "\" class=\"xt\">"
        << num(x, xs < 1 ? 1 : 0) << "</text>\n";
    }
  }
  o << "<rect x=\"" << kLeft << "\" y=\"" << kTop << "\" width=\"" << num(pw, 1) << "\" height=\""
    << num(ph, 1) << "\" class=\"f\"/>\n";
  o << "<text x=\"" << num(kLeft + pw / 2, 1) << "\" y=\"" << kH - 8 << "\" class=\"xt\">"
    << escapeHtml(c.xlabel) << "</text>\n";
  o << "<text transform=\"translate(14," << num(kTop + ph / 2, 1) << ") rotate(-90)\" class=\"xt\">"
    << escapeHtml(c.ylabel) << "</text>\n";

  for (const Line& l : c.lines) {
    o << "<polyline fill=\"none\" stroke=\"" << l.color << "\" stroke-width=\"" << num(l.width, 1)
      << "\"" << (l.dashed ? " stroke-dasharray=\"6 4\"" : "") << " points=\"";
    bool first = true;
    for (const auto& [x, y] : l.pts) {
      if (!std::isfinite(x) || !std::isfinite(y)) continue;
      o << (first ? "" : " ") << num(px(x), 1) << ',' << num(py(std::clamp(y, y0, y1)), 1);
      first = false;
    }
    o << "\"/>\n";
    if (l.markers) {
      for (const auto& [x, y] : l.pts) {
        if (!std::isfinite(x) || !std::isfinite(y)) continue;
        o << "<circle cx=\"" << num(px(x), 1) << "\" cy=\"" << num(py(y), 1)
          << "\" r=\"3.5\" fill=\"" << l.color << "\"/>\n";
      }
    }
  }
  std::vector<std::pair<std::string, std::string>> items;
  for (const Shade& s : c.shades) items.emplace_back(s.label, s.color);
  for (const Line& l : c.lines) items.emplace_back(l.label, l.color);
  o << legend(items) << "</svg></figure>\n";
  return o.str();
}

/// Grouped bars: one group per category, one bar per series.
std::string svgBars(const std::string& id, const std::string& title, const std::string& ylabel,
                    const std::vector<std::string>& categories,
                    const std::vector<std::pair<std::string, std::vector<double>>>& series,
                    const std::vector<std::string>& colors) {
  std::ostringstream o;
  o << svgOpen(id, title);
  double y0 = 0.0, y1 = 0.0;
  for (const auto& s : series) {
    for (double v : s.second) {
      if (!std::isfinite(v)) continue;
      y0 = std::min(y0, v);
      y1 = std::max(y1, v);
    }
  }
  if (categories.empty() || !(y1 > y0)) {
    o << "<text x=\"" << kW / 2 << "\" y=\"" << kH / 2 << "\" class=\"l\">no data</text></svg>"
      << "</figure>\n";
    return o.str();
  }
  y1 += 0.08 * (y1 - y0);
  const double pw = kW - kLeft - kRight, ph = kH - kTop - kBottom;
  auto py = [&](double y) { return kTop + (y1 - y) / (y1 - y0) * ph; };
  const double ys = niceStep(y1 - y0, 5);
  for (double y = std::ceil(y0 / ys) * ys; y <= y1 + 1e-9 * ys; y += ys) {
    o << "<line x1=\"" << kLeft << "\" x2=\"" << kW - kRight << "\" y1=\"" << num(py(y), 1)
      << "\" y2=\"" << num(py(y), 1) << "\" class=\"g\"/><text x=\"" << kLeft - 6 << "\" y=\""
      << num(py(y) + 4, 1) << "\" class=\"yt\">" << num(y, ys < 1 ? 1 : 0) << "</text>\n";
  }
  const double group = pw / static_cast<double>(categories.size());
  const double bar = 0.8 * group / static_cast<double>(std::max<std::size_t>(1, series.size()));
  for (std::size_t c = 0; c < categories.size(); ++c) {
    const double gx = kLeft + group * static_cast<double>(c) + 0.1 * group;
    for (std::size_t s = 0; s < series.size(); ++s) {
      const double v = c < series[s].second.size() ? series[s].second[c] : 0.0;
      if (!std::isfinite(v)) continue;
      const double top = py(std::max(v, 0.0)), bottom = py(std::min(v, 0.0));
      o << "<rect class=\"bar\" x=\"" << num(gx + bar * static_cast<double>(s), 1) << "\" y=\""
        << num(top, 1) << "\" width=\"" << num(bar * 0.92, 1) << "\" height=\""
        << num(bottom - top, 1) << "\" fill=\"" << colors[s % colors.size()] << "\"><title>"
        << escapeHtml(series[s].first) << ' ' << escapeHtml(categories[c]) << ": " << num(v, 1)
        << "</title></rect>\n";
    }
    o << "<text x=\"" << num(kLeft + group * (static_cast<double>(c) + 0.5), 1) << "\" y=\""
      << kH - kBottom + 16 << "\" class=\"xt\">" << escapeHtml(categories[c]) << "</text>\n";
  }
  o << "<rect x=\"" << kLeft << "\" y=\"" << kTop << "\" width=\"" << num(pw, 1) << "\" height=\""
    << num(ph, 1) << "\" class=\"f\"/>\n";
  o << "<text transform=\"translate(14," << num(kTop + ph / 2, 1) << ") rotate(-90)\" class=\"xt\">"
    << escapeHtml(ylabel) << "</text>\n";
  std::vector<std::pair<std::string, std::string>> items;
  for (std::size_t s = 0; s < series.size(); ++s) {
    items.emplace_back(series[s].first, colors[s % colors.size()]);
  }
  o << legend(items) << "</svg></figure>\n";
  return o.str();
}

Points forcePoints(const technique::Series& s) {
  std::vector<double> t(s.t_s.size());
  for (std::size_t i = 0; i < t.size(); ++i) t[i] = s.t_s[i] - s.t_s.front();
  return decimate(t, s.force_ref_n);
}

Points flexionPoints(const technique::Series& s) {
  std::vector<double> t(s.t_s.size()), a(s.t_s.size());
  for (std::size_t i = 0; i < t.size(); ++i) {
    t[i] = s.t_s[i] - s.t_s.front();
    a[i] = i < s.angles_rad.size() ? radToDeg(s.angles_rad[i][kFlexion]) : 0.0;
  }
  return decimate(t, a);
}

Points flat(double y, double x0, double x1) { return {{x0, y}, {x1, y}}; }

/// The mean overall score of the trials scored, and whether any was.
template <class Trial>
std::pair<double, bool> meanScored(const std::vector<Trial>& trials) {
  double sum = 0.0;
  std::size_t n = 0;
  for (const Trial& t : trials) {
    if (!t.samples.scored) continue;
    sum += t.score.overall;
    ++n;
  }
  return {n ? sum / static_cast<double>(n) : 0.0, n > 0};
}

std::string cell(const std::string& s) { return "<td>" + escapeHtml(s) + "</td>"; }

/// The table's samples cell: how many the trial has, or what the record lacks of it.
std::string samplesCell(const TrialSamples& ts) {
  if (ts.expected == 0) return cell("");
  if (ts.found == 0) return cell(ts.note());
  if (ts.missing() > 0) {
    return cell(std::to_string(ts.missing()) + " of " + std::to_string(ts.expected) +
                " samples missing");
  }
  return cell(std::to_string(ts.expected));
}

/// The rest of a row of a trial not scored.
std::string notScoredCells(int columns) {
  return "<td colspan=\"" + std::to_string(columns) + "\">not scored</td>";
}

/// The CSV's samples columns of a trial: samples_expected, samples_missing, note.
std::string samplesCsv(const TrialSamples& ts) {
  return std::to_string(ts.expected) + ',' + std::to_string(ts.missing()) + ',' +
         csvField(ts.note());
}

std::string signedNum(double v, int decimals) {
  if (std::abs(v) < 0.5 * std::pow(10.0, -decimals)) v = 0.0;  // "+0.0", not "-0.0"
  char buf[64];
  std::snprintf(buf, sizeof buf, "%+.*f", decimals, v);
  return buf;
}

std::string pageHead(const std::string& title, const std::string& subtitle) {
  std::ostringstream o;
  o << "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\n<title>"
    << escapeHtml(title) << "</title>\n<style>\n"
    << "body{font-family:sans-serif;margin:24px;color:#222;max-width:800px}\n"
    << "table{border-collapse:collapse;margin:8px 0 16px}td,th{border:1px solid #ccc;"
       "padding:3px 8px;text-align:right;font-size:13px}th{background:#f0f0f0}\n"
    << "td:first-child,th:first-child{text-align:left}figure{margin:8px 0}\n"
    << ".t{font-size:14px;font-weight:bold}.l,.xt,.yt{font-size:11px}.xt{text-anchor:middle}"
       ".yt{text-anchor:end}.g{stroke:#e4e4e4}.f{fill:none;stroke:#999}\n"
    << "</style></head><body>\n";
  o << "<h1>" << escapeHtml(title) << "</h1>\n";
  if (!subtitle.empty()) o << "<p>" << escapeHtml(subtitle) << "</p>\n";
  return o.str();
}

/// A figure per trial (from 0) against its target (dashed).
std::string perTrialChart(const std::string& id, const std::string& title,
                          const std::string& ylabel, const std::vector<std::string>& labels,
                          double target, const Points& values) {
  Chart c;
  c.id = id;
  c.title = title;
  c.ylabel = ylabel;
  c.xlabel = "trial";
  c.categories = labels;
  c.y_from_zero = true;
  const double xe = static_cast<double>(labels.size()) - 0.5;
  c.lines.push_back({flat(target, -0.5, xe), kTargetColor, "target", 1.2, true, false});
  c.lines.push_back({values, kTrialColor, "trial", 1.5, false, true});
  return svgChart(c);
}

/// The scores per trial, 0-100.
std::string scoresChart(const std::vector<std::string>& labels, const Points& scores) {
  Chart sc;
  sc.id = "scores";
  sc.title = "Score per trial";
  sc.ylabel = "score (0-100)";
  sc.xlabel = "trial";
  sc.categories = labels;
  sc.y_min = 0.0;
  sc.y_max = 100.0;
  sc.lines.push_back({scores, kTrialColor, "score", 1.5, false, true});
  return svgChart(sc);
}

/// The learning curve: the earlier lessons' mean scores, then this one's (when it has any).
std::string learningChart(const std::vector<std::pair<std::string, double>>& history, double mean,
                          bool any) {
  Chart lc;
  lc.id = "learning";
  lc.title = "Learning curve: mean score per lesson";
  lc.ylabel = "score (0-100)";
  lc.xlabel = "lesson";
  lc.y_min = 0.0;
  lc.y_max = 100.0;
  Points curve;
  for (const auto& [label, value] : history) {
    curve.emplace_back(static_cast<double>(lc.categories.size()), value);
    lc.categories.push_back(label);
  }
  if (any) {
    curve.emplace_back(static_cast<double>(lc.categories.size()), mean);
    lc.categories.push_back("this lesson");
  }
  lc.lines.push_back({curve, kTrialColor, "mean score", 1.5, false, true});
  return svgChart(lc);
}

}  // namespace

std::string TrialSamples::note() const {
  if (expected == 0) return scored ? "" : "not scored";
  const std::string of = " of " + std::to_string(expected) + " samples";
  if (found == 0) return "not in the record (0" + of + ")";
  const std::string gap = missing() > 0 ? std::to_string(missing()) + of + " missing" : "";
  if (scored) return gap;
  if (!why_not.empty()) return "not scored: " + (gap.empty() ? why_not : gap + ": " + why_not);
  return "not scored: " + (gap.empty() ? std::string("under 2 valid samples") : gap);
}

std::vector<std::pair<double, double>> decimate(const std::vector<double>& x,
                                                const std::vector<double>& y,
                                                std::size_t max_points) {
  const std::size_t n = std::min(x.size(), y.size());
  Points out;
  if (n <= max_points || max_points < 2) {
    out.reserve(n);
    for (std::size_t i = 0; i < n; ++i) out.emplace_back(x[i], y[i]);
    return out;
  }
  const std::size_t buckets = max_points / 2;
  out.reserve(2 * buckets);
  for (std::size_t b = 0; b < buckets; ++b) {
    const std::size_t lo = b * n / buckets, hi = (b + 1) * n / buckets;
    if (lo >= hi) continue;
    std::size_t imin = lo, imax = lo;
    for (std::size_t i = lo; i < hi; ++i) {
      if (y[i] < y[imin]) imin = i;
      if (y[i] > y[imax]) imax = i;
    }
    const std::size_t a = std::min(imin, imax), c = std::max(imin, imax);
    out.emplace_back(x[a], y[a]);
    if (c != a) out.emplace_back(x[c], y[c]);
  }
  return out;
}

std::string renderReportHtml(const ReportInput& in) {
  const technique::Targets& tg = in.targets;
  std::ostringstream o;
  o << pageHead(in.title, in.subtitle);

  o << "<h2>Targets (the demonstration)</h2>\n<table><tr><th>band</th><th>peak</th><th>trough"
    << "</th><th>mean</th><th>frequency</th><th>amplitude</th><th>jerk</th><th>oscillations</th>"
    << "</tr><tr>" << cell(num(tg.band_min_n, 1) + "–" + num(tg.band_max_n, 1) + " N")
    << cell(num(tg.force_peak_n, 2) + " N") << cell(num(tg.force_trough_n, 2) + " N")
    << cell(num(tg.force_mean_n, 2) + " N") << cell(num(tg.frequency_hz, 2) + " Hz")
    << cell(num(tg.amplitude_deg, 1) + " deg") << cell(num(tg.jerk, 2))
    << cell(std::to_string(tg.oscillations)) << "</tr></table>\n";

  o << "<h2>Trials</h2>\n<table><tr><th>trial</th><th>samples</th><th>oscillations</th>"
    << "<th>peak N</th><th>mean N</th><th>frequency Hz</th><th>amplitude deg</th>"
    << "<th>in band</th><th>path deg</th><th>jerk</th><th>score</th></tr>\n";
  for (const ReportTrial& t : in.trials) {
    o << "<tr>" << cell(t.label) << samplesCell(t.samples);
    if (!t.samples.scored) {
      o << notScoredCells(9) << "</tr>\n";
      continue;
    }
    const technique::TrialScore& s = t.score;
    const technique::TrialFigures& f = s.figures;
    o << cell(std::to_string(f.oscillations.size()))
      << cell(num(f.force_peak_n, 2) + " (" + signedNum(s.peak_error_n, 2) + ")")
      << cell(num(f.force_mean_n, 2) + " (" + signedNum(s.mean_error_n, 2) + ")")
      << cell(num(f.frequency_spectrum_hz, 2) + " (" + signedNum(s.frequency_error_hz, 2) + ")")
      << cell(num(f.amplitude_deg, 1) + " (" + signedNum(s.amplitude_error_deg, 1) + ")")
      << cell(num(100.0 * s.time_in_band, 0) + " %") << cell(num(s.path_error_deg, 2))
      << cell(signedNum(s.jerk_delta, 2)) << cell(num(s.overall, 0)) << "</tr>\n";
  }
  o << "</table>\n";

  const Points demo_force = forcePoints(in.demonstration);
  const Points demo_flex = flexionPoints(in.demonstration);
  o << "<h2>Force and flexion per trial</h2>\n";
  for (std::size_t i = 0; i < in.trials.size(); ++i) {
    const ReportTrial& t = in.trials[i];
    if (!t.samples.scored) {
      o << "<p>" << escapeHtml(t.label + ": " + t.samples.note()) << ".</p>\n";
      continue;
    }
    Chart force;
    force.id = "force-" + std::to_string(i);
    force.title = t.label + ": applied force";
    force.xlabel = "time (s)";
    force.ylabel = "force (N, reference scale)";
    force.shades.push_back({tg.band_min_n, tg.band_max_n, kBandColor, "band"});
    force.lines.push_back({demo_force, kDemoColor, "demonstration", 1.2, false, false});
    force.lines.push_back({forcePoints(t.series), kTrialColor, "trial", 1.5, false, false});
    o << svgChart(force);
    Chart flex;
    flex.id = "flexion-" + std::to_string(i);
    flex.title = t.label + ": flexion";
    flex.xlabel = "time (s)";
    flex.ylabel = "flexion (deg)";
    flex.lines.push_back({demo_flex, kDemoColor, "demonstration", 1.2, false, false});
    flex.lines.push_back({flexionPoints(t.series), kTrialColor, "trial", 1.5, false, false});
    o << svgChart(flex);
  }
  if (in.trials.empty()) o << "<p>No trials.</p>\n";

  std::vector<std::string> labels;
  Points freq, scores;
  for (std::size_t i = 0; i < in.trials.size(); ++i) {
    labels.push_back(in.trials[i].label);
    if (!in.trials[i].samples.scored) continue;
    freq.emplace_back(static_cast<double>(i), in.trials[i].score.figures.frequency_spectrum_hz);
    scores.emplace_back(static_cast<double>(i), in.trials[i].score.overall);
  }
  o << "<h2>Over the lesson</h2>\n"
    << perTrialChart("frequency", "Frequency per trial", "frequency (Hz)", labels, tg.frequency_hz,
                     freq);

  o << scoresChart(labels, scores);

  std::vector<std::string> dirs;
  std::vector<double> before, after;
  for (const ReportRange& r : in.ranges) {
    dirs.push_back(r.direction);
    before.push_back(r.baseline_deg);
    after.push_back(r.after_deg);
  }
  o << "<h2>Range of motion</h2>\n"
    << svgBars("ranges", "Range per direction, before and after", "range (deg)", dirs,
               {{"before", before}, {"after", after}}, {kDemoColor, kAfterColor});
  if (!in.ranges.empty()) {
    o << "<table><tr><th>direction</th><th>before deg</th><th>after deg</th><th>change</th></tr>\n";
    for (const ReportRange& r : in.ranges) {
      o << "<tr>" << cell(r.direction) << cell(num(r.baseline_deg, 1)) << cell(num(r.after_deg, 1))
        << cell(signedNum(r.after_deg - r.baseline_deg, 1)) << "</tr>\n";
    }
    o << "</table>\n";
  }

  const auto [mean, any] = meanScored(in.trials);
  o << "<h2>Learning curve</h2>\n" << learningChart(in.history, mean, any);
  o << "</body></html>\n";
  return o.str();
}

namespace {

/// The pads' normal force over a trial: both fingers' mean, reference scale.
Points pressPoints(const technique::MassageSeries& s) {
  std::vector<double> t(s.t_s.size()), f(s.t_s.size());
  for (std::size_t i = 0; i < t.size(); ++i) {
    t[i] = s.t_s[i] - s.t_s.front();
    f[i] = 0.5 * (s.normal_ref_n[kThumb][i] + s.normal_ref_n[kIndex][i]);
  }
  return decimate(t, f);
}

/// The contact point (the thimbles' midpoint) on the web, millimetres, after `settle_s`:
/// every n-th point so at most kMaxPlotPoints remain (a path, not a signal: no min/max).
Points pathPoints(const technique::MassageSeries& s, const TissueModel& web, double settle_s) {
  Points out;
  const std::size_t n = s.t_s.size();
  const std::size_t stride = std::max<std::size_t>(1, n / kMaxPlotPoints + 1);
  for (std::size_t i = 0; i < n; i += stride) {
    if (s.t_s[i] - s.t_s.front() < settle_s) continue;
    const Vec3 w = web.toWeb(0.5 * (s.position_m[kThumb][i] + s.position_m[kIndex][i]));
    out.emplace_back(1000.0 * w.x(), 1000.0 * w.y());
  }
  return out;
}

}  // namespace

std::string renderMassageReportHtml(const MassageReportInput& in) {
  const technique::MassageTargets& tg = in.targets;
  const TissueModel web(in.web);
  std::ostringstream o;
  o << pageHead(in.title, in.subtitle);
  o << "<h2>Targets (the demonstration)</h2>\n<table><tr><th>press</th><th>band</th>"
    << "<th>spread</th><th>frequency</th><th>radius</th><th>circularity</th>"
    << "<th>tangential/normal</th><th>laps</th></tr><tr>" << cell(num(tg.normal_mean_n, 2) + " N")
    << cell(num(tg.band_min_n, 1) + "–" + num(tg.band_max_n, 1) + " N")
    << cell(num(tg.normal_sd_n, 2) + " N") << cell(num(tg.frequency_hz, 2) + " Hz")
    << cell(num(1000.0 * tg.radius_m, 1) + " mm") << cell(num(tg.circularity, 2))
    << cell(num(tg.tangential_ratio, 2)) << cell(num(tg.laps, 0)) << "</tr></table>\n";

  o << "<h2>Trials</h2>\n<table><tr><th>trial</th><th>samples</th><th>press N</th>"
    << "<th>spread N</th><th>in band</th><th>frequency Hz</th><th>radius mm</th>"
    << "<th>circularity</th><th>tangential/normal</th><th>laps</th><th>score</th></tr>\n";
  for (const MassageReportTrial& t : in.trials) {
    o << "<tr>" << cell(t.label) << samplesCell(t.samples);
    if (!t.samples.scored) {
      o << notScoredCells(9) << "</tr>\n";
      continue;
    }
    const technique::MassageScore& s = t.score;
    const technique::MassageFigures& f = s.figures;
    o << cell(num(f.normal_mean_n, 2) + " (" + signedNum(s.normal_error_n, 2) + ")")
      << cell(num(f.normal_sd_n, 2) + " (" + signedNum(s.spread_delta_n, 2) + ")")
      << cell(num(100.0 * f.time_in_band, 0) + " %")
      << cell(num(f.frequency_hz, 2) + " (" + signedNum(s.frequency_error_hz, 2) + ")")
      << cell(num(1000.0 * f.radius_m, 1) + " (x" + num(s.radius_ratio, 2) + ")")
      << cell(num(f.circularity, 2) + " (" + signedNum(s.circularity_delta, 2) + ")")
      << cell(num(f.tangential_ratio, 2) + " (" + signedNum(s.tangential_ratio_error, 2) + ")")
      << cell(num(f.laps, 0)) << cell(num(s.overall, 0)) << "</tr>\n";
  }
  o << "</table>\n";

  const Points demo_press = pressPoints(in.demonstration);
  const Points demo_path = pathPoints(in.demonstration, web, 1.0);
  o << "<h2>Press and circle per trial</h2>\n";
  for (std::size_t i = 0; i < in.trials.size(); ++i) {
    const MassageReportTrial& t = in.trials[i];
    if (!t.samples.scored) {
      o << "<p>" << escapeHtml(t.label + ": " + t.samples.note()) << ".</p>\n";
      continue;
    }
    Chart press;
    press.id = "press-" + std::to_string(i);
    press.title = t.label + ": the pads' normal force";
    press.xlabel = "time (s)";
    press.ylabel = "force (N, reference scale)";
    press.y_from_zero = true;
    press.shades.push_back({tg.band_min_n, tg.band_max_n, kBandColor, "band"});
    press.lines.push_back({demo_press, kDemoColor, "demonstration", 1.2, false, false});
    press.lines.push_back({pressPoints(t.series), kTrialColor, "trial", 1.5, false, false});
    o << svgChart(press);
    Chart path;
    path.id = "path-" + std::to_string(i);
    path.title = t.label + ": the contact point on the web";
    path.xlabel = "x on the web (mm)";
    path.ylabel = "y on the web (mm)";
    path.lines.push_back({demo_path, kDemoColor, "demonstration", 1.0, false, false});
    path.lines.push_back({pathPoints(t.series, web, 1.0), kTrialColor, "trial", 1.2, false, false});
    o << svgChart(path);
  }
  if (in.trials.empty()) o << "<p>No trials.</p>\n";

  std::vector<std::string> labels;
  Points freq, radius, scores;
  for (std::size_t i = 0; i < in.trials.size(); ++i) {
    const auto x = static_cast<double>(i);
    labels.push_back(in.trials[i].label);
    if (!in.trials[i].samples.scored) continue;
    freq.emplace_back(x, in.trials[i].score.figures.frequency_hz);
    radius.emplace_back(x, 1000.0 * in.trials[i].score.figures.radius_m);
    scores.emplace_back(x, in.trials[i].score.overall);
  }
  o << "<h2>Over the lesson</h2>\n"
    << perTrialChart("frequency", "Laps per second per trial", "frequency (Hz)", labels,
                     tg.frequency_hz, freq)
    << perTrialChart("radius", "Circle radius per trial", "radius (mm)", labels,
                     1000.0 * tg.radius_m, radius);
  o << scoresChart(labels, scores);

  const auto [mean, any] = meanScored(in.trials);
  o << "<h2>Learning curve</h2>\n" << learningChart(in.history, mean, any);
  o << "</body></html>\n";
  return o.str();
}

std::string renderMassageScoresCsv(const MassageReportInput& in) {
  std::ostringstream o;
  o << "trial,label,normal_mean_n,normal_sd_n,time_in_band,frequency_hz,radius_m,circularity,"
       "tangential_ratio,laps,duration_s,normal_error_n,spread_delta_n,frequency_error_hz,"
       "radius_ratio,circularity_delta,tangential_ratio_error,centre_offset_m,overall,"
       "samples_expected,samples_missing,note\n";
  for (std::size_t i = 0; i < in.trials.size(); ++i) {
    const TrialSamples& ts = in.trials[i].samples;
    if (!ts.scored) {
      o << i << ',' << csvField(in.trials[i].label) << std::string(18, ',')  // 17 figures empty
        << samplesCsv(ts) << '\n';
      continue;
    }
    const technique::MassageScore& s = in.trials[i].score;
    const technique::MassageFigures& f = s.figures;
    o << i << ',' << csvField(in.trials[i].label) << ',' << num(f.normal_mean_n, 4) << ','
      << num(f.normal_sd_n, 4) << ',' << num(f.time_in_band, 4) << ',' << num(f.frequency_hz, 5)
      << ',' << num(f.radius_m, 6) << ',' << num(f.circularity, 4) << ','
      << num(f.tangential_ratio, 4) << ',' << num(f.laps, 2) << ',' << num(f.duration_s, 3) << ','
      << num(s.normal_error_n, 4) << ',' << num(s.spread_delta_n, 4) << ','
      << num(s.frequency_error_hz, 5) << ',' << num(s.radius_ratio, 4) << ','
      << num(s.circularity_delta, 4) << ',' << num(s.tangential_ratio_error, 4) << ','
      << num(s.centre_offset_m, 6) << ',' << num(s.overall, 2) << ',' << samplesCsv(ts) << '\n';
  }
  return o.str();
}

std::string renderScoresCsv(const ReportInput& in) {
  std::ostringstream o;
  o << "trial,label,oscillations,force_peak_n,force_trough_n,force_mean_n,frequency_hz,"
       "frequency_zc_hz,amplitude_deg,time_in_band,path_error_deg,jerk,duration_s,"
       "peak_error_n,trough_error_n,mean_error_n,frequency_error_hz,amplitude_error_deg,"
       "jerk_delta,overall,samples_expected,samples_missing,note\n";
  for (std::size_t i = 0; i < in.trials.size(); ++i) {
    const TrialSamples& ts = in.trials[i].samples;
    if (!ts.scored) {
      o << i << ',' << csvField(in.trials[i].label) << std::string(19, ',')  // 18 figures empty
        << samplesCsv(ts) << '\n';
      continue;
    }
    const technique::TrialScore& s = in.trials[i].score;
    const technique::TrialFigures& f = s.figures;
    o << i << ',' << csvField(in.trials[i].label) << ',' << f.oscillations.size() << ','
      << num(f.force_peak_n, 4) << ',' << num(f.force_trough_n, 4) << ',' << num(f.force_mean_n, 4)
      << ',' << num(f.frequency_spectrum_hz, 5) << ',' << num(f.frequency_zc_hz, 5) << ','
      << num(f.amplitude_deg, 4) << ',' << num(s.time_in_band, 4) << ',' << num(s.path_error_deg, 4)
      << ',' << num(f.jerk, 4) << ',' << num(f.duration_s, 3) << ',' << num(s.peak_error_n, 4)
      << ',' << num(s.trough_error_n, 4) << ',' << num(s.mean_error_n, 4) << ','
      << num(s.frequency_error_hz, 5) << ',' << num(s.amplitude_error_deg, 4) << ','
      << num(s.jerk_delta, 4) << ',' << num(s.overall, 2) << ',' << samplesCsv(ts) << '\n';
  }
  return o.str();
}

std::string renderOscillationsCsv(const ReportInput& in) {
  std::ostringstream o;
  o << "trial,label,oscillation,t_start_s,t_end_s,peak_n,trough_n,mean_n,frequency_hz,"
       "amplitude_deg\n";
  for (std::size_t i = 0; i < in.trials.size(); ++i) {
    if (!in.trials[i].samples.scored) continue;
    const auto& osc = in.trials[i].score.figures.oscillations;
    for (std::size_t k = 0; k < osc.size(); ++k) {
      const technique::Oscillation& x = osc[k];
      o << i << ',' << csvField(in.trials[i].label) << ',' << k << ',' << num(x.t_start_s, 4) << ','
        << num(x.t_end_s, 4) << ',' << num(x.peak_n, 4) << ',' << num(x.trough_n, 4) << ','
        << num(x.mean_n, 4) << ',' << num(x.frequency_hz, 5) << ',' << num(x.amplitude_deg, 4)
        << '\n';
    }
  }
  return o.str();
}

}  // namespace telehand::records
