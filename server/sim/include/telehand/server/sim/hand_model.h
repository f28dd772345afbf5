#pragma once
/// The patient's hand skeleton, loaded once from URDF (deploy/hand/hand24.urdf) and
/// immutable afterwards: bones (capsules) and joints, each joint with one to three limited
/// rotation axes. Chains of revolute joints joined by massless, zero-length links are merged
/// into one multi-axis joint (URDF has only single-axis joints).
#include <Eigen/Geometry>
#include <string>
#include <vector>

#include "telehand/core/math.h"

namespace telehand::server::sim {

using Pose = Eigen::Isometry3d;

struct Bone {
  std::string name;
  int parent_joint = -1;  ///< joint that moves it; -1 for the root
  double length_m = 0.0;  ///< along the link's x axis, from the joint
  double radius_m = 0.0;
  double mass_kg = 0.0;
  Vec3 inertia_kg_m2 = Vec3::Zero();  ///< principal moments about the centre of mass
  Vec3 com_m = Vec3::Zero();          ///< centre of mass in the link frame
  Pose pose0 = Pose::Identity();      ///< link frame in the world with every angle at zero
};

/// One rotation of a joint, about x (0), y (1) or z (2) of the joint frame.
struct Dof {
  std::string name;
  int axis = 0;
  double lower_rad = 0.0;
  double upper_rad = 0.0;
};

/// Rotations compose in y, x, z order (flexion, axial, abduction): the Euler convention of
/// common/joint_model.h, so the MCP's angles mean the same on the client and the server.
struct Joint {
  std::string name;  ///< the first URDF joint of the chain
  int parent_bone = -1;
  int child_bone = -1;
  Pose frame_in_parent = Pose::Identity();
  std::vector<Dof> dofs;
  /// Index into dofs of the rotation about `axis`, or -1 if the joint has none.
  int dofOnAxis(int axis) const noexcept;
};

class HandModel {
 public:
  /// ConfigError naming the file and the element when the file is malformed or violates
  /// the conventions above.
  static HandModel load(const std::string& path);
  static HandModel parse(const std::string& xml, const std::string& origin);

  const std::vector<Bone>& bones() const noexcept { return bones_; }
  const std::vector<Joint>& joints() const noexcept { return joints_; }
  std::size_t dofCount() const noexcept;
  /// Every rotation, in joint order, e.g. "index_mcp_flexion".
  std::vector<std::string> dofNames() const;
  /// Index by name; ConfigError naming the missing element.
  int bone(const std::string& name) const;
  int joint(const std::string& name) const;

 private:
  std::vector<Bone> bones_;
  std::vector<Joint> joints_;
};

}  // namespace telehand::server::sim
