#pragma once
/// The reduced model of the index MCP joint that both the client proxy and the server use,
/// so that with zero delay both compute identical torques and forces.
///
/// Geometry. The joint frame J (origin and orientation given in the device frame) has x
/// distal along the proximal phalanx at neutral, z dorsal, y = z × x. The phalanx frame is
/// R_J · Ry(alpha) · Rx(gamma) · Rz(beta): alpha = flexion (+ toward the palm), gamma = axial
/// rotation (+ = supination, an assumption; see healthyIndexMcp), beta = abduction. Axial
/// rotation, the smallest range, is the middle Euler axis, as the Bullet joint needs
/// (docs/facts.md "Bullet"). The student pinches the phalanx at the lever arm: the thumb on the
/// dorsal side (+z of the phalanx), the index on the palmar side.
///
/// Torques. Per-axis torques are the generalized forces conjugate to (alpha, beta, gamma):
/// tau_i = e_i · tau, with e_alpha = y_J, e_gamma = Ry(alpha) x, e_beta = Ry(alpha) Rx(gamma) z,
/// and tau = sum over fingers of (p_i − c) × F_i (docs/facts.md "Rendering").
#include <algorithm>
#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "telehand/core/math.h"
#include "telehand/core/tissue_model.h"

namespace telehand {

class KnnTorqueModel;

enum Axis : int { kFlexion = 0, kAbduction = 1, kAxial = 2 };
constexpr int kAxes = 3;
constexpr std::array<std::string_view, kAxes> kAxisNames = {"flexion", "abduction", "axial"};

/// F(a) = c3 a^3 + c2 a^2 + c1 a + c0: the force in newtons, applied at the lever arm in the
/// +angle direction, that holds the joint at angle a (degrees). Valid in [min_deg, max_deg];
/// outside, the curve continues along its end slope plus a stiff end-of-range wall.
struct CubicCurve {
  std::array<double, 4> coeffs{};  ///< c3, c2, c1, c0
  double min_deg = 0.0;
  double max_deg = 0.0;

  double eval(double deg) const noexcept;
  double slope(double deg) const noexcept;  ///< dF/da in N/deg

