#pragma once
/// The soft tissue of the thumb–index web (the paper's circular massage, docs/massage.md), as
/// both the client proxy and the server compute it: with the same samples both give the same
/// forces, as the joint model does for the mobilization.
///
/// Geometry. The web is a slab in its own frame W (origin and orientation given in the device
/// frame): z dorsal (out of the back of the hand), x distal along the web, y = z × x. The
/// operator's thumb presses on the dorsal surface (from +z), the index on the palmar surface
/// (from −z). A thimble touches its surface when its centre comes within the pad radius of it:
/// the depth is how far the centre is past that point, along the surface normal.
///
/// Normal force (Hunt & Crossley 1975): F_n = k·δ^n·(1 + λ·δ̇) for depth δ > 0, never
/// pulling: a stiffness that grows with the depth (n > 1) and a damping that grows with it
/// too, so that touching the surface gives no force step (docs/facts.md "Soft tissue").
///
/// Tangential force: Coulomb friction with stick–slip, rendered as an elastic anchor that the
/// skin drags along (Hayward & Armstrong 2000): while the tangential spring's force stays under
/// mu_static·F_n the skin sticks and the spring (the skin's lateral stiffness) pulls the
/// finger back toward the anchor; past it the anchor slips to where the spring pulls with
/// mu_kinetic·F_n. A viscous part −b·v (skin on fascia) adds to it while in contact. The
/// anchor is the only state; it is why the proxy is a class and not a function.
///
/// A patch (scar or adhesion) multiplies the stiffness and the friction coefficients inside a
/// disc of the surface, blended over its rim so that no force steps at it; the rim pushes a
/// pressing finger out of the stiffer patch (the slope of the energy it stores), which keeps
/// the web passive.
///
/// Forces at reference scale (N, device frame); the device gets force_scale of them.
/// Allocation-free, noexcept (but for TissueProxy::saveState, a checkpoint's).
#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "telehand/core/math.h"

namespace telehand {

/// Which technique a session renders: the MCP mobilization (joint model) or the massage of the
/// web (tissue model). The wire carries it in JointModel.
enum class Technique : uint8_t { kMobilization = 0, kMassage = 1 };
const char* techniqueName(Technique t) noexcept;
/// "mobilization" / "massage"; false for anything else.
bool parseTechnique(const char* text, Technique* out) noexcept;

struct TissueParams {
  // Geometry (device frame).
  Vec3 origin_m = Vec3::Zero();         ///< centre of the web's mid-surface
  Quat orientation = Quat::Identity();  ///< web frame W in the device frame
  double thickness_m = 0.012;           ///< dorsal to palmar surface, unloaded
  double pad_radius_m = 0.008;          ///< thimble centre to the skin it presses
  double half_extent_m = 0.02;          ///< contact area: |x|, |y| within this of the origin
  // Normal (Hunt–Crossley), reference scale.
  double stiffness_n_per_m_pow = 2.2e4;  ///< k: F = k·δ^n at rest
  double exponent = 1.5;                 ///< n
  double damping_s_per_m = 0.3;          ///< λ: F = k·δ^n·(1 + λ·δ̇)
  // Tangential (stick–slip with viscous skin), reference scale.
  double lateral_stiffness_n_per_m = 800.0;  ///< skin's tangential stiffness while it sticks
  double mu_static = 0.55;                   ///< sticks until |F_t| exceeds this · F_n
  double mu_kinetic = 0.4;                   ///< slips with |F_t| = this · F_n (≤ mu_static)
  double viscous_n_s_per_m = 2.0;            ///< b: −b·v while in contact
  // A stiffer, stickier disc (scar, adhesion); factor 1 = none.
  double patch_x_m = 0.0;
  double patch_y_m = 0.0;
  double patch_radius_m = 0.0;
  double patch_stiffness_factor = 1.0;  ///< multiplies k inside the patch
  double patch_friction_factor = 1.0;   ///< multiplies both mu (the skin sticks harder)
  double patch_rim_m = 0.002;           ///< blend width at the patch's edge

  bool operator==(const TissueParams&) const = default;

