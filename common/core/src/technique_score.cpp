#include "telehand/core/technique_score.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <complex>
#include <cstdio>
#include <limits>

#include "telehand/core/joint_model.h"
#include "telehand/core/thimble.h"

namespace telehand::technique {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kSqrt2 = 1.4142135623730951;
constexpr double kSpectrumMinHz = 0.3;
constexpr double kSpectrumMaxHz = 10.0;

/// 2nd-order Butterworth low-pass by the bilinear transform (cutoff prewarped).
struct Biquad {
  double b0 = 1, b1 = 0, b2 = 0, a1 = 0, a2 = 0;
};

Biquad butterworth(double cutoff_hz, double dt) noexcept {
  // Keep the cutoff below Nyquist at coarse sample intervals.
  const double fc = std::min(cutoff_hz, 0.45 / dt);
  const double k = std::tan(kPi * fc * dt);
  const double norm = 1.0 / (1.0 + kSqrt2 * k + k * k);
  Biquad q;
  q.b0 = k * k * norm;
  q.b1 = 2.0 * q.b0;
  q.b2 = q.b0;
  q.a1 = 2.0 * (k * k - 1.0) * norm;
  q.a2 = (1.0 - kSqrt2 * k + k * k) * norm;
  return q;
}

/// Group delay of the Butterworth at low frequency: sqrt(2) / (2 pi fc).
double butterworthDelayS(double cutoff_hz) { return kSqrt2 / (2.0 * kPi * cutoff_hz); }

/// Forward then backward (zero phase), each pass started at rest on its first value.
std::vector<double> filtfilt(const std::vector<double>& x, double cutoff_hz, double dt) {
  std::vector<double> y(x.size());
  if (x.empty()) return y;
  const Biquad q = butterworth(cutoff_hz, dt);
  auto pass = [&q](auto first, auto last, auto out) {
    double x1 = *first, x2 = *first, y1 = *first, y2 = *first;
    for (; first != last; ++first, ++out) {
      const double v = q.b0 * *first + q.b1 * x1 + q.b2 * x2 - q.a1 * y1 - q.a2 * y2;
      x2 = x1;
      x1 = *first;
      y2 = y1;
      y1 = v;
      *out = v;
    }
  };
  pass(x.begin(), x.end(), y.begin());
  std::vector<double> tmp(y.rbegin(), y.rend());
  pass(tmp.begin(), tmp.end(), y.rbegin());
  return y;
}

double medianInterval(std::span<const double> t) {
  if (t.size() < 2) return 1e-3;
  std::vector<double> d(t.size() - 1);
  for (std::size_t i = 1; i < t.size(); ++i) d[i - 1] = t[i] - t[i - 1];
  std::nth_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(d.size() / 2), d.end());
  const double m = d[d.size() / 2];
  return m > 0.0 ? m : 1e-3;
}

/// In-place iterative radix-2 FFT; a.size() is a power of two.
void fft(std::vector<std::complex<double>>& a) {
  const std::size_t n = a.size();
  for (std::size_t i = 1, j = 0; i < n; ++i) {
    std::size_t bit = n >> 1;
    for (; j & bit; bit >>= 1) j ^= bit;
    j ^= bit;
    if (i < j) std::swap(a[i], a[j]);
  }
  for (std::size_t len = 2; len <= n; len <<= 1) {
    const double ang = -2.0 * kPi / static_cast<double>(len);
    const std::complex<double> wl(std::cos(ang), std::sin(ang));
    for (std::size_t i = 0; i < n; i += len) {
      std::complex<double> w(1.0, 0.0);
      for (std::size_t k = 0; k < len / 2; ++k) {
        const std::complex<double> u = a[i + k], v = a[i + k + len / 2] * w;
        a[i + k] = u + v;
        a[i + k + len / 2] = u - v;
        w *= wl;
      }
    }
  }
}

