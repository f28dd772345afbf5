#pragma once
/// Technique scoring: how closely a student's MCP mobilization (an oscillating push on the
/// proximal phalanx, force oscillating across a band at 1-6 Hz) repeats a clinician's
/// demonstration. Pure computation on recorded trials (1 kHz), deterministic: the same
/// input gives the same figures on every machine. The rules are all written here, next to
/// the figures they make.
///
/// Conventions: forces in newtons at reference scale (the device renders them 1:force_scale),
/// times in seconds from the trial's first sample, angles in radians in a Series and in
/// degrees in every figure. "After settle" means samples at t >= settle_s: the build-up of
/// the push is not judged.
#include <cstddef>
#include <initializer_list>
#include <span>
#include <string>
#include <vector>

#include "telehand/core/math.h"
#include "telehand/core/sample.h"

namespace telehand::technique {

/// Points of Targets::path_rad over one period.
inline constexpr int kPathPoints = 64;
/// Sakoe-Chiba band of the path comparison, in path points either side of the diagonal
/// (1/8 of a period).
inline constexpr int kPathBand = 8;
/// The force is low-passed at this cutoff (2nd-order Butterworth) before extremes and
/// crossings are taken: the oscillation is 1-6 Hz, sensor noise is broadband.
inline constexpr double kForceCutoffHz = 10.0;
/// The flexion angle is low-passed (zero phase) at this cutoff before its third derivative.
inline constexpr double kJerkCutoffHz = 20.0;

/// Samples further apart than this many device periods (the median interval between samples)
/// are in different stretches of the trial: the samples between are not in the record (a
/// damaged record, samples a client never delivered). Up to it, the filters and the detector
/// carry over the jump as they do over a late sample.
inline constexpr double kGapIntervals = 5.0;
/// ...and at least this long, s: a haptic loop that stalls reads the device once when it
/// resumes, however many of the device's steps went by, so its record's times jump; on a
/// loaded machine loops stall for tens of milliseconds, and a record split at every stall
/// leaves stretches too short to judge. A stall, or a short loss, is carried over as a late
/// sample is, and the spectrum reads the samples at their times.
inline constexpr double kMinGapS = 0.25;

/// One stretch of a trial's samples without a gap: indices [begin, end).
struct Stretch {
  std::size_t begin = 0, end = 0;
};

/// The stretches of the sample times `t_s` (increasing): a new one wherever the next sample
/// comes more than kGapIntervals median intervals, and kMinGapS, after its predecessor. One
/// stretch for a trial without a gap; none for no samples.
std::vector<Stretch> stretchesOf(std::span<const double> t_s);

/// The stretches of `parts` from index i0 on (those ending before it left out, the one
/// across it cut there): what is judged after the settle.
std::vector<Stretch> stretchesFrom(const std::vector<Stretch>& parts, std::size_t i0);

/// Whether a trial's samples are enough to judge: "" when they are, else why not (a phrase
/// for "... not scored: <why>"). A trial is judged over its stretches (stretchesOf); it can be
/// judged when one of them reaches one period (`period_s`, the targets') past the settle and
/// past its own pick-up: the stretch from the trial's first sample needs no pick-up (it had
/// the settle), one after a gap needs `pickup_periods` periods first (what the detector needs
/// to find the movement again). For a trial without a gap that is: its samples span at least
/// the settle plus one period, the rule the server applies to a short trial before scoring it.
std::string whyNotJudged(std::span<const double> t_s, double settle_s, double period_s,
                         double pickup_periods);

/// One trial, sampled at (about) 1 kHz. The three vectors have the same length.
struct Series {
  std::vector<double> t_s;          ///< seconds, increasing
  std::vector<double> force_ref_n;  ///< applied force, reference scale
  std::vector<Vec3> angles_rad;     ///< MCP angles (flexion, abduction, axial)
};

/// The applied force of a sample at reference scale: the norm of the sum of both thimbles'
/// force vectors (thimbleForceVector from each finger's tangential/normal force and
/// orientation) divided by force_scale. A squeeze (equal and opposite pad forces) cancels;
/// what remains is the net push on the phalanx.
double appliedForceRefN(const Sample& s, double force_scale) noexcept;

/// A trial from recorded samples: t from source_time_ns relative to the first sample (a
/// sample whose time does not increase is placed 1 ms after its predecessor), the applied
/// force (appliedForceRefN) and the proxy's MCP angles.
Series seriesFromSamples(std::span<const Sample> samples, double force_scale);

/// One oscillation of the force: from one upward crossing of its mean to the next.
struct Oscillation {
  double t_start_s = 0.0, t_end_s = 0.0;  ///< upward mean crossings (filter delay removed)
  double peak_n = 0.0, trough_n = 0.0;    ///< extremes of the low-passed force
  double mean_n = 0.0;                    ///< time average of the force over the oscillation
  double frequency_hz = 0.0;              ///< 1 / (t_end - t_start)
  double amplitude_deg = 0.0;             ///< flexion, largest minus smallest
};

/// Streaming oscillation detector: feed one sample at a time (t, force, angles); add()
/// returns true and fills `out` when an oscillation completed. Bounded memory, no
/// allocation, no exceptions: a server calls it at 1 kHz per session.
///
/// Rule: the force is low-passed (kForceCutoffHz, 2nd-order Butterworth); its peaks and
/// troughs are found with hysteresis (a peak is confirmed when the force has fallen
/// max(hysteresis_n, 1/4 of the smaller of the last two half swings) below it, a trough
/// likewise); the mean level is the midpoint of the last confirmed peak and trough; an
/// oscillation runs from one upward crossing of that level (interpolated between samples,
/// the filter's group delay subtracted) to the next. Its peak and trough are the extremes
/// of the force low-passed again at 3x the previous oscillation's frequency (at most
/// kForceCutoffHz): sensor noise does not inflate them, and the attenuation of the
/// oscillation (0.6 %) is the same at every frequency. Oscillations whose frequency is
/// outside [min_hz, max_hz], whose swing is below 2 * hysteresis_n, or whose start was only
/// seen late (the crossing came before the trough was confirmed) are dropped.
class OscillationTracker {
 public:
  explicit OscillationTracker(double min_hz = 0.3, double max_hz = 10.0,
                              double hysteresis_n = 0.5) noexcept;
  bool add(double t_s, double force_n, const Vec3& angles_rad, Oscillation& out) noexcept;
  /// Forget everything (a new trial).
  void reset() noexcept;