  bool operator==(const CubicCurve&) const = default;
};

/// Largest holding force (N at the lever arm, reference scale) a curve may reach anywhere in
/// its [min_deg, max_deg]. The strongest joint a patient case or a random case holds takes
/// about 120 N (eqs. 3-5 at 3.6 times their stiffness, at 100 deg flexion), and a capture fit
/// follows the forces a hand applied; 1000 N leaves a wide margin above any real MCP joint and
/// still refuses a curve whose force is absurd (or not finite) before it reaches a device.
constexpr double kMaxHoldingForceN = 1000.0;

/// Why `curve` is no passive joint's holding force, or nullopt when it is one: its force must
/// rise with the angle everywhere in [min_deg, max_deg] (a joint resists being moved; the
/// least slope, at a range end or at the slope's vertex, must be positive and finite), and its
/// magnitude must stay within kMaxHoldingForceN there. The reason names the angle and the value
/// at fault; callers add which axis or file it is. A patient case (config) and a JointModel
/// from the network (wire) are held to it; the live refit publishes only curves that rise.
std::optional<std::string> passiveCurveProblem(const CubicCurve& curve);

/// A closed interval of angles, degrees; holds no NaN.
struct DegreeBounds {
  double lo = 0.0, hi = 0.0;
  constexpr bool contains(double deg) const noexcept { return deg >= lo && deg <= hi; }
};
/// Where an axis's range ends may lie: CubicCurve::min_deg within kRangeMinDegBounds,
/// max_deg within kRangeMaxDegBounds. A patient case file is held to them (config) and so is
/// a JointModel from the network (wire): a joint past them (or not finite) is no MCP joint,
/// and its rest angle, energy budget and range-runaway check would not be either.
constexpr DegreeBounds kRangeMinDegBounds{-90.0, 90.0};
constexpr DegreeBounds kRangeMaxDegBounds{0.0, 120.0};

/// Stiffness of the end-of-range wall beyond [min_deg, max_deg], N/deg at reference scale:
/// 1 N/deg at 1 cm is 1.4 N/mm after the 1:4 device scale, under the 2 N/mm that a 1 kHz
/// loop renders stably (docs/facts.md "Stable wall").
constexpr double kWallNPerDeg = 1.0;

/// The damping b at which a mass `mass_kg`, damped through a loop of period `period_s` whose
/// force acts `delay_ticks` ticks after the velocity it is computed from, stops being damped
/// and starts ringing: v(k+1) = v(k) − (b·T/m)·v(k−d) has roots on the unit circle at
/// b·T/m = 2·sin(π / (2(2d + 1))) (2 for d = 0, 1 for d = 1, 0.618 for d = 2; Levin & May
/// 1976, docs/facts.md "Damping cap"). 0 when the mass or the period is not positive.
double stableDampingNsPerM(double mass_kg, int delay_ticks, double period_s) noexcept;

/// The share of a device's damping limit (stableDampingNsPerM with its lightest mass, and its
/// command delay plus the tick the rendered velocity is old) the joint model may render; the
/// passivity controller keeps to 0.4 of it besides (PassivityConfig::stability_margin), so
/// that both together stay under the limit.
constexpr double kJointDampingShare = 0.5;

/// Largest damping the joint model puts on the device, N·s/m per unit lever speed: half the
/// discrete stability limit of a damper rendered on ~50 g at 1 kHz (m / T = 50 N·s/m), so
/// that the passivity controller's own bound (20 N·s/m) still fits under the limit on top of
/// it (docs/facts.md "Damping cap"). With the 1 cm lever and the 1:4 scale: 0.01 N·m·s/rad.
/// A lighter or slower device lowers it (JointModel::setDeviceDampingCap).
constexpr double kMaxDeviceDampingNsPerM = 25.0;

/// Fingertip force split (JointModel::fingertipForces): the load along the pinch line goes to
/// the finger whose pad faces against it, blended over kSplitBlendN so that the forces stay
/// continuous when it reverses; the other finger takes only what exceeds kFingerLoadN
/// (docs/facts.md "Force split").
constexpr double kSplitBlendN = 0.25;
constexpr double kFingerLoadN = 3.6;

/// The MCP Euler convention as free functions (joint frame, no joint model needed):
/// R = Ry(angles[kFlexion]) · Rx(angles[kAxial]) · Rz(angles[kAbduction]).
Mat3 eulerToRotation(const Vec3& angles_rad) noexcept;
Vec3 eulerFromRotation(const Mat3& r) noexcept;
/// Columns e_alpha, e_beta, e_gamma: the joint-frame axes that the angle rates turn about
/// (omega = E · rates) and that the per-axis torques act about (tau_i = e_i · tau).
Mat3 eulerAxisBasis(const Vec3& angles_rad) noexcept;

/// A lesson's haptic guidance (docs/lessons.md "Feel"): a bounded virtual spring in joint space
/// that leads the rendered joint along one period of the demonstration's MCP angles, repeated.
/// The grip follows the phalanx, so this is the demonstration's thimble path on the student's
/// grip. Rendered by the client's proxy on top of the passive torque, through the same
/// passivity guard and safety gate; the server's hand ignores it (it is not the joint's).
struct GuideParams {
  static constexpr int kPoints = 64;
  /// Largest stiffness and force a guide may ask for (wire validation): 2 N/deg at 1 cm is
  /// 2.9 N/mm after the 1:4 scale, still under the 1 kHz loop's stable wall with the joint's.
  static constexpr double kMaxStiffnessNPerDeg = 2.0;
  static constexpr double kMaxForceN = 16.0;
  /// The spring's damping on the angle rate error, as a time constant: stiffness · this.
  static constexpr double kDampingS = 0.005;
  double authority = 0.0;            ///< 0 (none) .. 1 (full): scales the whole guide force
  double period_s = 0.0;             ///< one period of the demonstration's oscillation
  double stiffness_n_per_deg = 0.5;  ///< reference scale, force at the lever arm per degree
  double max_force_n = 8.0;          ///< bound on each axis' guide force (reference scale)
  std::array<Vec3, kPoints> path_rad = zeroPath();  ///< MCP angles over one period, evenly in time
  bool active() const noexcept { return authority > 0.0 && period_s > 0.0; }
  static std::array<Vec3, kPoints> zeroPath() noexcept {
    std::array<Vec3, kPoints> a;
    for (Vec3& v : a) v.setZero();
    return a;
  }
  bool operator==(const GuideParams&) const = default;
};

/// Everything the server owns and publishes about one joint (JointModel on the wire).
struct JointModelParams {
  uint32_t version = 0;
  std::array<CubicCurve, kAxes> axes{};
  double lever_arm_m = 0.01;         ///< paper: forces measured about 1 cm from the centre
  double force_scale = 0.25;         ///< device force / reference force, paper: 1:4
  double damping_nms_per_rad = 0.0;  ///< viscous term, reference scale
  /// Half width of a zero-force band around each axis' rest angle (a lax joint), degrees.
  std::array<double, kAxes> neutral_zone_deg{};
  /// Protective spasm (velocity-dependent tone): while the joint is being stretched (moved
  /// the way its holding force resists), it resists with an added damping of speed_gain ·
  /// |elastic torque| N·m·s/rad: the resistance to stretch grows with the speed and with how
  /// far the joint is stretched, and never pushes (see passiveTorqueNm).
  double speed_gain_s_per_rad = 0.0;
  Vec3 joint_origin_m = Vec3::Zero();
  Quat joint_orientation = Quat::Identity();
  std::array<char, 64> case_name{};
  /// Data-driven stiffness (STIFFNESS_KNN): when set, the passive torque inside the ranges
  /// comes from these samples instead of the cubics; the end-of-range walls and the damping
  /// stay. Not owned: whoever publishes the model keeps it alive while it can be rendered.
  const KnnTorqueModel* knn = nullptr;
  /// The server's drift correction (server/session/drift.h), per axis: added to the angles
  /// the thimbles imply (anglesFromGrip) to give the angles the proxy renders, so that it
  /// renders the joint where the authoritative hand holds it. Zero without a server hand.
  Vec3 grip_offset_rad = Vec3::Zero();
  /// Largest correction a model may carry (wire validation; the server clamps well inside).
  static constexpr double kMaxGripOffsetDeg = 30.0;
  /// A lesson's guidance while the student is led (authority 0: none).
  GuideParams guide{};
  /// What the client's proxy renders: the joint (mobilization) or the web (massage, `tissue`).
  Technique technique = Technique::kMobilization;
  TissueParams tissue{};