/// A part of x at the times t as samples dt apart from its first time (linear interpolation).
/// A loop that stalls records fewer samples than the time that passed (each tick reads the
/// device once, however many of its steps went by), and read as if dt apart they would run
/// faster than they did. The part as it is where its samples already are dt apart (within
/// 5 %), and where their times cannot be read as time: going back (a sender's clock stepped,
/// or a hostile one), or spanning more than kMaxGridShare times their count in periods (most
/// of the device's steps unread), which would also cost that much more to transform.
std::vector<double> onUniformGrid(const std::vector<double>& x, const std::vector<double>& t,
                                  const Stretch& p, double dt) {
  constexpr double kMaxGridShare = 4.0;
  const auto as_is = [&] {
    return std::vector<double>(x.begin() + static_cast<std::ptrdiff_t>(p.begin),
                               x.begin() + static_cast<std::ptrdiff_t>(p.end));
  };
  const std::size_t count = p.end - p.begin;
  if (count < 2) return as_is();
  bool uniform = true, increasing = true;
  for (std::size_t i = p.begin + 1; i < p.end; ++i) {
    uniform = uniform && std::abs(t[i] - t[i - 1] - dt) <= 0.05 * dt;
    increasing = increasing && t[i] >= t[i - 1];
  }
  const double t0 = t[p.begin], span = t[p.end - 1] - t0;
  const double periods = span / dt;
  if (uniform || !increasing || !(dt > 0.0) || !std::isfinite(periods) ||
      periods + 1.0 > kMaxGridShare * static_cast<double>(count))
    return as_is();
  const auto m = static_cast<std::size_t>(std::floor(periods)) + 1;
  std::vector<double> out(m);
  std::size_t j = p.begin;
  for (std::size_t k = 0; k < m; ++k) {
    const double tk = t0 + static_cast<double>(k) * dt;
    while (j + 2 < p.end && t[j + 1] <= tk) ++j;
    const double d = t[j + 1] - t[j];
    const double f = d > 0.0 ? std::clamp((tk - t[j]) / d, 0.0, 1.0) : 0.0;
    out[k] = x[j] + f * (x[j + 1] - x[j]);
  }
  return out;
}

/// Periodogram peak of x (at the times t, read dt apart: onUniformGrid) over `parts` in
/// [lo, hi] Hz: per part, cubic trend removed, Hann window, zero padded to >= 8x the longest
/// part; the parts' powers summed, each times (total length / its length), so that each
/// counts by its length (a coherent oscillation's power grows with the square of the
/// length); a parabola through the log power of the peak bin and its neighbours. Parts under
/// 16 samples are left out. 0 when none is left or the sum is flat.
double spectrumPeakHz(const std::vector<double>& x_in, const std::vector<double>& t,
                      const std::vector<Stretch>& parts, double dt, double lo, double hi) {
  std::vector<std::vector<double>> grid;
  for (const Stretch& p : parts) grid.push_back(onUniformGrid(x_in, t, p, dt));
  std::size_t longest = 0, total = 0;
  for (const auto& g : grid) {
    if (g.size() < 16) continue;
    longest = std::max(longest, g.size());
    total += g.size();
  }
  if (longest == 0) return 0.0;
  std::size_t n = 1;
  while (n < 8 * longest) n <<= 1;
  std::vector<double> power(n / 2 + 1, 0.0);
  std::vector<std::complex<double>> a(n);
  for (const auto& x : grid) {
    const std::size_t m = x.size();
    if (m < 16) continue;
    // Cubic least-squares trend on u in [-1, 1].
    Eigen::Matrix4d ata = Eigen::Matrix4d::Zero();
    Eigen::Vector4d atb = Eigen::Vector4d::Zero();
    std::vector<double> u(m);
    for (std::size_t i = 0; i < m; ++i) {
      u[i] = 2.0 * static_cast<double>(i) / static_cast<double>(m - 1) - 1.0;
      const Eigen::Vector4d row(1.0, u[i], u[i] * u[i], u[i] * u[i] * u[i]);
      ata += row * row.transpose();
      atb += row * x[i];
    }
    const Eigen::Vector4d c = ata.ldlt().solve(atb);
    std::fill(a.begin(), a.end(), std::complex<double>(0.0, 0.0));
    for (std::size_t i = 0; i < m; ++i) {
      const double trend = c[0] + u[i] * (c[1] + u[i] * (c[2] + u[i] * c[3]));
      const double w =
          0.5 - 0.5 * std::cos(2.0 * kPi * static_cast<double>(i) / static_cast<double>(m - 1));
      a[i] = {(x[i] - trend) * w, 0.0};
    }
    fft(a);
    const double weight = static_cast<double>(total) / static_cast<double>(m);
    for (std::size_t k = 0; k < power.size(); ++k) power[k] += weight * std::norm(a[k]);
  }
  const double df = 1.0 / (static_cast<double>(n) * dt);
  const std::size_t k_lo = std::max<std::size_t>(1, static_cast<std::size_t>(std::ceil(lo / df)));
  const std::size_t k_hi = std::min(n / 2 - 1, static_cast<std::size_t>(std::floor(hi / df)));
  if (k_lo >= k_hi) return 0.0;
  std::size_t best = k_lo;
  double best_p = -1.0;
  for (std::size_t k = k_lo; k <= k_hi; ++k) {
    const double p = power[k];
    if (p > best_p) {
      best_p = p;
      best = k;
    }
  }
  if (!(best_p > 0.0)) return 0.0;
  const double l0 = std::log(power[best - 1] + 1e-300), l1 = std::log(best_p),
               l2 = std::log(power[best + 1] + 1e-300);
  const double den = l0 - 2.0 * l1 + l2;
  const double delta = den < 0.0 ? std::clamp(0.5 * (l0 - l2) / den, -0.5, 0.5) : 0.0;
  return (static_cast<double>(best) + delta) * df;
}