 private:
  /// 2nd-order low-pass, direct form I.
  struct Filter {
    double b0 = 1, b1 = 0, b2 = 0, a1 = 0, a2 = 0;
    double cutoff_hz = 0, dt = 0;
    double x1 = 0, x2 = 0, y1 = 0, y2 = 0;
    void design(double cutoff, double interval) noexcept;
    void rest(double v) noexcept { x1 = x2 = y1 = y2 = v; }
    double step(double x) noexcept;
  };
  void startOscillation(double t_cross) noexcept;
  void halfSwing(double swing) noexcept;

  double min_hz_, max_hz_, hysteresis_n_;
  Filter detect_;   // crossings and extremes with hysteresis
  Filter measure_;  // the figures' peak and trough
  double last_hz_ = 0;
  bool have_ = false;
  double t_prev_ = 0, y_prev_ = 0;
  // Extremes with hysteresis.
  bool rising_ = true;
  double ext_ = 0;  // running max (rising) or min (falling)
  bool have_peak_ = false, have_trough_ = false;
  double last_peak_ = 0, last_trough_ = 0, t_last_extreme_ = 0;
  double swings_[2] = {0, 0};  // the last two half swings (peak - trough)
  int n_swings_ = 0;
  bool crossed_ = false;  // this rising half has crossed the mean
  bool late_ = false;     // ... and it was seen only when the trough was confirmed
  // The oscillation being accumulated (since the last upward crossing).
  bool open_ = false;
  bool open_late_ = false;
  double t_open_ = 0, f_integral_ = 0, f_time_ = 0, y_max_ = 0, y_min_ = 0;
  double flex_max_ = 0, flex_min_ = 0;
};

/// What one trial did. A trial with gaps (stretchesOf) is analysed stretch by stretch: the
/// detector starts afresh on each, the filters run within each, and every figure is taken
/// over the stretches together, each counting by its length (its samples, its oscillations,
/// its crossings' time; the periodogram sums the stretches' powers, each times the total
/// length over its own). Nothing is taken across a gap. In a stretch after a gap the
/// detector's first period picks the oscillation up: an oscillation there counts when it
/// starts at least one of its periods after the stretch's first sample.
struct TrialFigures {
  std::vector<Oscillation> oscillations;        ///< those starting after settle
  double force_peak_n = 0, force_trough_n = 0;  ///< mean over the oscillations
  double force_mean_n = 0;                      ///< mean force over the trial after settle
  /// Upward zero crossings of the detrended force (a centred one-period moving average
  /// removed, then low-passed with zero phase): crossings - 1 over their time span.
  double frequency_zc_hz = 0;
  /// Periodogram peak of the force after settle (cubic trend removed, Hann window, zero
  /// padded to >= 8x) in [0.3, 10] Hz, interpolated by a parabola through the log power.
  double frequency_spectrum_hz = 0;
  double amplitude_deg = 0;  ///< flexion peak-to-peak per oscillation, mean
  double rom_min_deg[3] = {0, 0, 0}, rom_max_deg[3] = {0, 0, 0};  ///< after settle, per axis
  /// Fraction 0..1 of the samples after settle whose low-passed (zero phase) force is within
  /// [band_min, band_max].
  double time_in_band = 0;
  /// Smoothness, per oscillation then the mean: ln((T^5 / A^2) * integral of (d^3 flexion /
  /// dt^3)^2 dt) with T the oscillation's duration and A its flexion peak-to-peak, flexion
  /// low-passed at kJerkCutoffHz (zero phase). The negative of the log dimensionless jerk
  /// (LDLJ) of Balasubramanian et al. 2012: larger is jerkier; a pure sinusoid gives
  /// ln((2 pi)^6 / 8) = 8.95 whatever its frequency and amplitude.
  double jerk = 0;
  double duration_s = 0;      ///< first to last sample
  std::size_t stretches = 0;  ///< stretches of samples without a gap (1: no gap)
  double judged_s = 0;        ///< time after settle the stretches span, gaps excluded
};

/// Figures of one trial against a force band.
TrialFigures analyse(const Series& s, double band_min_n, double band_max_n, double settle_s = 1.0);

/// What a student's trial is compared with: the demonstration's own figures.
struct Targets {
  /// The demonstration's own band: its mean trough .. its mean peak.
  double band_min_n = 0, band_max_n = 0;
  double force_peak_n = 0, force_trough_n = 0, force_mean_n = 0;
  double frequency_hz = 0;  ///< the demonstration's periodogram peak
  double amplitude_deg = 0, jerk = 0;
  double rom_min_deg[3] = {0, 0, 0}, rom_max_deg[3] = {0, 0, 0};
  double path_period_s = 0;  ///< one period (mean over the oscillations)
  /// The demonstration's mean oscillation of the MCP angles, each oscillation resampled to
  /// kPathPoints over its own period and averaged; phase 0 at the force's upward mean crossing.
  std::vector<Vec3> path_rad;
  double time_in_band = 0;    ///< the demonstration's own time in its band
  double path_error_deg = 0;  ///< the demonstration's own oscillations against path_rad
  int oscillations = 0;       ///< how many oscillations the targets come from
};

/// Targets from a demonstration (its figures after settle).
Targets deriveTargets(const Series& demo, double settle_s = 1.0);

/// A trial against targets. Errors are attempt minus target (signed).
struct TrialScore {
  TrialFigures figures;
  double peak_error_n = 0, mean_error_n = 0, frequency_error_hz = 0, amplitude_error_deg = 0;
  double trough_error_n = 0;
  double time_in_band = 0;  ///< the attempt's, in the targets' band
  /// Each oscillation's angles, resampled to kPathPoints over its own period, against
  /// path_rad by dynamic time warping (Sakoe-Chiba band kPathBand, Euclidean distance of the
  /// three angles): RMS deg along the warping path, mean over the oscillations.
  double path_error_deg = 0;
  double jerk_delta = 0;  ///< attempt minus target; positive = jerkier than the demonstration
  /// 0..100, 100 = identical to the demonstration: 100 * sum of w_i * exp(-e_i / tol_i), the
  /// terms (e_i; tol_i; w_i):
  ///   |peak error|; 1 N; 0.15            |trough error|; 1 N; 0.10
  ///   |mean error|; 1 N; 0.15
  ///   |frequency error|; 10 % of the target frequency, at least 0.05 Hz; 0.15
  ///   |amplitude error|; 20 % of the target amplitude, at least 0.5 deg; 0.10
  ///   time in band short of the demonstration's own; 0.2; 0.15
  ///   path error beyond the demonstration's own; 25 % of the target amplitude, at least
  ///     0.5 deg; 0.10
  ///   jerk above the demonstration's; 0.5; 0.10
  /// Doing better than the demonstration on time in band, path or jerk costs nothing. No term
  /// has a cut-off: a larger error, the others unchanged, always scores lower. 0 when the
  /// trial has no oscillation.
  double overall = 0;
  /// Empty when the trial is scored; else why it is not (whyNotJudged with the targets'
  /// period, a pick-up of one period after a gap: the detector needs a peak and a trough
  /// before an oscillation starts), and `overall` is no score but 0: the trial's samples
  /// are too short to judge, and a 0 would say the student failed what the record cannot show.
  std::string not_scored;
};

TrialScore score(const Series& attempt, const Targets& t, double settle_s = 1.0);

/// One part of an overall score: its error, the error at which it has lost 63 % of its share,
/// and its share of 100.
struct ScoreTerm {
  double error, tolerance, weight;
};
/// 100 · Σ weight · exp(−error / tolerance), within 0..100: every technique's overall score.
double overallScore(std::initializer_list<ScoreTerm> terms) noexcept;

/// One line for an event, e.g. "trial: peak 15.1 N (+0.3), 3.02 Hz (+0.02), amplitude 8.1
/// deg (-0.2), in band 82 %, path 0.6 deg, jerk +0.1, score 91"; "trial: not scored: <why>"
/// for a trial not scored.
std::string summaryLine(const TrialScore& s);
/// One line per oscillation, e.g. "oscillation 2.35-2.68 s: peak 15.9 N (+0.1), trough 12.2 N
/// (+0.1), 3.03 Hz (+0.03), amplitude 8.0 deg (-0.1)".
std::string oscillationLine(const Oscillation& o, const Targets& t);

}  // namespace telehand::technique
