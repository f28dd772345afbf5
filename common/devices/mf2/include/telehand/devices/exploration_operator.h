#pragma once
/// A clinician exploring a joint (paper section IV, exploration): from the rest pose the
/// clinician pushes slowly toward each of the six directions in turn (flexion, extension,
/// abduction, adduction, supination, pronation), the force rising smoothly until it reaches
/// `reach_n` or the phalanx reaches the end of the range of motion, holds it there briefly,
/// releases it and lets the joint come back to rest. The axes not being explored are held
/// at their rest angles by the hand's stiffness (a spring at the grip), which also brings the
/// explored axis back to rest once the push is released (a lax joint has no restoring force
/// inside its neutral zone). Forces at reference scale, torques at the device's scale.
///
/// Manipulation is slow force application, under 40 N/s (docs/facts.md "The paper"): the
/// default push reaches 16 N in 1.6 s (10 N/s). Deterministic for a seed: the seed only
/// varies each push's duration by up to ±10 %.
#include <array>
#include <cstdint>

#include "telehand/core/joint_model.h"
#include "telehand/devices/simulated_mf2.h"

namespace telehand::devices {

struct ExplorationPlan {
  std::array<double, kAxes> rest_deg{};  ///< where each axis is held (the joint's rest)
  std::array<double, kAxes> min_deg{};   ///< range of motion: a push stops rising here
  std::array<double, kAxes> max_deg{};
  double reach_n = 16.0;      ///< largest push, reference scale (the band's top)
  double push_s = 1.6;        ///< rise from 0 to reach_n
  double hold_s = 1.0;        ///< at the reached force
  double release_s = 1.6;     ///< back to 0
  double settle_s = 0.8;      ///< back at rest before the next direction
  double force_scale = 0.25;  ///< device force / reference force (the rendering's 1:4)
  double lever_arm_m = 0.01;
  /// The hand's hold of the axes at rest, N/m at the grip (the simulated MF-2's operator
  /// stiffness), i.e. 200 N/m · lever² in joint space.
  double hold_n_per_m = 200.0;
  bool repeat = true;  ///< start again with flexion after the sixth direction
  uint64_t seed = 1;

  /// One direction: push, hold, release, settle.
  double directionS() const noexcept { return push_s + hold_s + release_s + settle_s; }
};

/// The plan for a joint: rest angles and ranges from its model, the rest as given.
ExplorationPlan planExploration(const JointModelParams& joint, double reach_n = 16.0);

class ExplorationOperator final : public Operator {
 public:
  explicit ExplorationOperator(const ExplorationPlan& plan);
  Vec3 torqueNm(double t_s, const Vec3& angles_rad, const Vec3& rates_rad_s) noexcept override;

  /// Direction being explored at t: 0..5 = flexion, extension, abduction +, abduction −,
  /// axial +, axial − (axis = direction / 2, sign + for even).
  int direction(double t_s) const noexcept;
  /// The push the plan asks for at t (reference N, before the range-end stop).
  double plannedForceN(double t_s) const noexcept;
  /// Force the hand actually pushes with now (reference N): the planned force, held where
  /// the range end stopped it.
  double pushN() const noexcept { return push_n_; }
  const ExplorationPlan& plan() const noexcept { return plan_; }

 private:
  /// Duration scale of direction `d` in its cycle `cycle` (seeded, 0.9..1.1).
  double jitter(uint64_t cycle, int d) const noexcept;
  /// Time into the current direction, its index and its scaled phase durations.
  struct Phase {
    int direction = 0;
    uint64_t cycle = 0;
    double t = 0.0;  ///< seconds into this direction
    double k = 1.0;  ///< duration scale
    bool done = false;
  };
  Phase phaseAt(double t_s) const noexcept;

  ExplorationPlan plan_;
  double push_n_ = 0.0;      // what the hand pushes with
  double stopped_n_ = -1.0;  // the force where the range end stopped the rise (-1: not stopped)
  int stopped_dir_ = -1;
  uint64_t stopped_cycle_ = 0;
};

}  // namespace telehand::devices