/// Upward zero crossings of the detrended, zero-phase low-passed force after index i0, within
/// each of `parts` (the moving average and the crossings do not reach across a gap): the
/// parts' crossings - 1 summed over the parts' first-to-last crossing times summed. 0 when no
/// part has two.
double zeroCrossingHz(const std::vector<double>& t, const std::vector<double>& lp,
                      const std::vector<Stretch>& parts, std::size_t i0, double dt,
                      double period_s) {
  if (!(period_s > 0.0)) return 0.0;
  const std::size_t w =
      std::max<std::size_t>(1, static_cast<std::size_t>(std::lround(period_s / dt)));
  const std::size_t half = w / 2;
  double crossings = 0.0, span = 0.0;
  for (const Stretch& p : parts) {
    const std::size_t n = p.end - p.begin;
    if (n < 4 || n < w + 2) continue;
    // Prefix sums for a centred one-period moving average.
    std::vector<double> pre(n + 1, 0.0);
    for (std::size_t i = 0; i < n; ++i) pre[i + 1] = pre[i] + lp[p.begin + i];
    const std::size_t first = std::max(i0, p.begin + half), last = p.end - (w - half);
    if (first + 2 >= last) continue;
    std::vector<double> d(last - first);
    double ss = 0.0;
    for (std::size_t i = first; i < last; ++i) {
      const std::size_t j = i - p.begin;
      const double ma = (pre[j - half + w] - pre[j - half]) / static_cast<double>(w);
      d[i - first] = lp[i] - ma;
      ss += d[i - first] * d[i - first];
    }
    const double h = std::max(0.05, 0.25 * std::sqrt(ss / static_cast<double>(d.size())));
    bool armed = false;
    int count = 0;
    double t_first = 0.0, t_last = 0.0;
    for (std::size_t k = 1; k < d.size(); ++k) {
      if (d[k] < -h) armed = true;
      if (armed && d[k - 1] < 0.0 && d[k] >= 0.0) {
        const double ta = t[first + k - 1], tb = t[first + k];
        const double tc = ta + (tb - ta) * (-d[k - 1]) / (d[k] - d[k - 1]);
        if (count == 0) t_first = tc;
        t_last = tc;
        ++count;
        armed = false;
      }
    }
    if (count < 2 || !(t_last > t_first)) continue;
    crossings += static_cast<double>(count - 1);
    span += t_last - t_first;
  }
  if (!(crossings > 0.0) || !(span > 0.0)) return 0.0;
  return crossings / span;
}

/// Each part's stretch of x low-passed with zero phase (filtfilt), nothing across a gap.
std::vector<double> filtfiltParts(const std::vector<double>& x, const std::vector<Stretch>& parts,
                                  double cutoff_hz, double dt) {
  if (parts.size() == 1 && parts.front().begin == 0 && parts.front().end == x.size()) {
    return filtfilt(x, cutoff_hz, dt);
  }
  std::vector<double> y(x.size(), 0.0);
  for (const Stretch& p : parts) {
    const std::vector<double> part(x.begin() + static_cast<std::ptrdiff_t>(p.begin),
                                   x.begin() + static_cast<std::ptrdiff_t>(p.end));
    const std::vector<double> lp = filtfilt(part, cutoff_hz, dt);
    std::copy(lp.begin(), lp.end(), y.begin() + static_cast<std::ptrdiff_t>(p.begin));
  }
  return y;
}

/// Angles at relative time tq, linear between samples (clamped at the ends).
Vec3 anglesAt(const std::vector<double>& t, const std::vector<Vec3>& a, double tq) {
  if (tq <= t.front()) return a.front();
  if (tq >= t.back()) return a.back();
  const auto it = std::upper_bound(t.begin(), t.end(), tq);
  const std::size_t j = static_cast<std::size_t>(it - t.begin());
  const double u = (tq - t[j - 1]) / (t[j] - t[j - 1]);
  return a[j - 1] + u * (a[j] - a[j - 1]);
}

using Path = std::array<Vec3, kPathPoints>;

/// One oscillation's angles at kPathPoints phases over its own period.
Path resample(const std::vector<double>& t, const std::vector<Vec3>& a, const Oscillation& o) {
  Path p;
  const double period = o.t_end_s - o.t_start_s;
  for (int k = 0; k < kPathPoints; ++k) {
    p[static_cast<std::size_t>(k)] = anglesAt(t, a, o.t_start_s + period * k / kPathPoints);
  }
  return p;
}

