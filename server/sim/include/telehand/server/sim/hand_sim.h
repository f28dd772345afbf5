#pragma once
/// The authoritative hand: a Bullet world stepped at a fixed 1 ms. Every joint is a
/// btGeneric6DofSpring2Constraint with translations locked and rotations limited per axis;
/// the index MCP's non-linear stiffness comes from the shared joint model (common/), applied
/// as external torques before every step (Bullet's own springs are linear and get capped at
/// low rates: docs/facts.md "Bullet"). The student's thumb and index are spheres pulled toward
/// the thimble positions by a spring-damper (virtual coupling); they push the proximal
/// phalanx through frictionless contacts and hold it by skin friction, solved inside
/// Bullet's solver and bounded by the friction limit, with a squeeze that follows the load
/// (grip-load coupling). Immutable HandModel, mutable HandSim.
#include <memory>
#include <vector>

#include "telehand/core/joint_model.h"
#include "telehand/server/sim/hand_model.h"

class btDynamicsWorld;

namespace telehand::server::sim {

struct HandSimConfig {
  double dt_s = 1e-3;
  int solver_iterations = 20;
  bool fix_metacarpals = true;                  ///< the therapist stabilises the hand on the table
  std::string mcp_joint = "index_mcp_flexion";  ///< the joint the shared model drives
  /// Passive tone of every other joint toward neutral (an assumption: a few N·cm/rad,
  /// linear, an order below the MCP's; docs/facts.md gives no figures for them).
  double other_stiffness_nm_per_rad = 0.01;
  double other_damping_nms_per_rad =
      0.0001;                      // explicit: b·dt/I stays < 0.2 for a 15 mm distal phalanx
  double sphere_radius_m = 0.003;  ///< + 5 mm bone radius = the 8 mm thimble half width
  /// Virtual coupling. Stiff enough that 16 N shifts the sphere by 0.08 mm (0.5 deg at the
  /// 1 cm lever arm); the 1 kg sphere keeps k·dt²/m = 0.2, well inside the stable range of
  /// an explicit spring at 1 ms, and critically damped.
  double sphere_mass_kg = 1.0;
  double coupling_stiffness_n_per_m = 2.0e5;
  double coupling_damping_ns_per_m = 894.0;
  double pinch_preload_n = 3.0;  ///< least squeeze of the pinch grip (assumption)
  /// Skin friction (pad on skin, an assumption) and the tangential spring that carries it,
  /// solved implicitly: 1 N per micrometre keeps the pads' shear under 0.2 deg of axial
  /// rotation at the largest load.
  double skin_friction = 1.0;
  double grip_stiffness_n_per_m = 1.0e6;
  double grip_damping_ns_per_m = 200.0;
  /// Grip-load coupling (Johansson & Westling, Exp Brain Res 1984: people grip a safety
  /// margin above the slip limit; Flanagan & Wing, Exp Brain Res 1993: in a movement of
  /// their own the grip changes in phase with the load, not after it as it does for a load
  /// that comes unexpectedly; the figures here are assumptions): squeeze = margin * load /
  /// friction, at least the preload and at most max_pinch_n, both pads touching. Time
  /// constants: 10 ms rising (at 30 ms the pads slip 1.5-3 deg where a supination or
  /// pronation meets the end of a neutral zone, docs/capture.md "The grip"), 0.3 s falling.
  double grip_safety_margin = 1.4;
  double grip_rise_s = 0.01;
  double grip_fall_s = 0.3;
  double max_pinch_n = 20.0;
  double min_pad_force_n = 1.0;  ///< the lighter pad keeps at least this contact
};

class HandSim {
 public:
  HandSim(const HandModel& model, const JointModelParams& mcp, const HandSimConfig& config = {});
  ~HandSim();
  HandSim(const HandSim&) = delete;
  HandSim& operator=(const HandSim&) = delete;

  /// New MCP stiffness (patient case, new version). Limits follow the model's ranges.
  void setMcpModel(const JointModelParams& mcp);
  const JointModel& mcpModel() const noexcept { return mcp_; }

  /// Thimble positions in the device frame (the frame JointModelParams' joint origin and
  /// orientation are given in). `engaged` false parks the spheres away from the hand.
  void setFingerTargets(const PerFinger<Vec3>& p_device, bool engaged) noexcept;
  /// Extra per-axis torque on the MCP (tests: step and oscillating pushes).
  void setExternalMcpTorque(const Vec3& axis_torque_nm) noexcept { external_ = axis_torque_nm; }
  /// Place the MCP at these angles (velocities zero), e.g. to start a test from rest.
  void resetMcp(const Vec3& angles_rad);

  void step();
  /// What moves, as numbers: every bone's and sphere's pose and velocity, the pads' grips,
  /// the squeeze and the time. A server keeps it as a session's checkpoint; another one,
  /// with the same hand model, goes on from it (restoreState).
  std::vector<double> saveState() const;
  /// Go on from a saveState() of a hand of the same model; false, with nothing changed, when
  /// the state does not fit this hand (another model, a truncated checkpoint).
  bool restoreState(const std::vector<double>& state);
  double timeS() const noexcept { return time_s_; }

  /// MCP angles (flexion, abduction, axial), rates, and the passive torque applied last step.
  Vec3 mcpAngles() const;
  Vec3 mcpRates() const;
  Vec3 mcpPassiveTorque() const noexcept { return last_passive_; }
  /// Every rotation of the hand in HandModel::dofNames() order.
  std::vector<double> jointAngles() const;
  /// Bone poses in the world frame (HandModel::bones() order).
  Pose bonePose(int bone) const;
  /// Sphere centres and contact forces (the phalanx on each sphere), device frame.
  PerFinger<Vec3> spherePositionsDevice() const;
  PerFinger<Vec3> contactForcesDevice() const noexcept { return contact_device_; }
  /// Where each pad touches the skin (the sphere centre when it touches nothing), device frame.
  PerFinger<Vec3> contactPointsDevice() const noexcept { return contact_point_device_; }
  /// Present squeeze of the pinch (N): the preload, raised with the load the pads carry.
  double pinchForce() const noexcept { return pinch_n_; }
  /// Device frame -> world.
  const Pose& deviceToWorld() const noexcept { return device_to_world_; }
  /// Moment of inertia of the index finger (proximal, middle, distal) about the MCP
  /// flexion axis at the current pose: ground truth for the 1-DoF validation.
  double mcpFlexionInertia() const;
  /// Inertia of everything downstream of `joint` about its x (0), y (1) or z (2) axis.
  double axisInertia(int joint, int axis) const;
  const HandModel& model() const noexcept { return model_; }

 private:
  struct Impl;
  static void preTick(btDynamicsWorld* world, double dt);
  void applyJointTorques();
  void readContacts();

  const HandModel& model_;
  HandSimConfig config_;
  JointModel mcp_;
  std::unique_ptr<Impl> impl_;
  Pose device_to_world_ = Pose::Identity();
  PerFinger<Vec3> target_world_{Vec3::Zero(), Vec3::Zero()};
  PerFinger<Vec3> target_velocity_{Vec3::Zero(), Vec3::Zero()};
  bool engaged_ = false;
  Vec3 external_ = Vec3::Zero();
  Vec3 last_passive_ = Vec3::Zero();
  PerFinger<Vec3> contact_device_{Vec3::Zero(), Vec3::Zero()};
  PerFinger<Vec3> contact_point_device_{Vec3::Zero(), Vec3::Zero()};
  double pinch_n_ = 0.0;  ///< present squeeze of the pinch (grip-load coupling)
  double time_s_ = 0.0;
};

}  // namespace telehand::server::sim