  bool operator==(const JointModelParams&) const = default;
};

/// The healthy index MCP of the paper: eqs. 3 (flexion), 4 (abduction), 5 (axial), with the
/// range of motion of docs/facts.md (flexion -45..90 deg, abduction ±20 deg) and, as a stated
/// assumption since no reliable figures exist, axial rotation -10 (pronation) .. +15 deg
/// (supination). Damping 0.002 N·m·s/rad: chosen so that viscous force stays under 5 % of
/// the passive force during a 3 Hz mobilization at the 1 cm lever arm.
JointModelParams healthyIndexMcp();

/// Pure functions of an immutable parameter set. No allocation, no exceptions.
class JointModel {
 public:
  explicit JointModel(const JointModelParams& params);
  const JointModelParams& params() const noexcept { return p_; }

  /// Reference-scale force (N at the lever arm) holding `axis` at `angle_rad`: the cubic,
  /// with the neutral zone cut out around the rest angle. Speed-independent.
  double holdingForceN(int axis, double angle_rad) const noexcept;

  /// Passive torque per axis at reference scale: the elastic part −F(angle)·lever (the
  /// restoring torque, speed-independent) plus a viscous part −c·rate that only ever resists
  /// the motion (its power −c·rate² is never positive), with
  ///   c = min(b + [stretching] · speed_gain · |F(angle)|·lever, maxDampingNmsPerRad()),
  /// where "stretching" means the rate points the way the elastic torque resists (the spasm's
  /// stretch reflex: Lance 1980, docs/facts.md "Spasm"). So the spasm's extra resistance grows
  /// linearly with speed, as a damper does, and is bounded by what the device renders stably.
  Vec3 passiveTorqueNm(const Vec3& angles_rad, const Vec3& rates_rad_s) const noexcept;

  /// The largest joint damping (N·m·s/rad, reference scale) this model renders: the one that
  /// puts the device damping cap (kMaxDeviceDampingNsPerM unless set lower) at the device
  /// through the lever arm and the force scale.
  double maxDampingNmsPerRad() const noexcept;
  /// Lower the device damping cap for a device that renders less (N·s/m per unit lever speed;
  /// kMaxDeviceDampingNsPerM at most, values that are not positive are ignored).
  void setDeviceDampingCap(double ns_per_m) noexcept;
  double deviceDampingCapNsPerM() const noexcept { return device_damping_cap_ns_per_m_; }

  /// MCP angles from the two thimble positions (device frame).
  Vec3 anglesFromGrip(const PerFinger<Vec3>& p_device_finger) const noexcept;
  /// The angles the proxy renders for these thimble positions: anglesFromGrip plus the
  /// server's drift correction (grip_offset_rad). The server compares its hand with these.
  Vec3 proxyAngles(const PerFinger<Vec3>& p_device_finger) const noexcept {
    return anglesFromGrip(p_device_finger) + p_.grip_offset_rad;
  }