/// DTW of two paths (Sakoe-Chiba band kPathBand), Euclidean distance in degrees: RMS along
/// the warping path.
double dtwRmsDeg(const Path& x, const std::vector<Vec3>& y) {
  constexpr int n = kPathPoints;
  std::array<std::array<double, n>, n> cost;
  std::array<std::array<int, n>, n> steps;
  for (auto& row : cost) row.fill(kInf);
  for (int i = 0; i < n; ++i) {
    for (int j = std::max(0, i - kPathBand); j <= std::min(n - 1, i + kPathBand); ++j) {
      const double d =
          radToDeg(1.0) * radToDeg(1.0) *
          (x[static_cast<std::size_t>(i)] - y[static_cast<std::size_t>(j)]).squaredNorm();
      double best = 0.0;
      int len = 0;
      if (i > 0 || j > 0) {
        best = kInf;
        auto consider = [&](int a, int b) {
          if (a < 0 || b < 0) return;
          const double c = cost[static_cast<std::size_t>(a)][static_cast<std::size_t>(b)];
          if (c < best) {
            best = c;
            len = steps[static_cast<std::size_t>(a)][static_cast<std::size_t>(b)];
          }
        };
        consider(i - 1, j - 1);
        consider(i - 1, j);
        consider(i, j - 1);
      }
      cost[static_cast<std::size_t>(i)][static_cast<std::size_t>(j)] = best + d;
      steps[static_cast<std::size_t>(i)][static_cast<std::size_t>(j)] = len + 1;
    }
  }
  const double total = cost[n - 1][n - 1];
  return std::sqrt(total / steps[n - 1][n - 1]);
}

double meanPathError(const Series& s, const std::vector<double>& rel_t,
                     const std::vector<Oscillation>& osc, const std::vector<Vec3>& path) {
  if (osc.empty() || path.size() != static_cast<std::size_t>(kPathPoints)) return 0.0;
  double sum = 0.0;
  for (const Oscillation& o : osc) sum += dtwRmsDeg(resample(rel_t, s.angles_rad, o), path);
  return sum / static_cast<double>(osc.size());
}

std::vector<double> relativeTimes(const Series& s) {
  std::vector<double> t(s.t_s.size());
  for (std::size_t i = 0; i < t.size(); ++i) t[i] = s.t_s[i] - s.t_s.front();
  return t;
}

double signedOr(double v) { return std::isfinite(v) ? v : 0.0; }

/// v, or 0 when it prints as zero at `decimals` (no "-0.0" in a line).
double tidy(double v, int decimals) {
  return std::abs(v) < 0.5 * std::pow(10.0, -decimals) ? 0.0 : v;
}

}  // namespace

std::vector<Stretch> stretchesOf(std::span<const double> t_s) {
  std::vector<Stretch> out;
  if (t_s.empty()) return out;
  const double limit = std::max(kGapIntervals * medianInterval(t_s), kMinGapS);
  Stretch cur;
  for (std::size_t i = 1; i < t_s.size(); ++i) {
    if (!(t_s[i] - t_s[i - 1] <= limit)) {
      cur.end = i;
      out.push_back(cur);
      cur.begin = i;
    }
  }
  cur.end = t_s.size();
  out.push_back(cur);
  return out;
}

std::vector<Stretch> stretchesFrom(const std::vector<Stretch>& parts, std::size_t i0) {
  std::vector<Stretch> out;
  for (const Stretch& p : parts) {
    if (p.end > std::max(p.begin, i0)) out.push_back({std::max(p.begin, i0), p.end});
  }
  return out;
}

std::string whyNotJudged(std::span<const double> t_s, double settle_s, double period_s,
                         double pickup_periods) {
  if (t_s.empty()) return "no samples";
  std::vector<double> t(t_s.size());
  for (std::size_t i = 0; i < t.size(); ++i) t[i] = t_s[i] - t_s.front();
  const std::vector<Stretch> parts = stretchesOf(t);
  double longest = 0.0;
  for (std::size_t k = 0; k < parts.size(); ++k) {
    const double start = t[parts[k].begin], end = t[parts[k].end - 1];
    const double judged_from =
        k == 0 ? settle_s : std::max(settle_s, start + pickup_periods * period_s);
    if (end >= judged_from + period_s) return "";
    longest = std::max(longest, end - start);
  }
  char text[320];
  if (parts.size() == 1) {
    std::snprintf(text, sizeof text,
                  "its samples span %.1f s (%.1f s needed: %.1f s to settle and a %.1f s period)",
                  longest, settle_s + period_s, settle_s, period_s);
  } else {
    std::snprintf(text, sizeof text,
                  "none of its %zu stretches between gaps is long enough to judge (from the "
                  "start: %.1f s to settle and a %.1f s period; after a gap: %.1f s, to %.1f s "
                  "or later); the longest spans %.1f s",
                  parts.size(), settle_s, period_s, (pickup_periods + 1.0) * period_s,
                  settle_s + period_s, longest);
  }
  return text;
}

