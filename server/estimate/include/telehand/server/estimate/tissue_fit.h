#pragma once
/// Fitting the web's tissue model from a massage capture (the actuators off, the clinician's
/// thumb and index circling on a real web), as capture_fit.h does for the joint: the
/// parameters of common/core's tissue model that explain what the thimbles measured, with a
/// standard error per parameter and the residuals, for a patient case's [tissue] section.
///
/// What a thimble measures (paper eqs. 1-2): the force its pad presses, along its side axis
/// (tangential) and along its pad normal (normal, a magnitude). Both are predicted from the
/// model at each sample's position and velocity and compared in those two components, so a
/// thimble that sits off the surface normal or turns about it is no problem.
///
/// The fit, in two alternating blocks (each holding the other's forces as known):
///  - Normal (Hunt–Crossley, F = k·δ^n·(1 + λ·δ̇)): Levenberg–Marquardt on (ln k, n, λ, the
///    surface offset of each finger's side, ln patch stiffness factor), started from the
///    best of a grid over the offsets and n with k in closed form. The offsets move the
///    surfaces the nominal geometry gives (thickness and origin), found from where the force
///    sets in. Eq. 2 is a magnitude: near zero the noise is cut at 0, so the fit compares
///    the measurement with the expected value of the cut noisy force (E[max(F + e, 0)]),
///    which keeps the onset unbiased.
///  - Friction (stick–slip on an elastic skin anchor plus viscous skin). The anchor is a
///    state the parameters drive, so the prediction simulates it over the capture with the
///    normal block's force. The skin's sawtooth while it slips (up to mu_static, back to
///    mu_kinetic, teeth of a millimetre or two) cannot be followed in step at 1.43 N of
///    noise, and a simulation with it makes the residual jump with every per cent of a
///    parameter, so the fit's model averages it (simulateFriction in tissue_fit.cpp): a
///    slipping skin holds mu_mid = (mu_static + mu_kinetic) / 2 and the skin first yields
///    at mu_static after each touch. Nelder–Mead on (ln lateral stiffness, ln mu_mid, ln
///    patch friction factor) with b projected out (it is linear), started from a grid; the
///    teeth's height mu_static − mu_kinetic from the residual's covariance one sample apart
///    where the model slips (a sawtooth's autocovariance; the noise is white); b last, from
///    the exact sawtooth at the fitted values.
/// Standard errors: the normal block's from its Jacobian (σ²·(JᵀJ)⁻¹), the friction's from a
/// delete-a-group jackknife over the contacts (the model's averaging, not the noise, sets
/// their spread). A massage at 10 ± 2 N alone does not hold k, λ and b within 10 % at
/// 1.43 N of noise; the capture protocol (indentations, light fast strokes, then the
/// circles) does: docs/capture.md "Massage".
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "telehand/core/joint_model.h"
#include "telehand/core/sample.h"
#include "telehand/core/tissue_model.h"
#include "telehand/server/estimate/capture_fit.h"