  /// Thimble positions that pinch the phalanx at the lever arm with the given half width.
  PerFinger<Vec3> gripFromAngles(const Vec3& angles_rad, double half_width_m) const noexcept;

  /// Thimble orientation: z = pad normal (into the phalanx), x = the phalanx axis.
  Quat thimbleOrientation(int finger, const Vec3& angles_rad) const noexcept;

  /// Fingertip forces (device frame) that together exert `axis_torque` on the joint (forces on
  /// the fingers, as the phalanx would push them). The axial component is an equal and
  /// opposite couple; the net force across the pinch line is shared equally; the net force
  /// along the pinch line (flexion and extension) goes to the finger it presses into its pad:
  /// the thumb (dorsal side) when it points dorsally, the index (palmar side) when it points
  /// palmarly. Only what exceeds kFingerLoadN goes to the other finger, and the split blends
  /// to equal shares within ±kSplitBlendN of zero so that the forces stay continuous (their
  /// change is at most ~1.2 times that of the net force). Moving load along the pinch line
  /// is a pair of equal and opposite forces on the line between the pads: it has no moment,
  /// so the torque is exact whatever the split.
  PerFinger<Vec3> fingertipForces(const PerFinger<Vec3>& p_device_finger, const Vec3& angles_rad,
                                  const Vec3& axis_torque_nm) const noexcept;

  /// Per-axis torque that fingertip forces exert on the joint.
  Vec3 axisTorque(const PerFinger<Vec3>& p_device_finger, const Vec3& angles_rad,
                  const PerFinger<Vec3>& force_n) const noexcept;

  /// Orientation of the phalanx in the device frame for the given angles.
  Mat3 phalanxRotation(const Vec3& angles_rad) const noexcept;
  /// Inverse of phalanxRotation: angles from a phalanx orientation in the device frame.
  Vec3 anglesFromRotation(const Mat3& r_device_phalanx) const noexcept;
  /// Columns e_alpha, e_beta, e_gamma (device frame): the axes the per-axis torques act about.
  Mat3 axisBasis(const Vec3& angles_rad) const noexcept;
  /// The torque vector (device frame) whose generalized components are `axis_torque_nm`.
  Vec3 torqueVector(const Vec3& angles_rad, const Vec3& axis_torque_nm) const noexcept;

  /// Angle where the holding force is zero (the joint's rest angle on that axis), found by
  /// bisection over the curve's valid range; the nearest range end if none is inside.
  double restAngleRad(int axis) const noexcept;

  /// How far `angles_rad` lie past the model's range of motion, degrees, on the axis that is
  /// furthest out; 0 inside it (non-finite angles are the caller's to check).
  double rangeExcessDeg(const Vec3& angles_rad) const noexcept;

  /// Energy the passive joint stores at `angles_rad` (the work done against the holding
  /// forces from the rest angles), at device scale in joules: zero at rest, never negative.
  double potentialEnergyJ(const Vec3& angles_rad) const noexcept;
  /// Where the guide leads the joint `t_s` into its period (linear between path points,
  /// periodic), and the path's angle rates there.
  Vec3 guideTargetRad(double t_s, Vec3* rates_rad_s = nullptr) const noexcept;
  /// The guide's torque per axis at reference scale, `t_s` after it started: per axis
  /// authority · clamp(k · (target − angle) + k · kDampingS · (target rate − rate), ±max force)
  /// at the lever arm. Zero without an active guide.
  Vec3 guideTorqueNm(const Vec3& angles_rad, const Vec3& rates_rad_s, double t_s) const noexcept;

 private:
  /// The viscous part for one axis given its elastic torque (see passiveTorqueNm).
  double viscousTorqueNm(double elastic_nm, double rate_rad_s) const noexcept;