  /// Wire validation bounds (docs/security.md "Bounds"): a model outside them is refused.
  static constexpr double kMaxStiffness = 1e7;  ///< N/m^n
  static constexpr double kMinExponent = 1.0;
  static constexpr double kMaxExponent = 3.0;
  static constexpr double kMaxDamping = 5.0;     ///< s/m
  static constexpr double kMaxLateral = 5000.0;  ///< N/m: 1.25 N/mm on the device
  static constexpr double kMaxMu = 2.0;
  static constexpr double kMaxViscous = 50.0;  ///< N·s/m: 12.5 on the device
  static constexpr double kMaxPatchFactor = 10.0;
  /// The narrowest rim a patch that changes the web is blended over (invalidTissueParam).
  static constexpr double kMinPatchRimM = 0.001;
  /// A patch that changes the web (and so needs a rim of at least kMinPatchRimM).
  bool patchChangesWeb() const noexcept {
    return patch_radius_m > 0.0 && (patch_stiffness_factor != 1.0 || patch_friction_factor != 1.0);
  }
  static constexpr double kMaxLengthM = 0.1;
};

/// Names the first parameter that is not finite or out of bounds, or nullptr when they are all
/// usable (also mu_kinetic ≤ mu_static).
const char* invalidTissueParam(const TissueParams& p) noexcept;

/// The web cases (docs/massage.md "Cases"): healthy, oedema (swollen: thicker, softer at first
/// and stiffening sooner, more damping), scar (adhesion: a stiff, sticky patch), hypertonic
/// (raised tone: stiffer). Unknown names give healthy.
TissueParams tissueCase(const char* name) noexcept;

/// One thimble's contact on the web, reference scale.
struct TissueContact {
  double depth_m = 0.0;              ///< how far the pad is pressed into the skin (0: no contact)
  double depth_rate_m_s = 0.0;       ///< its rate (+ pressing in)
  Vec3 normal_n = Vec3::Zero();      ///< normal force on the finger, device frame
  Vec3 tangential_n = Vec3::Zero();  ///< friction force on the finger, device frame
  Vec3 point_w = Vec3::Zero();       ///< contact point in the web frame (x, y on the surface)
  bool sticking = false;
  Vec3 force() const noexcept { return normal_n + tangential_n; }
};

/// The model's pure parts.
class TissueModel {
 public:
  explicit TissueModel(const TissueParams& p = {}) noexcept : p_(p) {}
  const TissueParams& params() const noexcept { return p_; }

  /// Point in the web frame.
  Vec3 toWeb(const Vec3& p_device) const noexcept;
  Vec3 fromWeb(const Vec3& p_web) const noexcept;
  /// The device-frame direction of the web's normal (dorsal).
  Vec3 normalAxis() const noexcept;
  /// Depth of a thimble (0 thumb on the dorsal side, 1 index on the palmar side); ≤ 0: no
  /// contact.
  double depthOf(int finger, const Vec3& p_device) const noexcept;
  /// Patch weight at a surface point: 0 outside, 1 inside, smooth across the rim.
  double patchWeight(double x_m, double y_m) const noexcept;
  /// Its gradient over the surface (per metre; x, y; z = 0).
  Vec3 patchGradient(double x_m, double y_m) const noexcept;
  /// Hunt–Crossley normal force magnitude at a depth and depth rate, at surface point (x, y).
  double normalForceN(double depth_m, double depth_rate_m_s, double x_m = 0.0,
                      double y_m = 0.0) const noexcept;
  /// Energy the normal spring stores at a depth (reference J): k·δ^(n+1)/(n+1).
  double normalEnergyJ(double depth_m, double x_m = 0.0, double y_m = 0.0) const noexcept;
  /// The depth at which the static normal force is `force_n` (inverse of k·δ^n).
  double depthForForce(double force_n, double x_m = 0.0, double y_m = 0.0) const noexcept;

