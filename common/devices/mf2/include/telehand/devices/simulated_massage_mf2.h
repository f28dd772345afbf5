#pragma once
/// A simulated MF-2 whose virtual operator performs the paper's circular massage of the web
/// between thumb and index (docs/massage.md): the index on the palmar surface, the thumb on
/// the dorsal one, each pressing along the web's normal with about 10 N at reference scale
/// while both move their contact point together on a small circle, against the friction of
/// the skin. Deterministic for a given seed and clock. The operator's skill (OperatorConfig:
/// force_bias_n, frequency_error_hz, amplitude_scale on the radius, tremor_n, seed) makes it
/// a student; at their defaults it is the clinician.
///
/// Each thimble is a point mass (finger, thimble and links) moved by the operator's hand and
/// by what acts on the thimble from outside: the force the device renders, or in a capture
/// (setPatient) the real web, with the actuators off. The hand presses along the normal with
/// a force it controls (the plan's press, a slow wander, the bias, the tremor) and a little
/// damping, and drives the contact point along the circle with a stiff-ish impedance
/// (spring and damper to the moving target, plus the feed-forward of its own inertia).
/// Friction drags against it; a skilled hand learns that drag over a few laps and pushes
/// through it (an integral of the error in the target's turning frame), so the circle comes
/// out at the size it means.
///
/// Scale: a capture measures the real web, at reference scale; rendered, the operator
/// presses the device with force_scale of the reference force and the hand's impedance
/// scaled alike (the same hand in a world scaled 1:4), the mass unscaled.
///
/// The FSRs measure what the fingers press on their thimbles, the hand's force, as the
/// mobilization's SimulatedMf2 does (the moving mass sits on the device's side of the
/// sensors): in a capture that is the web's push back up to the mass's acceleration. The
/// device model (encoder quantization, FSR calibration, actuator rendering) is
/// SimulatedMf2Hardware. read() and write() allocate nothing.
#include <array>
#include <atomic>
#include <cstdint>
#include <vector>

#include "telehand/config/config.h"
#include "telehand/core/clock.h"
#include "telehand/core/tissue_model.h"
#include "telehand/devices/device.h"
#include "telehand/devices/mf2_device.h"
#include "telehand/devices/simulated_hardware.h"