double appliedForceRefN(const Sample& s, double force_scale) noexcept {
  Vec3 applied = Vec3::Zero();
  for (const SampleFinger& f : s.fingers) {
    const Quat q(f.orientation_q[0], f.orientation_q[1], f.orientation_q[2], f.orientation_q[3]);
    applied += thimbleForceVector({f.tangential_n, f.normal_n}, q);
  }
  return applied.norm() / force_scale;
}

Series seriesFromSamples(std::span<const Sample> samples, double force_scale) {
  Series s;
  s.t_s.reserve(samples.size());
  s.force_ref_n.reserve(samples.size());
  s.angles_rad.reserve(samples.size());
  for (const Sample& x : samples) {
    double t = static_cast<double>(x.source_time_ns - samples.front().source_time_ns) * 1e-9;
    // A loop faster than its device records each device sample once a tick, with the same
    // time: it is taken once (spacing the copies 1 ms apart would stretch the trial's time).
    if (!s.t_s.empty() && t == s.t_s.back()) continue;
    if (!s.t_s.empty() && !(t > s.t_s.back())) t = s.t_s.back() + 1e-3;
    s.t_s.push_back(t);
    s.force_ref_n.push_back(appliedForceRefN(x, force_scale));
    s.angles_rad.emplace_back(x.mcp_angles_rad[0], x.mcp_angles_rad[1], x.mcp_angles_rad[2]);
  }
  return s;
}

// --- OscillationTracker -------------------------------------------------------------------

OscillationTracker::OscillationTracker(double min_hz, double max_hz, double hysteresis_n) noexcept
    : min_hz_(min_hz), max_hz_(max_hz), hysteresis_n_(hysteresis_n) {}

void OscillationTracker::reset() noexcept {
  *this = OscillationTracker(min_hz_, max_hz_, hysteresis_n_);
}

void OscillationTracker::Filter::design(double cutoff, double interval) noexcept {
  const Biquad q = butterworth(cutoff, interval);
  b0 = q.b0;
  b1 = q.b1;
  b2 = q.b2;
  a1 = q.a1;
  a2 = q.a2;
  cutoff_hz = std::min(cutoff, 0.45 / interval);
  dt = interval;
}

double OscillationTracker::Filter::step(double x) noexcept {
  const double y = b0 * x + b1 * x1 + b2 * x2 - a1 * y1 - a2 * y2;
  x2 = x1;
  x1 = x;
  y2 = y1;
  y1 = y;
  return y;
}

void OscillationTracker::startOscillation(double t_cross) noexcept {
  open_ = true;
  open_late_ = late_;
  t_open_ = t_cross;
  f_integral_ = 0.0;
  f_time_ = 0.0;
  y_max_ = -kInf;
  y_min_ = kInf;
  flex_max_ = -kInf;
  flex_min_ = kInf;
}

void OscillationTracker::halfSwing(double swing) noexcept {
  swings_[1] = swings_[0];
  swings_[0] = swing;
  n_swings_ = std::min(n_swings_ + 1, 2);
}

