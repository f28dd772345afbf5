#pragma once
/// The MF-2 device model: encoder counts -> joint angles -> thimble poses (forward
/// kinematics), fingertip forces -> actuator torques (Jacobian transpose), and raw FSR
/// readings -> newtons with fault flags (thimble calibration). Parameters come from a device
/// file (deploy/devices/mf2.toml) and one calibration file per thimble.
///
/// Kinematics (paper section II.A, docs/facts.md "MF-2"): 7 actuators, 13 DoF. Actuator 0 is the
/// redundant base joint shared by both fingers, a rotation q_b about the device z axis
/// through `base_pivot_m`. Each finger then has a yaw joint q_y about z at its own pivot
/// (`yaw_pivot_m`, carried by the base), and a planar five-bar in the vertical plane of the
/// yaw direction: two cranks (q_1, q_2) pivoting at ±`crank_half_spacing_m` along the plane's
/// horizontal axis u, angles measured from +u toward +z; their distal links meet at the
/// gimbal centre P, where the three gimbal axes intersect and the fingertip force acts. The
/// gimbal (3 measured angles g_1..g_3, axes z-y-x) hangs from the first distal link.
///   p_f = c + Rz(q_b) (o_f + Rz(q_y) (u e_x + w e_z)),  (u, w) = fiveBar(q_1, q_2)
///   R_f = Rz(q_b + q_y) Ry(-psi) Rz(g_1) Ry(g_2) Rx(g_3) R_mount,  psi = pitch of link B1->P
/// Actuator order: 0 base, 1..3 thumb (yaw, crank 1, crank 2), 4..6 index (same).
///
/// Real-time use: every method of Mf2Kinematics and ThimbleCalibration is allocation-free
/// and noexcept; FsrMonitor keeps fixed-size state. Loading files throws ConfigError.
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "telehand/core/math.h"
#include "telehand/core/thimble.h"

namespace telehand::mf2 {

constexpr int kActuators = 7;
constexpr int kGimbalAxes = 3;
constexpr int kFsrPerThimble = 4;

/// Index of actuator `joint` (0 = yaw, 1 = crank 1, 2 = crank 2) of `finger`.
constexpr int actuatorIndex(int finger, int joint) { return 1 + 3 * finger + joint; }

using ActuatorAngles = Eigen::Matrix<double, kActuators, 1>;
using ActuatorTorques = Eigen::Matrix<double, kActuators, 1>;
/// d(p_thumb, p_index) / d(actuator angles): 6 x 7.
using Jacobian = Eigen::Matrix<double, 6, kActuators>;

/// All joint angles of the device, radians.
struct JointAngles {
  ActuatorAngles actuators = ActuatorAngles::Zero();
  PerFinger<Vec3> gimbal{Vec3::Zero(), Vec3::Zero()};
};

/// Raw encoder readings as a driver reads them.
struct EncoderCounts {
  std::array<int64_t, kActuators> actuators{};
  PerFinger<std::array<int64_t, kGimbalAxes>> gimbal{};
};

/// angle = (counts - zero_counts) / counts_per_rad; a negative counts_per_rad reverses the
/// encoder's direction. Angles outside [min_rad, max_rad] are mechanically impossible.
struct EncoderCalibration {
  double counts_per_rad = 1.0;
  int64_t zero_counts = 0;
  double min_rad = -kPi;
  double max_rad = kPi;

  double angle(int64_t counts) const noexcept {
    return static_cast<double>(counts - zero_counts) / counts_per_rad;
  }
  int64_t counts(double angle_rad) const noexcept {
    return zero_counts + static_cast<int64_t>(std::llround(angle_rad * counts_per_rad));
  }
};

/// One finger's linkage. Lengths in metres, in the frame that the base joint rotates.
struct FingerLinkage {
  Vec3 yaw_pivot_m = Vec3::Zero();      ///< relative to the base pivot, at q_b = 0
  double crank_half_spacing_m = 0.015;  ///< the cranks pivot at u = -/+ this
  std::array<double, 2> crank_m{0.10, 0.10};
  std::array<double, 2> distal_m{0.12, 0.12};
  Quat gimbal_mount = Quat::Identity();  ///< thimble frame at zero gimbal angles
};

/// Fault flags of one FSR channel.
enum FsrFault : uint8_t {
  kFsrOk = 0,
  kFsrSaturated = 1,  ///< at or above the amplifier/ADC ceiling: the force is a lower bound
  kFsrDead = 2,       ///< no signal (open or shorted channel): the reading means nothing
};

/// One FlexiForce A201 channel. The A201's conductance is close to linear in force
/// (Tekscan); the conditioning amplifier makes the ADC reading linear in conductance:
///   counts = zero_counts + counts_per_n * F
/// fitted per sensor against a reference load cell (the paper used an ATI F/T sensor).
struct FsrCalibration {
  double zero_counts = 0.0;         ///< reading with no load
  double counts_per_n = 100.0;      ///< slope of counts over force
  double saturation_counts = 4000;  ///< at or above: kFsrSaturated
  double floor_counts = -1.0;       ///< at or below: no conduction at all (open channel)