  JointModelParams p_;
  std::array<double, kAxes> rest_deg_{};  // of the cubic alone, where the neutral zone centres
  double device_damping_cap_ns_per_m_ = kMaxDeviceDampingNsPerM;
};

/// What the proxy renders on one tick.
struct ProxyOutput {
  Vec3 angles_rad = Vec3::Zero();
  Vec3 torque_ref_nm = Vec3::Zero();  ///< passive torque, reference scale
  Vec3 guide_ref_nm = Vec3::Zero();   ///< a lesson guide's torque, reference scale (in the forces)
  PerFinger<Vec3> force_device_n{Vec3::Zero(), Vec3::Zero()};  ///< before the safety gate
  bool blending = false;
  /// This tick's force change due to the model update alone (blend weight change times the
  /// gap between the two models' forces), device N, largest finger.
  double update_step_n = 0.0;
  /// Energy the blend added to the rendered joint this tick (device J; negative: released).
  double blend_energy_j = 0.0;
  /// The part of blend_energy_j the energy budget did not pay for: only a fade that waited
  /// out kEnergyWaitNs adds any (device J).
  double unpaid_energy_j = 0.0;
  /// Energy the rendered joint stores at these angles (device J), see potentialEnergyJ.
  double potential_j = 0.0;
};

/// The client's local stand-in for the joint: renders at 1 kHz from the latest model the
/// server published, and fades to a new version so that an update causes no force step and
/// injects no energy. The fade weight moves toward the new model by at most `dt / blend_ns`
/// per tick, less when a tick's force change from the update would exceed
/// max(kUpdateStepFraction · force, kUpdateStepFloorN), and only as far as the energy budget
/// (setEnergyBudget) pays for what a stiffer model stores, for at most kEnergyWaitNs (then
/// the passivity controller is the safety net). A version that arrives during a
/// fade waits until the fade ends (the newest wins). Allocation-free.
class JointProxy {
 public:
  explicit JointProxy(const JointModelParams& initial, int64_t blend_ns = 200'000'000);

  /// Adopt a new model version: its fade starts at the next render that is not already
  /// fading (the newest version received wins; one equal to the present model is no change).
  void setModel(const JointModelParams& next) noexcept;
  uint32_t version() const noexcept { return current_.params().version; }
  const JointModel& model() const noexcept { return current_; }
  bool blending() const noexcept { return blending_; }
  /// The k-nearest-neighbour models this proxy may still read: the rendered version's, the
  /// one fading out, the one waiting for the fade to end (null where there is none).
  std::array<const KnnTorqueModel*, 3> knnInUse() const noexcept {
    return {current_.params().knn, blending_ ? previous_.params().knn : nullptr,
            have_pending_ ? pending_.params().knn : nullptr};
  }

  /// The device's damping cap (JointModel::setDeviceDampingCap) for every version rendered,
  /// the ones fading and those still to come.
  void setDeviceDampingCap(double ns_per_m) noexcept;

  /// Energy (device J) a fade may add to the joint on the next render; the loop passes what
  /// its passivity observer has seen dissipated. Infinite by default (no gating).
  void setEnergyBudget(double joules) noexcept { energy_budget_j_ = joules; }

  /// One tick: thimble positions -> angles -> passive torque -> device fingertip forces.
  ProxyOutput render(const PerFinger<Vec3>& p_device_finger, int64_t now_ns) noexcept;

  /// No tick's force may change by more than this share of the force, or the floor, because
  /// of a model update (the force JND is 7-10 %, docs/facts.md "Rendering and perception").
  static constexpr double kUpdateStepFraction = 0.05;
  static constexpr double kUpdateStepFloorN = 0.1;
  /// The largest force step (N) an update may cause on a tick rendering `force_n`.
  static constexpr double updateStepBoundN(double force_n) noexcept {
    return std::max(kUpdateStepFraction * force_n, kUpdateStepFloorN);
  }
  /// How long a stiffer model waits for the energy budget before it fades in regardless.
  static constexpr int64_t kEnergyWaitNs = 2'000'000'000;

 private:
  ProxyOutput renderWith(const JointModel& m, const PerFinger<Vec3>& p, const Vec3& angles,
                         const Vec3& rates, double guide_t_s) const noexcept;
  void startFade(int64_t now_ns) noexcept;

  JointModel current_;
  JointModel previous_;
  JointModel pending_;
  bool have_pending_ = false;
  int64_t blend_ns_;
  double weight_ = 1.0;  // of current_ against previous_
  bool blending_ = false;
  int64_t fade_ns_ = 0;  // time the weight was last advanced to
  int64_t fade_start_ns_ = 0;
  double energy_budget_j_ = 1e300;
  bool have_last_ = false;
  int64_t last_ns_ = 0;
  Vec3 last_angles_ = Vec3::Zero();
  Vec3 rates_ = Vec3::Zero();
  double device_damping_cap_ns_per_m_ = kMaxDeviceDampingNsPerM;
  int64_t guide_t0_ns_ = 0;       // when the guide's path (as rendered now) started
  int64_t prev_guide_t0_ns_ = 0;  // the same for the version being faded out
};

}  // namespace telehand