namespace telehand::devices {

/// The massage the clinician performs: what a skill departs from.
struct MassagePlan {
  double normal_force_n = 10.0;  ///< each finger's press, reference scale (paper: 10 ± 2 N)
  /// The press wanders slowly: two sines of equal amplitude, at 0.7 and 1.3 times
  /// wander_hz, with phases drawn from the seed; their sum has this RMS (reference N).
  double wander_n = 0.7;
  double wander_hz = 0.3;
  double radius_m = 0.006;        ///< of the contact point's circle (times amplitude_scale)
  double frequency_hz = 1.5;      ///< laps per second (plus frequency_error_hz)
  bool counter_clockwise = true;  ///< seen from the dorsal side (down the web's −z)
  double centre_x_m = 0.0;        ///< the circle's centre on the web, web frame
  double centre_y_m = 0.0;
  /// The press and the circling speed build up over this (smoothRamp), from rest on the
  /// circle's start point (angle 0: +x of the centre) at the surface.
  double ramp_s = 0.5;
};

/// A capture's characterisation of the web before the massage (docs/capture.md "The
/// capture protocol"), as a clinician examining tissue does, the thumb and index together:
///  - indentations: from just above the skin to a depth (or to indent_max_force_n, whichever
///    comes first) and back out, each at its own spot, depth and speed, the hand driving the
///    depth (the stiffness, its exponent and the damping λ: the force at many depths and
///    depth rates);
///  - strokes: back and forth along a line at a light press and a fast pace, each with its
///    own press, speed and direction (the skin's viscous drag apart from its friction: b·v
///    does not grow with the press, mu·F does not grow with the speed);
/// then the plan's circles.
struct MassageCaptureProtocol {
  double indent_s = 16.0;
  double stroke_s = 12.0;
  double indent_depth_m[2] = {0.004, 0.012};  ///< aimed at, drawn per indentation
  /// The hand presses no harder: the MF-2's pad FSR saturates at about 22.5 N (4000 counts
  /// at the default calibration), 24 N along the pad normal.
  double indent_max_force_n = 20.0;
  double indent_speed_m_s[2] = {0.08, 0.3};  ///< peak depth rate in and out (log-uniform)
  double indent_hold_s[2] = {0.02, 0.1};
  double indent_air_s[2] = {0.04, 0.1};
  double air_gap_m = 0.002;                  ///< how far above the skin between indentations
  double spot_m = 0.008;                     ///< indentation spots within ± this of the centre
  double press_stiffness_n_per_m = 10000.0;  ///< the hand along the normal while indenting
  double stroke_force_n[2] = {0.5, 2.5};     ///< press per stroke contact
  double stroke_speed_m_s[2] = {0.15, 0.5};  ///< peak speed per stroke contact
  double stroke_half_m = 0.011;              ///< half length of the stroke
  double stroke_contact_s[2] = {1.5, 2.5};
  uint64_t seed = 1;
};

/// The hand and the moving mass, per thimble; impedances at reference scale.
struct SimulatedMassageDynamics {
  double mass_kg = 0.05;                 ///< finger + thimble + link mass per thimble
  double hand_stiffness_n_per_m = 3000;  ///< tangential spring to the circle's target
  double hand_damping_n_s_per_m = 40.0;  ///< tangential damper to the target's velocity
  double press_damping_n_s_per_m = 20;   ///< along the normal: the press's own damping
  /// The hand learns the skin's drag: the tracking error, seen in the frame that turns with
  /// the target (along its radius and its direction of travel), is integrated with gain
  /// hand_stiffness / adapt_s into a force that pushes the fingers onto the circle. 0: a
  /// plain spring and damper, which friction pulls inside the circle.
  double adapt_s = 0.25;
  double pad_angle_deg = 20.0;  ///< how the normal load splits over FSRs 1 (end) and 4 (pad)
};

class SimulatedMassageMf2 final : public Device {
 public:
  /// `web`: where the operator finds the web (its geometry: origin, orientation, thickness,
  /// pad radius); rendered, `force_scale` is the device's share of the reference force.
  SimulatedMassageMf2(const TissueParams& web, const OperatorConfig& op, const Clock& clock,
                      double force_scale = 0.25, const MassagePlan& plan = {},
                      const SimulatedMassageDynamics& dyn = {},
                      const mf2::Mf2Description& device = mf2::defaultMf2());

  /// A real web between the fingers (capture): it pushes on the thimbles through
  /// tissueContact at reference scale, the operator presses at reference scale and the
  /// actuators are off (write() renders nothing). Call before the first read.
  void setPatient(const TissueParams& truth) noexcept;
  /// In a capture, characterise the web first (MassageCaptureProtocol), then massage it as
  /// the plan says. Call before the first read (it plans, and allocates).
  void setCaptureProtocol(const MassageCaptureProtocol& protocol);
  /// When the plan's circles start, s from the first read (0 without a protocol).
  double massageStartS() const noexcept { return massage_start_s_; }
  /// Thimble measurement error (the paper's 1.43 N): N(0, sigma^2) newtons at the sensor
  /// added to each finger's normal and to its side (tangential) force before they are split
  /// over the FSRs, independently per sample; the fingers move under the true force.
  void setForceNoise(double sigma_n) noexcept { force_noise_n_ = sigma_n; }

  /// Whether the operator massages (the default) or rests: the hands hold the fingers on the
  /// circle's start point and press nothing. Each start of the massage starts it afresh (the
  /// press and the circling build up again, the learned drag is forgotten): a lesson's
  /// trials. Any thread; takes effect at the next step.
  void setPerforming(bool on) noexcept { performing_.store(on, std::memory_order_release); }

  bool read(DeviceSample& out) noexcept override;
  bool write(const ForceCommand& cmd) noexcept override;
  DeviceStatus status() const noexcept override { return DeviceStatus::kOk; }
  std::string_view name() const noexcept override { return "sim-massage"; }
  /// Each thimble's mass; a force written now acts from the next step.
  DeviceDynamics dynamics() const noexcept override { return {dyn_.mass_kg, 0}; }