namespace telehand::server::estimate {

/// One thimble's sample, in the device frame and in the nominal web frame.
struct TissuePoint {
  uint64_t seq = 0;
  int64_t t_ns = 0;
  Vec3 p_device = Vec3::Zero();      ///< thimble centre
  Vec3 v_device = Vec3::Zero();      ///< its velocity (central differences), m/s
  Vec3 side_device = Vec3::UnitY();  ///< the thimble's side axis (eq. 1's direction)
  Vec3 pad_device = Vec3::UnitZ();   ///< its pad normal (eq. 2's direction)
  /// Its acceleration (second differences over twice the velocity's window), m/s².
  Vec3 a_device = Vec3::Zero();
  Vec3 p_web = Vec3::Zero(), v_web = Vec3::Zero();  ///< the same in the nominal web frame
  Vec3 a_web = Vec3::Zero();
  Vec3 side_web = Vec3::UnitY(), pad_web = Vec3::UnitZ();
  double tangential_n = 0.0;  ///< eq. 1 as measured
  double normal_n = 0.0;      ///< eq. 2 as measured
};

/// What a clinician knows of a web before its fit: where it is, how thick, the pad, the
/// contact area and where a scar sits; nothing of its mechanics (those stay the defaults).
TissueParams tissueGeometry(const TissueParams& p) noexcept;

struct TissueFitOptions {
  /// The thimble error, 1 σ (the expected value of eq. 2 near zero rests on it; the fit's own
  /// residual is reported beside it).
  double noise_n = 1.43;
  /// Eq. 2 is a magnitude: the noise is cut at 0. false: the measurement may go negative.
  bool normal_cut_at_zero = true;
  /// Central difference half window for velocities, samples.
  int rate_half_window = 2;
  /// Estimate the mass between the sensors and the skin (thimble and link, kg): the
  /// thimbles then measure the web's force plus that mass times its acceleration, which
  /// fast indentations make a newton or more.
  bool fit_mass = true;
  /// Estimate each side's surface offset from the nominal geometry (within ± this, m).
  bool fit_surface = true;
  double max_surface_offset_m = 0.004;
  /// Fit the patch's factors when the nominal geometry has a patch (its place and size are
  /// the nominal's) and this many contact samples lie inside it.
  bool fit_patch = true;
  std::size_t min_patch_samples = 2000;
  /// Samples in contact each finger needs (both together at least this), and the depth
  /// span they must cover.
  std::size_t min_contact_samples = 5000;
  double min_depth_span_m = 0.002;
  int max_iterations = 60;
  int passes = 2;  ///< alternations of the normal and friction blocks
  /// The friction parameters' standard errors: a delete-a-group jackknife over the contacts
  /// (this many groups, each refitted with up to jackknife_evals simplex steps); fewer than
  /// 2: none (NaN).
  int jackknife_groups = 5;
  int jackknife_evals = 150;
};

/// A fitted value with its standard error (NaN: not estimated).
struct FittedValue {
  double value = 0.0;
  double se = 0.0;
};

struct TissueFit {
  bool ok = false;
  std::string why;  ///< when not ok: what the capture lacks
  /// The nominal geometry with the surfaces moved by the offsets, and the fitted values.
  TissueParams params;
  FittedValue stiffness, exponent, damping, lateral_stiffness, mu_static, mu_kinetic, viscous;
  FittedValue patch_stiffness_factor, patch_friction_factor;  ///< se NaN when not fitted
  /// The normal force at the reference depth (the contact depths' geometric mean): what the
  /// capture pins down of the stiffness apart from n (k = force_at_ref / ref_depth^n).
  FittedValue force_at_ref;
  double ref_depth_m = 0.0;
  FittedValue thimble_mass_kg;  ///< se NaN when not fitted
  bool patch_fitted = false;
  PerFinger<FittedValue> surface_offset_m{};  ///< + deeper than nominal (the skin sits higher)
  double normal_rms_n = 0.0;                  ///< RMS residual of eq. 2
  /// RMS residual of eq. 1 in contact, of the averaged friction model the fit uses (the
  /// exact sawtooth replayed out of step with the data leaves more: see simulateFriction).
  double tangential_rms_n = 0.0;
  /// Depths in contact the capture covered (fitted surfaces), m, and their depth rates (5th
  /// and 95th percentile, m/s); normal forces the fit predicts there, N.
  double depth_min_m = 0.0, depth_max_m = 0.0;
  double depth_rate_p5_m_s = 0.0, depth_rate_p95_m_s = 0.0;
  double force_max_n = 0.0;
  double slip_fraction = 0.0;  ///< of contact samples, where the fitted skin slides
  double speed_p95_m_s = 0.0;  ///< tangential speed in contact, 95th percentile
  std::size_t samples = 0;     ///< thimble samples used (both fingers)
  std::size_t contact_samples = 0;
  std::size_t patch_samples = 0;
  int iterations = 0;  ///< Levenberg–Marquardt iterations and simplex evaluations, all passes
  CaptureCounts counts;
};

/// Accumulates capture samples of a massage and fits them.
class TissueFitter {
 public:
  /// `nominal`: the web's geometry (origin, orientation, thickness, pad radius, contact area,
  /// patch place and size); its other values only start the fit where a block is skipped.
  explicit TissueFitter(const TissueParams& nominal, const TissueFitOptions& options = {});
  bool add(const Sample& s, bool valid);
  std::size_t size() const noexcept { return seq_.size(); }
  const CaptureCounts& counts() const noexcept { return counts_; }
  /// Per finger, the points with their velocities (sorted by sequence).
  PerFinger<std::vector<TissuePoint>> points() const;
  TissueFit fit() const;
  const TissueParams& nominal() const noexcept { return nominal_; }

 private:
  TissueParams nominal_;
  TissueFitOptions options_;
  std::vector<uint64_t> seq_;
  std::vector<Sample> samples_;
  CaptureCounts counts_;
};

/// What a fitted model predicts each point measures: eq. 2 (before the noise) and eq. 1,
/// the depth and whether the skin slips, stepping the anchors through the points in order.
struct TissuePrediction {
  std::vector<double> normal_n, tangential_n, depth_m, depth_rate_m_s, normal_force_n;
  std::vector<uint8_t> contact, slipping;
};
TissuePrediction predictTissue(const TissueParams& model, int finger,
                               const std::vector<TissuePoint>& points);

/// What the plots of a fit show (telehand-records fit), over the points of both fingers.
struct TissuePlotData {
  /// Normal force: the depth (fitted surfaces) and eq. 2 as measured over the pad's share
  /// of the normal (N), near contact; the patch weight there (0 outside, 1 inside).
  std::vector<double> depth_m, normal_n, patch_weight;
  /// Damping: the elastic force times the depth rate (N·m/s) against what eq. 2 measured
  /// beyond the elastic force (N): the slope is λ.
  std::vector<double> elastic_rate, normal_excess_n;
  /// Lateral stiffness: from each touch until the fitted skin first yields, the
  /// displacement from the touch point along the side axis (m) against eq. 1 less the normal
  /// and viscous shares (N): the slope is the lateral stiffness.
  std::vector<double> stick_disp_m, stick_force_n;
  /// Friction: where the fitted skin slides with its stretch within 35° of the side axis,
  /// g·F_n (N) against the friction along the stretch (N): between mu_kinetic·g·F_n and
  /// mu_static·g·F_n, about mu_mid·g·F_n on average.
  std::vector<double> slide_normal_n, slide_friction_n;
  /// Viscous: the velocity along the side axis (m/s) against eq. 1 less the exact model
  /// without b (N): the slope is b.
  std::vector<double> side_speed_m_s, viscous_force_n;
};
TissuePlotData tissuePlotData(const TissueFitter& fitter, const TissueFit& fit);

/// The [tissue] section of a patient case (keys named after TissueParams' fields), with the
/// fit's figures as comments when `fit` is given.
std::string tissueSectionToml(const TissueParams& p, const TissueFit* fit = nullptr);

/// A whole patient case: the joint sections of `joint` (written as patientCaseToml does for
/// a joint that was not fitted) and the fitted [tissue] section.
std::string massageCaseToml(const TissueFit& fit, const JointModelParams& joint,
                            const std::string& name, const std::string& description,
                            const std::string& source);

}  // namespace telehand::server::estimate