bool OscillationTracker::add(double t_s, double force_n, const Vec3& angles_rad,
                             Oscillation& out) noexcept {
  if (!std::isfinite(t_s) || !std::isfinite(force_n)) return false;
  if (!have_) {
    have_ = true;
    detect_.rest(force_n);  // the filters start at rest on the first value
    measure_.rest(force_n);
    t_prev_ = t_s;
    y_prev_ = force_n;
    ext_ = force_n;
    rising_ = true;
    t_last_extreme_ = t_s;
    return false;
  }
  const double dt = t_s - t_prev_;
  if (!(dt > 0.0)) return false;
  if (!(std::abs(dt - detect_.dt) <= 0.01 * detect_.dt)) detect_.design(kForceCutoffHz, dt);
  const double measure_hz =
      last_hz_ > 0.0 ? std::min(kForceCutoffHz, 3.0 * last_hz_) : kForceCutoffHz;
  if (!(std::abs(dt - measure_.dt) <= 0.01 * measure_.dt) ||
      !(std::abs(measure_hz - measure_.cutoff_hz) <= 0.01 * measure_hz)) {
    measure_.design(measure_hz, dt);
  }
  const double y = detect_.step(force_n);
  const double ym = measure_.step(force_n);

  if (open_) {
    f_integral_ += force_n * dt;
    f_time_ += dt;
    y_max_ = std::max(y_max_, ym);
    y_min_ = std::min(y_min_, ym);
    flex_max_ = std::max(flex_max_, angles_rad[kFlexion]);
    flex_min_ = std::min(flex_min_, angles_rad[kFlexion]);
  }

  // Peaks and troughs with hysteresis; a long stall forgets the swings.
  if (t_s - t_last_extreme_ > 1.0 / min_hz_) n_swings_ = 0;
  const double h = n_swings_ >= 2 ? std::max(hysteresis_n_, 0.25 * std::min(swings_[0], swings_[1]))
                                  : hysteresis_n_;
  bool trough_now = false;
  if (rising_) {
    if (y > ext_) {
      ext_ = y;
    } else if (y < ext_ - h) {
      if (have_trough_) halfSwing(ext_ - last_trough_);
      last_peak_ = ext_;
      have_peak_ = true;
      rising_ = false;
      ext_ = y;
      t_last_extreme_ = t_s;
    }
  } else {
    if (y < ext_) {
      ext_ = y;
    } else if (y > ext_ + h) {
      if (have_peak_) halfSwing(last_peak_ - ext_);
      last_trough_ = ext_;
      have_trough_ = true;
      rising_ = true;
      crossed_ = false;
      trough_now = true;
      ext_ = y;
      t_last_extreme_ = t_s;
    }
  }

  bool done = false;
  if (rising_ && !crossed_ && have_peak_ && have_trough_) {
    const double level = 0.5 * (last_peak_ + last_trough_);
    if (y >= level) {
      crossed_ = true;
      // Seen in time when the previous sample was still below the level on this rise.
      late_ = trough_now && !(y_prev_ < level);
      const double tc =
          (y_prev_ < level && y > y_prev_) ? t_prev_ + dt * (level - y_prev_) / (y - y_prev_) : t_s;
      const double t_cross = tc - butterworthDelayS(detect_.cutoff_hz);
      if (open_ && f_time_ > 0.0) {
        const double period = t_cross - t_open_;
        const double freq = period > 0.0 ? 1.0 / period : 0.0;
        const double swing = y_max_ - y_min_;
        if (freq >= min_hz_ && freq <= max_hz_ && swing >= 2.0 * hysteresis_n_ && !open_late_ &&
            !late_) {
          out.t_start_s = t_open_;
          out.t_end_s = t_cross;
          out.peak_n = y_max_;
          out.trough_n = y_min_;
          out.mean_n = f_integral_ / f_time_;
          out.frequency_hz = freq;
          out.amplitude_deg = radToDeg(flex_max_ - flex_min_);
          last_hz_ = freq;
          done = true;
        }
      }
      startOscillation(t_cross);
    }
  }
  y_prev_ = y;
  t_prev_ = t_s;
  return done;
}

// --- Trials -------------------------------------------------------------------------------