 private:
  TissueParams p_;
};

/// One thimble's friction state: the skin's anchor (web frame, x and y).
struct TissueAnchor {
  double x_m = 0.0, y_m = 0.0;
  bool attached = false;
};

/// Contact forces for one tick of one finger: advances the anchor. `v_device` is the thimble's
/// velocity (device frame). The shared step of the proxy and the server.
TissueContact tissueContact(const TissueModel& m, int finger, const Vec3& p_device,
                            const Vec3& v_device, TissueAnchor& anchor) noexcept;

/// What the tissue proxy renders on one tick.
struct TissueOutput {
  PerFinger<TissueContact> contact{};
  PerFinger<Vec3> force_device_n{Vec3::Zero(), Vec3::Zero()};  ///< before the safety gate
  bool blending = false;
  /// Energy the web stores now (normal springs and stuck skin), device J.
  double potential_j = 0.0;
};

/// The client's local web: the tissue model at 1 kHz from thimble positions, with the
/// velocity estimated from them, and a fade between parameter sets over `blend_ns` (the
/// forces of the two sets mixed, the anchors shared) so that an update makes no force step.
/// The server steps the same class with the samples it receives. Allocation-free.
class TissueProxy {
 public:
  explicit TissueProxy(const TissueParams& initial = {}, double force_scale = 0.25,
                       int64_t blend_ns = 200'000'000) noexcept;
  /// Adopt new parameters: faded in from the next render (no change if equal).
  void setParams(const TissueParams& next, double force_scale) noexcept;
  const TissueModel& model() const noexcept { return current_; }
  /// The thimbles' velocities as the last render estimated them (device frame).
  const PerFinger<Vec3>& velocities() const noexcept { return v_; }
  /// Forget the anchors and the velocity history (a session starts, a device resumes).
  void reset() noexcept;
  /// One tick at the sample's time.
  TissueOutput render(const PerFinger<Vec3>& p_device, int64_t t_ns) noexcept;
  /// Same with the velocities given (the server's samples, tests).
  TissueOutput renderWith(const PerFinger<Vec3>& p_device, const PerFinger<Vec3>& v_device,
                          int64_t t_ns) noexcept;

  /// Take one finger's state from the force another proxy rendered for the last sample
  /// rendered here (the client's, recorded with the sample; reference N, device frame): the
  /// depth rate in the velocity filter from its normal part (Hunt–Crossley inverted, within
  /// kMaxRateStepMps of this proxy's own), and the skin's anchor where the spring, with this
  /// proxy's velocity, gives its tangential part, the stretch held inside the static friction
  /// limit at the normal force (nothing the model could not reach itself). False, with
  /// nothing changed, when the finger is not on the web here, the force is not finite, the
  /// parameters are fading or the skin has no lateral stiffness. The next render() at the
  /// same sample gives the force with the new state.
  bool resync(int finger, const Vec3& force_device_n) noexcept;
  /// How far resync() may move the depth rate (m/s): a sample's normal force is taken where
  /// it lies within what the thimble's speed across a gap can explain.
  static constexpr double kMaxRateStepMps = 1.0;
  /// The last sample rendered again (as render() at its time; after resync()).
  TissueOutput renderLast() noexcept { return renderWith(last_p_, v_, last_ns_); }

  /// The proxy's state (anchors, velocity filter, fade, both parameter sets) appended to
  /// `out` as kStateSize doubles, for a checkpoint (docs/pool.md).
  static constexpr std::size_t kStateSize = 72;
  void saveState(std::vector<double>& out) const;
  /// Go on from a saveState(): false, with nothing changed, for anything else (a size, a
  /// number that is not finite or out of its bounds, parameters invalidTissueParam refuses).
  /// Saved under other parameters than the current ones, the proxy fades from those to the
  /// current ones, as setParams would have.
  bool restoreState(std::span<const double> state) noexcept;

 private:
  TissueModel current_;
  TissueModel previous_;
  double scale_;
  int64_t blend_ns_;
  bool blending_ = false;
  int64_t fade_start_ns_ = 0;
  bool fade_started_ = false;
  PerFinger<TissueAnchor> anchor_{};
  // Velocity: the difference of positions over the sample interval, low-passed (~150 Hz).
  bool have_last_ = false;
  int64_t last_ns_ = 0;
  PerFinger<Vec3> last_p_{Vec3::Zero(), Vec3::Zero()};
  PerFinger<Vec3> v_{Vec3::Zero(), Vec3::Zero()};
};

}  // namespace telehand
