#pragma once
/// Assessment by exploration (paper section V.B): the angle reached in each of the six
/// directions of the MCP and the force holding the joint there, per phase (a baseline, then a
/// reassessment after treatment), and how the reassessment compares.
///
/// A direction counts only a reach that went that way: the joint held by the pads (a released
/// finger swinging back is no reach) beyond both its rest angle and the pose the pads first
/// held in the phase by kMinExcursionDeg. So neither the start pose nor the swing to rest
/// before the pads close counts, and a direction never explored is not reached: finish()
/// leaves it out rather than reporting where the joint started.
///
/// Angles and forces are followed through a first-order filter (kSmoothingS) while the pads
/// hold: a reach is a pose the student holds, and the force at an instantaneous extreme is
/// the one braking the overshoot (at a lax reach, braking can exceed the holding force and
/// point the other way), not the one holding the joint.
#include <array>
#include <string>
#include <vector>

#include "telehand/core/math.h"
#include "telehand/server/store/store.h"

namespace telehand::server::session {

using store::EventRecord;
using store::SessionFile;
using store::SessionInfo;
using store::SessionStore;

class Exploration {
 public:
  /// Direction names, in the order finish() returns them.
  static constexpr std::array<const char*, 6> kDirections = {
      "flexion", "extension", "abduction", "adduction", "supination", "pronation"};
  /// Axis (kFlexion, kAbduction, kAxial) and sense (+1, -1) of each direction.
  static constexpr std::array<int, 6> kDirectionAxis = {0, 0, 1, 1, 2, 2};
  static constexpr std::array<double, 6> kDirectionSign = {1, -1, 1, -1, 1, -1};
  /// How far past rest and past the first held pose a direction must go to count (deg):
  /// twice the 1 deg to which the hand follows the thimbles, so that neither a pad settling on
  /// the skin nor the hand's give under load passes for a reach.
  static constexpr double kMinExcursionDeg = 2.0;
  /// Time constant of the filter on angles and forces (s): it damps the grip's 14 ms
  /// ringing (1 kg pad on 2e5 N/m) twentyfold and settles within a 0.3 s hold.
  static constexpr double kSmoothingS = 0.05;

  void begin(const std::string& phase);
  bool active() const noexcept { return active_; }
  const std::string& phase() const noexcept { return phase_; }
  /// One authoritative sample: MCP angles (flexion, abduction, axial), the joint's rest
  /// angles, the force the pads exert on each axis (N at the lever arm, positive toward
  /// +angle: the joint torque on that axis over the lever arm), and whether the pads hold
  /// the phalanx, `dt_s` after the previous one. A direction's force is its axis' force in its
  /// sense.
  void observe(const Vec3& angles_rad, const Vec3& rest_rad, const Vec3& axis_force_n, bool held,
               double dt_s = 1e-3) noexcept;
  /// The reaches of the phase, in kDirections order, only the directions reached; the phase
  /// ends.
  std::vector<SessionStore::Reach> finish();

  /// "flexion 72.1 deg (+3.4 vs baseline), extension not reached, ..." for people: every
  /// direction in kDirections order.
  static std::string summary(const std::vector<SessionStore::Reach>& now,
                             const std::vector<SessionStore::Reach>& baseline);

 private:
  bool active_ = false;
  bool started_ = false;  // the pads have held the phalanx in this phase
  bool holding_ = false;  // ... and still do: the filter runs
  Vec3 angles_rad_ = Vec3::Zero(), force_n_axis_ = Vec3::Zero();  // filtered
  std::string phase_;
  Vec3 start_rad_ = Vec3::Zero();  // where they first held it
  std::array<bool, 6> reached_{};
  std::array<double, 6> angle_deg_{};
  std::array<double, 6> force_n_{};
};

}  // namespace telehand::server::session