TrialFigures analyse(const Series& s, double band_min_n, double band_max_n, double settle_s) {
  TrialFigures f;
  const std::size_t n = std::min({s.t_s.size(), s.force_ref_n.size(), s.angles_rad.size()});
  if (n < 2) return f;
  std::vector<double> t = relativeTimes(s);
  t.resize(n);
  const std::vector<double> force(s.force_ref_n.begin(),
                                  s.force_ref_n.begin() + static_cast<std::ptrdiff_t>(n));
  f.duration_s = t[n - 1];
  const double dt = medianInterval(t);
  const std::vector<Stretch> parts = stretchesOf(t);
  f.stretches = parts.size();

  // The detector starts afresh on each stretch; each oscillation is within one. After a gap
  // its first period picks the oscillation up (its first extremes are where the stretch
  // began, not the force's): an oscillation there counts from one of its periods in.
  OscillationTracker tracker;
  Oscillation o;
  std::vector<std::size_t> part_of;  // the stretch of each oscillation
  for (std::size_t k = 0; k < parts.size(); ++k) {
    tracker.reset();
    const double picked_up = k == 0 ? 0.0 : t[parts[k].begin];
    for (std::size_t i = parts[k].begin; i < parts[k].end; ++i) {
      if (tracker.add(t[i], force[i], s.angles_rad[i], o) && o.t_start_s >= settle_s &&
          (k == 0 || o.t_start_s - picked_up >= o.t_end_s - o.t_start_s)) {
        f.oscillations.push_back(o);
        part_of.push_back(k);
      }
    }
  }
  const std::size_t i0 =
      static_cast<std::size_t>(std::lower_bound(t.begin(), t.end(), settle_s) - t.begin());
  if (i0 >= n) return f;
  const std::vector<Stretch> judged = stretchesFrom(parts, i0);
  for (const Stretch& p : judged) f.judged_s += t[p.end - 1] - t[p.begin];

  if (!f.oscillations.empty()) {
    double peak = 0, trough = 0, amp = 0;
    for (const Oscillation& x : f.oscillations) {
      peak += x.peak_n;
      trough += x.trough_n;
      amp += x.amplitude_deg;
    }
    const double k = static_cast<double>(f.oscillations.size());
    f.force_peak_n = peak / k;
    f.force_trough_n = trough / k;
    f.amplitude_deg = amp / k;
  }

  const std::vector<double> lp = filtfiltParts(force, parts, kForceCutoffHz, dt);
  double sum = 0.0;
  int in_band = 0;
  for (int a = 0; a < kAxes; ++a) {
    f.rom_min_deg[a] = kInf;
    f.rom_max_deg[a] = -kInf;
  }
  for (std::size_t i = i0; i < n; ++i) {
    sum += force[i];
    if (lp[i] >= band_min_n && lp[i] <= band_max_n) ++in_band;
    for (int a = 0; a < kAxes; ++a) {
      f.rom_min_deg[a] = std::min(f.rom_min_deg[a], radToDeg(s.angles_rad[i][a]));
      f.rom_max_deg[a] = std::max(f.rom_max_deg[a], radToDeg(s.angles_rad[i][a]));
    }
  }
  const double m = static_cast<double>(n - i0);
  f.force_mean_n = sum / m;
  f.time_in_band = in_band / m;

  f.frequency_spectrum_hz = spectrumPeakHz(force, t, judged, dt, kSpectrumMinHz, kSpectrumMaxHz);
  if (f.frequency_spectrum_hz > 0.0) {
    f.frequency_zc_hz = zeroCrossingHz(t, lp, parts, i0, dt, 1.0 / f.frequency_spectrum_hz);
  }

  // Smoothness: third derivative of the low-passed flexion, per oscillation.
  std::vector<double> flex(n);
  for (std::size_t i = 0; i < n; ++i) flex[i] = s.angles_rad[i][kFlexion];
  const std::vector<double> fl = filtfiltParts(flex, parts, kJerkCutoffHz, dt);
  double jerk_sum = 0.0;
  int jerk_n = 0;
  for (std::size_t q = 0; q < f.oscillations.size(); ++q) {
    const Oscillation& x = f.oscillations[q];
    const Stretch& p = parts[part_of[q]];
    const double a_rad = degToRad(x.amplitude_deg);
    const double T = x.t_end_s - x.t_start_s;
    if (!(a_rad > 1e-9) || !(T > 0.0)) continue;
    auto lo =
        static_cast<std::size_t>(std::lower_bound(t.begin(), t.end(), x.t_start_s) - t.begin());
    auto hi = static_cast<std::size_t>(std::lower_bound(t.begin(), t.end(), x.t_end_s) - t.begin());
    lo = std::max<std::size_t>(lo, p.begin + 1);
    hi = std::min(hi, p.end - std::min<std::size_t>(p.end, 2));
    double integral = 0.0;
    for (std::size_t i = lo; i < hi; ++i) {
      const double j3 = (fl[i + 2] - 3.0 * fl[i + 1] + 3.0 * fl[i] - fl[i - 1]) / (dt * dt * dt);
      integral += j3 * j3 * dt;
    }
    if (!(integral > 0.0)) continue;
    jerk_sum += std::log(std::pow(T, 5) / (a_rad * a_rad) * integral);
    ++jerk_n;
  }
  if (jerk_n > 0) f.jerk = jerk_sum / jerk_n;
  return f;
}

Targets deriveTargets(const Series& demo, double settle_s) {
  Targets tg;
  const TrialFigures first = analyse(demo, -kInf, kInf, settle_s);
  tg.band_min_n = first.force_trough_n;
  tg.band_max_n = first.force_peak_n;
  const TrialFigures f = analyse(demo, tg.band_min_n, tg.band_max_n, settle_s);
  tg.force_peak_n = f.force_peak_n;
  tg.force_trough_n = f.force_trough_n;
  tg.force_mean_n = f.force_mean_n;
  tg.frequency_hz = f.frequency_spectrum_hz;
  tg.amplitude_deg = f.amplitude_deg;
  tg.jerk = f.jerk;
  for (int a = 0; a < kAxes; ++a) {
    tg.rom_min_deg[a] = f.rom_min_deg[a];
    tg.rom_max_deg[a] = f.rom_max_deg[a];
  }
  tg.time_in_band = f.time_in_band;
  tg.oscillations = static_cast<int>(f.oscillations.size());
  if (f.oscillations.empty()) return tg;
  if (!(tg.frequency_hz > 0.0)) {
    double fs = 0.0;
    for (const Oscillation& o : f.oscillations) fs += o.frequency_hz;
    tg.frequency_hz = fs / static_cast<double>(f.oscillations.size());
  }
  const std::vector<double> t = relativeTimes(demo);
  Path mean;
  mean.fill(Vec3::Zero());
  double period = 0.0;
  for (const Oscillation& o : f.oscillations) {
    const Path p = resample(t, demo.angles_rad, o);
    for (std::size_t k = 0; k < mean.size(); ++k) mean[k] += p[k];
    period += o.t_end_s - o.t_start_s;
  }
  const double k = static_cast<double>(f.oscillations.size());
  tg.path_period_s = period / k;
  tg.path_rad.reserve(mean.size());
  for (const Vec3& v : mean) tg.path_rad.push_back(v / k);
  tg.path_error_deg = meanPathError(demo, t, f.oscillations, tg.path_rad);
  return tg;
}

