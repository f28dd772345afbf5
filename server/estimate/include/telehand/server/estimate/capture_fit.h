#pragma once
/// Fitting a joint model from a capture (paper section IV.B): per MCP axis, the force at the
/// lever arm that the thimbles measured against the angle the encoders measured, fitted by
/// least squares as the joint model renders it: a cubic, a free neutral zone around rest
/// and end-of-range walls where the clinician felt them (fitPiecewiseCubic), plus a viscous
/// term, a protective spasm (a stretch reflex capped as the joint model renders it) and an
/// inertial term (the phalanx, thimbles and links accelerated by the clinician), so that
/// mobilizing at speed does not bend the curve. Reported with the RMS residual, the
/// range reached, and two checks the residual alone does not show: how far the curve moves
/// when the dynamic terms are left out, and the up- against down-sweep hysteresis. The same code
/// serves the live refit in the server and `telehand-records fit`.
#include <array>
#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "telehand/core/fit.h"
#include "telehand/core/joint_model.h"
#include "telehand/core/sample.h"

namespace telehand::server::estimate {

/// One usable capture sample.
struct CapturePoint {
  uint64_t seq = 0;
  int64_t t_ns = 0;
  Vec3 angles_rad = Vec3::Zero();
  Vec3 axis_force_n = Vec3::Zero();  ///< force at the lever arm per axis, as captured (N)
  /// The eight FSR readings (N), thumb's sensors 1-4 then the index's: the Sample::flags
  /// fault-bit order.
  std::array<float, 2 * 4> fsr_n{};
};

/// Why samples were left out.
struct CaptureCounts {
  uint64_t used = 0;
  uint64_t invalid = 0;      ///< stored flagged invalid (non-finite fields)
  uint64_t fsr_fault = 0;    ///< a thimble sensor was flagged saturated or dead
  uint64_t not_capture = 0;  ///< the actuators were on (not a capture sample)
  /// Of the used, left out of the force fit because an FSR read near its ceiling there
  /// (FitOptions::saturation_margin); counted by the fit.
  uint64_t near_saturation = 0;
};

struct AxisFit {
  bool ok = false;
  /// Coefficients; range = the walls found, else the range reached.
  CubicCurve curve;
  bool wall_min = false, wall_max = false;  ///< the range end is a wall the capture felt
  double reached_min_deg = 0.0, reached_max_deg = 0.0;
  double zone_deg = 0.0;  ///< free neutral zone, half width (0: none found)
  double rest_deg = 0.0;  ///< its centre
  double rms_n = 0.0;     ///< RMS residual, N
  double damping_nms_per_rad = 0.0;
  /// Protective spasm (JointModelParams::speed_gain_s_per_rad): while the joint is stretched
  /// the damping is min(damping + gain·|F_el|·lever, damping_cap_nms_per_rad). The gain
  /// as used (0 when the spasm did not pay for itself, FitOptions::penalty), and the free
  /// estimate with its standard error from the curvature of the residual (whether used or
  /// not; a standard error of infinity: the capture holds no unsaturated stretch).
  double speed_gain_s_per_rad = 0.0;
  bool spasm = false;
  double speed_gain_fitted_s_per_rad = 0.0;
  double speed_gain_se_s_per_rad = 0.0;
  /// How much the spasm term lowered the axis' residual sum of squares, N² (0: not found;
  /// at the joint's gain where the axis took it, FitOptions::one_speed_gain).
  double spasm_evidence_n2 = 0.0;
  double damping_cap_nms_per_rad = 0.0;  ///< the cap the fit assumed (FitOptions)
  double inertia_kgm2 = 0.0;  ///< the moving mass as seen at the joint (phalanx + device)
  /// Whether inertia_kgm2 was estimated from the capture (true) or is the known value
  /// FitOptions::inertia_kgm2, used because the capture did not excite the inertia apart
  /// from the stiffness (see inertia_collinearity, inertia_fitted_kgm2).
  bool inertia_estimated = false;
  /// The inertia as a free coefficient of the least squares, and its standard error,
  /// whether used or not.
  double inertia_fitted_kgm2 = 0.0;
  double inertia_se_kgm2 = 0.0;
  /// Correlation of the angular acceleration with its best fit by a cubic in the angle and
  /// the rate: near 1 in a sweep at one frequency (acceleration ≈ −ω²·(angle − centre)),
  /// where inertia and stiffness cannot be told apart.
  double inertia_collinearity = 0.0;
  /// Largest change of the holding force over the range when the fit leaves the viscous and
  /// inertial terms out: what a purely static fit would get wrong (N). Above a few tenths
  /// of a newton, the curve rests on the dynamic terms: mobilize slower.
  double dynamic_n = 0.0;
  /// Largest difference of the mean residual between up and down sweeps at the same angle
  /// (5° bins), N: a speed-dependent force the model does not hold (e.g. a spasm the fit
  /// did not keep) shows here.
  double hysteresis_n = 0.0;
  double neutral_min_deg = 0.0;  ///< where |F| stays under the neutral-zone threshold
  double neutral_max_deg = 0.0;
  std::size_t samples = 0;
  /// The fitted holding force at `deg` (JointModel::holdingForceN semantics).
  double holdingForceN(double deg) const noexcept;
  /// The fitted force at the lever arm besides the holding force, at `deg` moving at
  /// `rate_rad_s` and accelerating at `acc_rad_s2`: viscous and spasm (capped, as
  /// JointModel::passiveTorqueNm) and inertial, N.
  double dynamicForceN(double deg, double rate_rad_s, double acc_rad_s2,
                       double lever_m) const noexcept;
};

struct CaptureFit {
  std::array<AxisFit, kAxes> axes{};
  CaptureCounts counts;
  double delay_samples = 0.0;  ///< the force channel's lag behind the positions, samples
  bool ok() const noexcept { return axes[0].ok && axes[1].ok && axes[2].ok; }
  /// The joint's speed gain: the estimate of the axis whose capture shows the spasm most
  /// (AxisFit::spasm_evidence_n2, the largest); 0 when no axis found one.
  double speedGain() const noexcept;
  /// `base` with the fitted curves, ranges, damping and speed gain (lever arm, scale, frame,
  /// name kept).
  JointModelParams model(const JointModelParams& base) const;
};

/// Whether the curve's force rises everywhere in [min_deg, max_deg] (what a patient case
/// must do; config.cpp refuses a falling one).
bool risesOverRange(const CubicCurve& c) noexcept;

struct FitOptions {
  /// Force below which the joint counts as lax (the neutral zone), N. About a force JND
  /// (7-10 %, docs/facts.md) of the paper's 12-16 N band.
  double neutral_force_n = 1.0;
  /// Angular rates: the least-squares slope of the angle over ±rate_half_window samples
  /// (1 kHz: ±4 ms; windowedRates). A sweep at ω reads about (ω·1 ms)²·Σk⁴ / (6·Σk²) slow,
  /// 0.28 % at 6 Hz, and the angle's noise reaches the rate by 1/√Σk² = 1/√60 per ms; the
  /// central difference over ±5 ms used before read 0.59 % slow at 6 Hz with 1/√50 (against
  /// a damping at the cap, tens of newtons at 6 Hz, 0.6 % is 0.2-0.4 N).
  int rate_half_window = 4;
  /// Half window for accelerations (second differences), samples. Narrower windows let encoder
  /// quantization into the acceleration and bias the inertia toward zero (±1 ms: by half).
  int acc_half_window = 5;
  /// ...except at the turns: where the second difference over ±turn_half_window differs
  /// from the one above by more than turn_outlier times its spread (1.4826 × the median
  /// absolute difference over the axis), the narrow one is used. A turn at the range end
  /// (a bounce off the wall at 6 Hz: 1,000-5,000 rad/s² within 5-10 ms, 2.6 N per
  /// 1,000 rad/s² at the known inertia and the 1 cm lever) is smeared by the wide window,
  /// and the curve absorbed the misread inertial force (random patient 10 at 6 Hz, seed 1:
  /// flexion 0.34 N off near its 6.1° zone; with the turns read narrow 0.15 N).
  /// turn_outlier 0: the wide window everywhere.
  int turn_half_window = 2;
  double turn_outlier = 5.0;
  /// The rates at the turns (the samples the test above marks), over ±turn_rate_half_window
  /// samples (0: the wide window there too). The ±4 ms quadratic does not follow a turn
  /// either: the shipped spasm case at 6 Hz, seed 45, read a turn's rate low where its
  /// damping sits at the cap (1 N per rad/s at 1 cm), and the fit put a false wall one
  /// degree inside the range reached (flexion 0.92 N off; over ±2 ms, 0.05 N).
  int turn_rate_half_window = 2;
  /// The turns' samples (and one either side) weigh less in the least squares, by how well
  /// their inertial force is known: σ² / (σ² + (J/L · Δa)²), σ the force channel's noise read
  /// from the capture, Δa the most the wide and narrow accelerations disagree there, J/L the
  /// known inertia at the lever arm. false: every sample weighs the same.
  bool weigh_turns = true;
  /// A wall is kept only when it explains at least this share of the force it adds beyond
  /// it (PiecewiseFitOptions::min_wall_share); 0: whenever it pays for itself.
  double min_wall_share = PiecewiseFitOptions{}.min_wall_share;
  /// Samples an axis needs spread over at least this many degrees to be fitted.
  double min_span_deg = 5.0;
  std::size_t min_samples = 200;
  /// The force channel may lag the position channel (FSR conditioning, sampling order):
  /// the fit finds the lag, up to this many samples, that explains the data best.
  int max_delay_samples = 4;
  /// The lag is chosen by the residual of fits with the end walls and the neutral zone
  /// searched at each lag (true), or of a plain cubic (false). Where the stiffness is
  /// constant a lag is a change of damping; the walls and zone edges, where it changes,
  /// tell them apart, and a plain cubic misreads them (random patient 10 at 3 Hz, seed 1: lag
  /// 0 for the truth's 1, its 6° zone lost, flexion 0.39 N off; with the shape 1.0, 0.16 N).
  bool lag_with_shape = true;
  /// The moving mass about the MCP, kg·m²: the proximal phalanx (2.1e-5, docs/facts.md
  /// "Ground truth") and the grip's thimbles and links (the simulated MF-2's 0.05 kg at the
  /// 1 cm lever arm, 0.5e-5). Used when the capture cannot separate inertia from stiffness.
  double inertia_kgm2 = 2.6e-5;
  /// The inertia is estimated from the capture only when the capture excites it apart from
  /// the stiffness: the acceleration's correlation with a cubic in the angle and the rate
  /// (AxisFit::inertia_collinearity) below this, and the estimate's standard error below
  /// max_inertia_rel_se of inertia_kgm2; else the known value is used. A correlation r
  /// amplifies any small misfit of the curve into the inertia by 1 / (1 − r²): at r = 0.8,
  /// measured, the estimate is still 10-30 % off. 0 always uses the known value.
  double max_inertia_collinearity = 0.5;
  double max_inertia_rel_se = 0.1;
  /// Protective spasm: the speed gain is fitted (alternating with the curve until it
  /// settles) and kept when it lowers the residual sum of squares by more than
  /// spasm_penalty · σ² ln n. false: no spasm term.
  bool fit_spasm = true;
  double spasm_penalty = 2.0;
  /// ...and its gain is at least this (s/rad). A smaller gain changes the damping by a few
  /// per cent of the cap over the range, and at speed a joint without spasm can earn one:
  /// where the joint's plain damping is near the cap, a tiny gain gives the stretch the cap
  /// and the return the plain damping, and that asymmetry absorbs the capture's own lag
  /// misfit (a random patient at 6 Hz: gain 0.006, its curve 0.8 N off). Random patients
  /// draw 0.5-3 s/rad, the shipped spasm has 1.5.
  double min_speed_gain_s_per_rad = 0.1;
  /// Every axis' curve is fitted with the joint's speed gain (CaptureFit::speedGain, the one
  /// the model renders on all three), its walls and zone searched again at it; an axis keeps
  /// its own fit where that drops a wall or the zone its own found. false: each axis' curve
  /// with its own gain.
  bool one_speed_gain = true;
  /// ...reached from the axis' own fit in this many geometric steps of the gain, the walls
  /// and zone settled at each and carried to the next, as well as in one; the fit of lower
  /// residual at the joint's gain is kept. 0: in one step only.
  int joint_gain_steps = 4;
  /// The scale the fitted model is rendered at (paper: 1:4). With the lever arm it sets the
  /// cap on damping plus spasm that the joint model renders (JointModel::maxDampingNmsPerRad:
  /// 0.01 N·m·s/rad at 1 cm and 1:4), which the fit applies as the model does. A simulated
  /// patient is capped so; a real finger's reflex is not, and the fitted gain then holds the
  /// part of it under the cap, which is what the model renders. 0: no cap.
  double render_force_scale = 0.25;
  /// Near an FSR's ceiling. A sample in which a sensor saturates is left out (its reading is
  /// only a lower bound), and where the force runs close to the ceiling that leaves the
  /// samples whose noise pushed the reading down and drops those it pushed up: the force the
  /// fit sees there reads low, a truncation that the residual does not show. At 6 Hz, where
  /// a stretch at speed runs the pad sensors to their 22 N, that bent the spasm's reading:
  /// random patient 80, seed 7, 268 samples saturated, the gain read 2.17 s/rad for the
  /// truth's 1.80 (1.85 with the sensors' ceiling out of reach) and the axial curve 0.33 N
  /// off at that gain. So, for each sensor that saturated in the capture, the samples are
  /// left out where its reading averaged over ±saturation_half_window samples (which a
  /// sample's own noise moves by a fraction) comes within saturation_margin times the
  /// sensor's noise of its ceiling: the choice rests on the motion, not on each sample's
  /// noise. The ceiling is the least reading among the sensor's saturated samples, the noise
  /// the robust spread of its second differences. 0: only the saturated samples are left out.
  double saturation_margin = 4.0;
  int saturation_half_window = 10;
};

/// Rates of a signal `x` sampled at `t_ns` (about 1 kHz, in order; samples may be missing):
/// per sample, the slope at its time of a least-squares quadratic through the samples within
/// ±half_window of it (and within half_window + 0.5 ms), when that holds one on each side
/// and four in all (with the window whole: the least-squares slope); else the difference
/// across the window where it spans no gap, else 0. Per second.
std::vector<double> windowedRates(std::span<const int64_t> t_ns, std::span<const double> x,
                                  int half_window);

/// The per-axis force that a sample's thimbles exert at the lever arm (paper eqs. 1-2 for
/// each thimble, τ = Σ (p − c) × F, generalized per axis, divided by the lever arm), or
/// nullopt with the reason counted.
std::optional<CapturePoint> capturePoint(const JointModel& geometry, const Sample& s, bool valid,
                                         CaptureCounts& counts);

/// Accumulates capture samples and fits them. Samples may come out of sequence order (a
/// retried chunk, a backlog sent after an outage while live samples go on): those are kept
/// aside and merged in order, duplicates dropped, when the points are next read, so that a
/// capture's cost stays O(n log n) whatever order its samples come in. Not thread-safe.
class CaptureFitter {
 public:
  explicit CaptureFitter(const JointModelParams& geometry, const FitOptions& options = {});
  /// Returns true when the sample was used (false: not a usable capture point, or a sequence
  /// number already held in order; a duplicate among the late ones is dropped at the merge).
  bool add(const Sample& s, bool valid);
  std::size_t size() const {
    settle();
    return points_.size();
  }
  const CaptureCounts& counts() const noexcept { return counts_; }
  const std::vector<CapturePoint>& points() const {
    settle();
    return points_;
  }
  /// Angular rates of every point (windowedRates over FitOptions::rate_half_window, over
  /// ±turn_rate_half_window at the turns), rad/s.
  std::vector<Vec3> rates() const;
  /// Angular accelerations of every point (second central differences over
  /// ±FitOptions::acc_half_window, over ±turn_half_window at the turns), rad/s².
  std::vector<Vec3> accelerations() const;
  /// Per point and axis, whether it is at a turn: where the second difference over
  /// ±FitOptions::turn_half_window differs from the one over ±acc_half_window by more than
  /// turn_outlier times its robust spread (all false with turn_outlier 0).
  std::vector<std::array<bool, kAxes>> turns() const;
  /// Second central differences over ±half_window samples, rad/s².
  std::vector<Vec3> accelerationsOver(int half_window) const;
  /// The force channel's lag behind the position channel, in samples (fractional).
  double delaySamples() const;
  /// `progress(axis, fraction)` is called as the fit advances (long captures).
  CaptureFit fit(const std::function<void(int, double)>& progress = {}) const;