  double forceN(double counts) const noexcept { return (counts - zero_counts) / counts_per_n; }
  double countsFor(double force_n) const noexcept { return zero_counts + counts_per_n * force_n; }
};

/// The four sensors of one thimble; sensor i+1 of the paper is index i.
struct ThimbleCalibration {
  std::string serial;
  std::string source;  ///< how and when it was calibrated
  std::array<FsrCalibration, kFsrPerThimble> fsr{};
  /// A channel whose reading does not change by a single count for this many consecutive
  /// samples is dead: a powered A201 channel always shows at least one count of ADC noise.
  uint32_t stuck_samples = 500;
};

/// Calibrated thimble readings.
struct ThimbleReading {
  FsrReadings fsr_n{};  ///< newtons, clamped at 0 (FSRs only sense pressure)
  std::array<uint8_t, kFsrPerThimble> fault{};  ///< FsrFault bits per sensor
  ThimbleForces forces;                         ///< paper eqs. 1-2
  bool tangential_valid = true;                 ///< sensors 2 and 3 are healthy
  bool normal_valid = true;                     ///< sensors 1 and 4 are healthy
  uint8_t faultMask() const noexcept;           ///< bit i: sensor i+1 is flagged
};

/// Per-sample calibration plus the stateful stuck-channel detector of one thimble.
class FsrMonitor {
 public:
  explicit FsrMonitor(const ThimbleCalibration& cal) : cal_(cal) {}
  /// Convert raw ADC counts, flag saturated and dead channels. Allocation-free.
  ThimbleReading update(const std::array<uint16_t, kFsrPerThimble>& counts) noexcept;
  const ThimbleCalibration& calibration() const noexcept { return cal_; }

 private:
  ThimbleCalibration cal_;
  std::array<uint16_t, kFsrPerThimble> last_{};
  std::array<uint32_t, kFsrPerThimble> same_{};
  bool have_last_ = false;
};

/// Calibrate one sample without history (saturation and open-channel floor only).
ThimbleReading calibrateThimble(const ThimbleCalibration& cal,
                                const std::array<uint16_t, kFsrPerThimble>& counts) noexcept;

/// Everything a device file states.
struct Mf2Description {
  std::string name = "mf2";
  std::string source;  ///< where the numbers come from
  std::string path;    ///< the file it was loaded from (empty: built in)
  Vec3 base_pivot_m{-0.16, 0.0, -0.05};
  PerFinger<FingerLinkage> fingers{};
  std::array<EncoderCalibration, kActuators> actuator_encoders{};
  PerFinger<std::array<EncoderCalibration, kGimbalAxes>> gimbal_encoders{};
  ActuatorTorques max_torque_nm = ActuatorTorques::Constant(0.5);  ///< per actuator, joint side
  PerFinger<ThimbleCalibration> thimbles{};
  PerFinger<std::string> thimble_files{};  ///< calibration file paths as loaded
};

/// The built-in description (the values of deploy/devices/mf2.toml).
Mf2Description defaultMf2();

/// Load a device file; thimble calibration files are resolved relative to it.
Mf2Description loadMf2Description(const std::string& path);
Mf2Description parseMf2Description(const std::string& text, const std::string& origin,
                                   const std::string& base_dir);
ThimbleCalibration loadThimbleCalibration(const std::string& path);
ThimbleCalibration parseThimbleCalibration(const std::string& text, const std::string& origin);

/// The files a description was loaded from (device file, then the thimble calibrations),
/// named "device/<file>" and "thimble/<file>", as a capture session keeps them; a built-in
/// description gives one note instead. ConfigError when a file cannot be read.
struct NamedFile {
  std::string name;
  std::string content;
};
std::vector<NamedFile> descriptionFiles(const Mf2Description& d);

/// One thimble's pose, device frame.
struct ThimblePose {
  Vec3 position_m = Vec3::Zero();  ///< gimbal centre: where the fingertip force acts
  Quat orientation = Quat::Identity();
};

/// Pure functions of an immutable description.
class Mf2Kinematics {
 public:
  explicit Mf2Kinematics(const Mf2Description& d);
  const Mf2Description& description() const noexcept { return d_; }

  JointAngles anglesFromCounts(const EncoderCounts& c) const noexcept;
  EncoderCounts countsFromAngles(const JointAngles& q) const noexcept;
  /// False when an angle is outside its range or the five-bar cannot close.
  bool withinLimits(const JointAngles& q) const noexcept;

  /// Forward kinematics of both thimbles; false (poses untouched) when a five-bar cannot
  /// close (its distal links cannot meet: bad encoder data).
  bool forward(const JointAngles& q, PerFinger<ThimblePose>& out) const noexcept;
  /// d p / d q over the 7 actuators. Columns of the other finger's joints are zero.
  bool jacobian(const ActuatorAngles& q, Jacobian& out) const noexcept;
  /// Actuator torques that render fingertip forces: tau = J^T F (virtual work).
  bool actuatorTorques(const ActuatorAngles& q, const PerFinger<Vec3>& force_n,
                       ActuatorTorques& out) const noexcept;
  /// The fingertip forces that actuator torques render (least-squares inverse of J^T; the
  /// base joint is redundant, so torques outside the range of J^T are not rendered).
  bool fingertipForces(const ActuatorAngles& q, const ActuatorTorques& tau,
                       PerFinger<Vec3>& out) const noexcept;

  /// Inverse kinematics with the base joint held at `base_rad` (the simulated device and
  /// tests): actuator and gimbal angles that put the thimbles at `target`. False when a
  /// position is out of reach.
  bool inverse(const PerFinger<ThimblePose>& target, double base_rad,
               JointAngles& out) const noexcept;

 private:
  struct FiveBar {
    double u, w;           // gimbal centre in the plane
    double psi;            // pitch of distal link 1
    Eigen::Matrix2d dpdq;  // d(u, w) / d(q1, q2)
  };
  bool fiveBar(int finger, double q1, double q2, FiveBar& out) const noexcept;

  Mf2Description d_;
};

}  // namespace telehand::mf2