  // Ground truth for tests.
  bool capturing() const noexcept { return capturing_; }
  /// The force scale the operator works at: force_scale rendered, 1 in a capture.
  double operatorScale() const noexcept { return capturing_ ? 1.0 : force_scale_; }
  /// True thimble centres and velocities, device frame.
  const PerFinger<Vec3>& positions() const noexcept { return p_; }
  const PerFinger<Vec3>& velocities() const noexcept { return v_; }
  /// The press each finger means at time t (s from the start), reference scale: the plan's
  /// force plus force_bias_n plus the wander, built up over ramp_s. The tremor comes on top.
  double targetPressN(double t_s) const noexcept;
  /// Where the hand drives the contact point at time t: the circle's target in the web frame
  /// (x, y; z = 0).
  Vec3 targetPointW(double t_s) const noexcept;
  /// The circle the operator means: radius (radius_m · amplitude_scale) and laps per second
  /// (frequency_hz + frequency_error_hz, positive counter-clockwise from the dorsal side).
  double targetRadiusM() const noexcept { return radius_m_; }
  double targetFrequencyHz() const noexcept { return freq_hz_; }
  /// The force each hand exerts on its thimble (device frame, the operator's scale).
  const PerFinger<Vec3>& operatorForce() const noexcept { return operator_force_; }
  /// Force rendered at each thimble after the actuators (device frame).
  const PerFinger<Vec3>& renderedForce() const noexcept { return hw_.rendered(); }
  /// The real web's contact on each finger in a capture (last step), reference scale.
  const PerFinger<TissueContact>& patientContact() const noexcept { return contact_; }
  const TissueModel& web() const noexcept { return web_; }
  const mf2::Mf2Kinematics& kinematics() const noexcept { return hw_.kinematics(); }

 private:
  struct Phase {
    double angle, rate, accel;  // rad, rad/s, rad/s^2 of the target on its circle
  };
  Phase phaseAt(double t_s) const noexcept;
  /// One indentation or stroke contact of the protocol.
  struct Step {
    double start_s = 0.0, in_s = 0.0, hold_s = 0.0, out_s = 0.0, end_s = 0.0;
    double x = 0.0, y = 0.0;  ///< spot (indentation) or the stroke's centre, web frame
    double depth_m = 0.0;     ///< indentation
    double force_n = 0.0, omega = 0.0, dir = 0.0, half_m = 0.0;  ///< stroke
  };
  /// What the hand aims at during the protocol (t_s < massage_start_s_): along the normal a
  /// depth (indenting) or a press; across it a point on the web.
  struct Aim {
    bool depth_control = false;
    double depth = 0.0, depth_rate = 0.0, depth_accel = 0.0, press = 0.0;
    Vec3 point = Vec3::Zero(), velocity = Vec3::Zero(), accel = Vec3::Zero();
  };
  Aim protocolAim(double t_s) const noexcept;
  void advanceTo(int64_t t_ns) noexcept;
  void integrate(double dt) noexcept;

  TissueModel web_;  // where the operator aims
  TissueModel patient_{TissueParams{}};
  bool capturing_ = false;
  PerFinger<TissueAnchor> anchor_{};
  PerFinger<TissueContact> contact_{};
  OperatorConfig op_;
  const Clock& clock_;
  double force_scale_;
  MassagePlan plan_;
  SimulatedMassageDynamics dyn_;
  double radius_m_, freq_hz_;
  std::array<double, 2> wander_phase_{};
  PerFinger<Quat> thimble_;  // fixed: x along the web, z into it
  SimulatedMf2Hardware hw_;
  GaussianNoise noise_;  // FSR and thimble noise
  // Tremor: its own generator (sensor noise is the same with or without it), one 8-12 Hz
  // band-pass per finger and web axis (x, y, normal).
  GaussianNoise tremor_noise_;
  PerFinger<std::array<TremorFilter, 3>> tremor_;
  double force_noise_n_ = 0.0;

  bool reading_ = false;  // the first read() starts the clinician's time
  std::atomic<bool> performing_{true};
  bool was_performing_ = true;
  int64_t start_ns_;
  int64_t sim_ns_;
  uint64_t seq_ = 0;
  PerFinger<Vec3> p_{Vec3::Zero(), Vec3::Zero()};
  PerFinger<Vec3> v_{Vec3::Zero(), Vec3::Zero()};
  PerFinger<Vec3> sampled_p_{Vec3::Zero(), Vec3::Zero()};  // where the last step's forces were
  PerFinger<Vec3> operator_force_{Vec3::Zero(), Vec3::Zero()};
  PerFinger<std::array<double, 2>> learned_{};  // radial, along travel (reference N)
  MassageCaptureProtocol protocol_;
  std::vector<Step> indents_, strokes_;
  double massage_start_s_ = 0.0;
};

}  // namespace telehand::devices