 private:
  /// Per axis, the known inertial coefficient (N per rad/s²) to use, or NaN where the
  /// capture excites the inertia apart from the stiffness and it is estimated; per axis
  /// the acceleration's collinearity, the free estimate and its standard error (kg·m²)
  /// through `info` (3 each). `skip`: the points left out of the force fit (nearSaturation).
  std::array<double, kAxes> inertiaChoice(
      const std::vector<Vec3>& rate, const std::vector<Vec3>& acc, std::span<const uint8_t> skip,
      std::array<std::array<double, 3>, kAxes>* info = nullptr) const;
  double delaySamples(const std::vector<Vec3>& rate, const std::vector<Vec3>& acc,
                      const std::array<double, kAxes>& known_j, const std::vector<Vec3>& weight,
                      std::span<const uint8_t> skip) const;
  /// Per point and axis, its weight in the least squares (FitOptions::weigh_turns; empty:
  /// all 1).
  std::vector<Vec3> turnWeights() const;

  /// Merges the late points into points_ (sorted by sequence number, the first copy of each
  /// kept).
  void settle() const;
  /// Per point, whether it is left out of the force fit near an FSR's ceiling
  /// (FitOptions::saturation_margin).
  std::vector<uint8_t> nearSaturation() const;
  /// Sorts faulted_ by sequence number, the first copy of each kept.
  void settleFaulted() const;

  /// A sample left out for a flagged FSR: its readings, for the ceiling and its neighbours.
  struct FsrFaulted {
    uint64_t seq = 0;
    uint8_t mask = 0;  ///< Sample::flags' FSR fault bits
    std::array<float, 2 * 4> fsr_n{};
  };

  JointModel geometry_;
  FitOptions options_;
  mutable std::vector<CapturePoint> points_;  // in sequence order
  mutable std::vector<CapturePoint> late_;    // out of order, not merged yet
  mutable std::vector<FsrFaulted> faulted_;   // in arrival order until settleFaulted()
  CaptureCounts counts_;
};

/// Geometry a capture is fitted with: the joint's frame and lever arm at reference scale
/// (the thimbles measure real forces; 1:4 is a rendering scale).
JointModelParams captureGeometry(const JointModelParams& joint);

/// A patient-case TOML (deploy/cases format, loadable by sessions) of a fitted model.
std::string patientCaseToml(const CaptureFit& fit, const JointModelParams& model,
                            const std::string& name, const std::string& description,
                            const std::string& source);

}  // namespace telehand::server::estimate