TrialScore score(const Series& attempt, const Targets& t, double settle_s) {
  TrialScore r;
  r.figures = analyse(attempt, t.band_min_n, t.band_max_n, settle_s);
  const TrialFigures& f = r.figures;
  r.time_in_band = f.time_in_band;
  r.not_scored = whyNotJudged(attempt.t_s, settle_s, 1.0 / std::max(t.frequency_hz, 0.1), 1.0);
  if (!r.not_scored.empty() || f.oscillations.empty()) return r;
  r.peak_error_n = f.force_peak_n - t.force_peak_n;
  r.trough_error_n = f.force_trough_n - t.force_trough_n;
  r.mean_error_n = f.force_mean_n - t.force_mean_n;
  r.frequency_error_hz = signedOr(f.frequency_spectrum_hz - t.frequency_hz);
  r.amplitude_error_deg = f.amplitude_deg - t.amplitude_deg;
  r.path_error_deg = meanPathError(attempt, relativeTimes(attempt), f.oscillations, t.path_rad);
  r.jerk_delta = f.jerk - t.jerk;

  const double amp_tol = std::max(0.5, 0.2 * t.amplitude_deg);
  const double path_tol = std::max(0.5, 0.25 * t.amplitude_deg);
  r.overall = overallScore({
      {std::abs(r.peak_error_n), 1.0, 0.15},
      {std::abs(r.trough_error_n), 1.0, 0.10},
      {std::abs(r.mean_error_n), 1.0, 0.15},
      {std::abs(r.frequency_error_hz), std::max(0.05, 0.1 * t.frequency_hz), 0.15},
      {std::abs(r.amplitude_error_deg), amp_tol, 0.10},
      {std::max(0.0, t.time_in_band - r.time_in_band), 0.2, 0.15},
      {std::max(0.0, r.path_error_deg - t.path_error_deg), path_tol, 0.10},
      {std::max(0.0, r.jerk_delta), 0.5, 0.10},
  });
  return r;
}

double overallScore(std::initializer_list<ScoreTerm> terms) noexcept {
  double overall = 0.0;
  for (const ScoreTerm& x : terms) overall += x.weight * std::exp(-x.error / x.tolerance);
  return std::clamp(100.0 * overall, 0.0, 100.0);
}

std::string summaryLine(const TrialScore& s) {
  if (!s.not_scored.empty()) return "trial: not scored: " + s.not_scored;
  const TrialFigures& f = s.figures;
  char buf[320];
  std::snprintf(buf, sizeof buf,
                "trial: %zu oscillations, peak %.1f N (%+.1f), mean %.1f N (%+.1f), %.2f Hz "
                "(%+.2f), amplitude %.1f deg (%+.1f), in band %.0f %%, path %.1f deg, jerk "
                "%+.1f, score %.0f",
                f.oscillations.size(), f.force_peak_n, tidy(s.peak_error_n, 1), f.force_mean_n,
                tidy(s.mean_error_n, 1), f.frequency_spectrum_hz, tidy(s.frequency_error_hz, 2),
                f.amplitude_deg, tidy(s.amplitude_error_deg, 1), 100.0 * s.time_in_band,
                s.path_error_deg, tidy(s.jerk_delta, 1), s.overall);
  return buf;
}

std::string oscillationLine(const Oscillation& o, const Targets& t) {
  char buf[256];
  std::snprintf(buf, sizeof buf,
                "oscillation %.2f-%.2f s: peak %.1f N (%+.1f), trough %.1f N (%+.1f), %.2f Hz "
                "(%+.2f), amplitude %.1f deg (%+.1f)",
                o.t_start_s, o.t_end_s, o.peak_n, tidy(o.peak_n - t.force_peak_n, 1), o.trough_n,
                tidy(o.trough_n - t.force_trough_n, 1), o.frequency_hz,
                tidy(o.frequency_hz - t.frequency_hz, 2), o.amplitude_deg,
                tidy(o.amplitude_deg - t.amplitude_deg, 1));
  return buf;
}

}  // namespace telehand::technique
