#pragma once
/// Technique scoring for the circular massage of the web between thumb and index
/// (docs/massage.md): how closely a student's massage repeats a clinician's demonstration.
/// The operator presses the web from both sides (thumb dorsal, index palmar, about 10 N at
/// reference scale) and moves both contact points together round a small circle. Pure
/// computation on recorded trials (1 kHz), deterministic; the rules are all written here,
/// next to the figures they make, as technique_score.h does for the mobilization.
///
/// Conventions: forces in newtons at reference scale (the device renders them 1:force_scale),
/// lengths in metres in a series and in millimetres in a line, times in seconds from the
/// trial's first sample. "After settle" means samples at t >= settle_s: the build-up of the
/// press is not judged. The circle is that of the contact point, the midpoint of the two
/// thimbles, in the web frame W of the tissue model (tissue_model.h): x, y on the web, seen
/// from the dorsal side; a frequency is positive counter-clockwise from there.
#include <cstddef>
#include <span>
#include <string>
#include <vector>

#include "telehand/core/math.h"
#include "telehand/core/sample.h"
#include "telehand/core/technique_score.h"
#include "telehand/core/tissue_model.h"

namespace telehand::technique {

/// A contact point that stays within this of its centre (mean distance) draws no circle: a
/// press without the movement, whatever its jitter's angle does.
inline constexpr double kMinCircleRadiusM = 0.0005;

/// One massage trial, sampled at (about) 1 kHz. All vectors have the same length.
struct MassageSeries {
  std::vector<double> t_s;                          ///< seconds, increasing
  PerFinger<std::vector<Vec3>> position_m;          ///< thimble centres, device frame
  PerFinger<std::vector<double>> normal_ref_n;      ///< paper eq. 2 / force_scale
  PerFinger<std::vector<double>> tangential_ref_n;  ///< paper eq. 1 / force_scale (signed)
};

/// A trial from recorded samples: t from source_time_ns relative to the first sample (a
/// sample whose time does not increase is placed 1 ms after its predecessor), the thimble
/// positions, and each finger's normal and tangential force divided by force_scale (a
/// capture's samples are at reference scale: force_scale 1).
MassageSeries massageSeriesFromSamples(std::span<const Sample> samples, double force_scale);

/// What one trial did.
struct MassageFigures {
  /// Each finger's normal force after settle: mean and standard deviation.
  PerFinger<double> finger_normal_mean_n{};
  PerFinger<double> finger_normal_sd_n{};
  /// Both fingers together: the mean of the two means, and the RMS of the two deviations.
  double normal_mean_n = 0, normal_sd_n = 0;
  /// Fraction 0..1 of the fingers' samples after settle whose normal force is within
  /// [band_min, band_max].
  double time_in_band = 0;
  /// Mean |tangential| over mean normal, both fingers. Eq. 1 measures the thimble's side
  /// axis only (the web's y), so a force that turns with the circle shows 2/pi of itself.
  double tangential_ratio = 0;
  /// The contact point's circle, fitted over whole laps (see analyseMassage): its centre
  /// (web frame, z = 0), mean distance from it, the signed laps per second, and how round
  /// the path is.
  Vec3 centre_w = Vec3::Zero();
  double radius_m = 0;
  double frequency_hz = 0;
  double laps = 0;  ///< whole laps judged
  /// Minor over major axis of the path's ellipse of inertia (sqrt of the ratio of the
  /// eigenvalues of the points' covariance about the centre): 1 for a circle.
  double circularity = 0;
  double radial_rms_m = 0;  ///< RMS of the distance from the centre minus radius_m
  double duration_s = 0;    ///< first to last sample
  /// Share 0..1 of the judged time (after settle) spent circling: the whole laps' time plus
  /// one of their periods (the lap under way when the trial ended), over the judged time.
  double circling_share = 0;
  /// Share 0..1 of the fingers' samples after settle that press the web: normal force at
  /// least half the band's low end (at least 0.5 N).
  double contact_share = 0;
  std::size_t stretches = 0;  ///< stretches of samples without a gap (1: no gap)
  double judged_s = 0;        ///< time after settle the stretches span, gaps excluded
};

/// Figures of one trial on a web. The circle: a least-squares circle (Kasa) through the
/// contact points after settle gives a first centre; the angle round it, unwrapped, picks
/// the samples from settle to the end of the last whole lap; the circle is fitted again on
/// those, and the frequency is the slope of the unwrapped angle (least squares over time)
/// over 2 pi. Fewer than one whole lap, or a radius under kMinCircleRadiusM: the circle's
/// figures stay 0.
///
/// A trial with gaps (stretchesOf, technique_score.h) is judged stretch by stretch, nothing
/// taken across a gap (the laps made in one are not in the record): the press over all the
/// samples after settle, as for a whole trial; the angle unwrapped within each stretch, its
/// whole laps from the stretch's first sample after settle; laps, the second circle, radius,
/// circularity and radial RMS over all the stretches' whole laps together; the frequency the
/// least-squares slope of the angle over time with an offset per stretch (each stretch counts
/// by its length); the circling share's time is the stretches' whole laps plus, per
/// stretch, the lap under way at its end (one mean lap period, at most the stretch's time).
MassageFigures analyseMassage(const MassageSeries& s, const TissueParams& web,
                              double band_min_n = 8.0, double band_max_n = 12.0,
                              double settle_s = 1.0);

/// What a student's massage is compared with: the demonstration's own figures.
struct MassageTargets {
  double normal_mean_n = 0, normal_sd_n = 0;
  /// The demonstration's band: its mean ± max(2 sd, 1 N).
  double band_min_n = 0, band_max_n = 0;
  double time_in_band = 0;
  double tangential_ratio = 0;
  Vec3 centre_w = Vec3::Zero();
  double radius_m = 0, frequency_hz = 0, circularity = 0, radial_rms_m = 0;
  double laps = 0;
};

MassageTargets deriveMassageTargets(const MassageSeries& demo, const TissueParams& web,
                                    double settle_s = 1.0);

/// A trial against targets. Errors are attempt minus target (signed).
struct MassageScore {
  MassageFigures figures;
  double normal_error_n = 0;
  double spread_delta_n = 0;  ///< normal_sd_n minus the target's: positive = less steady
  double frequency_error_hz = 0;
  double radius_ratio = 0;  ///< attempt over target (1 = as demonstrated)
  double circularity_delta = 0;
  double tangential_ratio_error = 0;
  double centre_offset_m = 0;  ///< distance between the two circles' centres
  /// 0..100, 100 = identical to the demonstration: 100 * sum of w_i * exp(-e_i / tol_i), the
  /// terms (e_i; tol_i; w_i):
  ///   |normal error|; 1 N; 0.25
  ///   spread beyond the demonstration's; 0.5 N; 0.10
  ///   |frequency error|; 10 % of the target frequency, at least 0.05 Hz; 0.20
  ///   |radius ratio - 1|; 0.15; 0.20
  ///   circularity short of the demonstration's; 0.1; 0.10
  ///   |tangential ratio error|; 0.05; 0.10
  ///   centre offset; 25 % of the target radius, at least 0.5 mm; 0.05
  /// A steadier press or a rounder circle than the demonstration's costs nothing. No term has
  /// a cut-off: a larger error, the others unchanged, always scores lower. The sum is then
  /// multiplied by the circling share and the contact share (figures): one good lap and a
  /// trial held still, or circles traced off the web, are not the technique. 0 when the
  /// trial has no whole lap.
  double overall = 0;
  /// Empty when the trial is scored; else why it is not (whyNotJudged with the targets'
  /// period and no pick-up after a gap: a lap is counted from a stretch's first sample), and
  /// `overall` is no score but 0.
  std::string not_scored;
};

MassageScore scoreMassage(const MassageSeries& attempt, const MassageTargets& t,
                          const TissueParams& web, double settle_s = 1.0);

/// One line for an event, e.g. "massage: press 10.2 N (+0.2) sd 0.8 N (+0.1), 1.52 Hz
/// (+0.02), radius 5.9 mm (x0.98), circularity 0.97 (-0.01), tangential 0.30 (+0.01),
/// 27 laps, score 93"; "massage: not scored: <why>" for a trial not scored.
std::string massageSummaryLine(const MassageScore& s);

}  // namespace telehand::technique
