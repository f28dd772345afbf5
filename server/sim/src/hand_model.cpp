#include "telehand/server/sim/hand_model.h"

#include <console_bridge/console.h>
#include <urdf_parser/urdf_parser.h>

#include <fstream>
#include <functional>
#include <map>
#include <mutex>
#include <sstream>

#include "telehand/core/error.h"

namespace telehand::server::sim {

namespace {

/// Collects urdfdom's complaints (it reports through console_bridge) so that they end up in
/// the ConfigError instead of on stderr.
class CollectingHandler : public console_bridge::OutputHandler {
 public:
  void log(const std::string& text, console_bridge::LogLevel level, const char*, int) override {
    if (level >= console_bridge::CONSOLE_BRIDGE_LOG_WARN)
      messages += (messages.empty() ? "" : "; ") + text;
  }
  std::string messages;
};

Pose toPose(const urdf::Pose& p) {
  double x, y, z, w;
  p.rotation.getQuaternion(x, y, z, w);
  Pose out = Pose::Identity();
  out.linear() = Quat(w, x, y, z).normalized().toRotationMatrix();
  out.translation() = Vec3(p.position.x, p.position.y, p.position.z);
  return out;
}

bool isIdentity(const urdf::Pose& p) {
  const Pose t = toPose(p);
  return t.translation().norm() < 1e-9 && (t.linear() - Mat3::Identity()).norm() < 1e-9;
}

/// A massless link without geometry that only joins two rotations of one joint.
bool isAxisLink(const urdf::Link& l) {
  return (!l.inertial || l.inertial->mass == 0.0) && !l.collision && l.child_joints.size() == 1 &&
         isIdentity(l.child_joints[0]->parent_to_joint_origin_transform);
}

}  // namespace

int Joint::dofOnAxis(int axis) const noexcept {
  for (std::size_t i = 0; i < dofs.size(); ++i) {
    if (dofs[i].axis == axis) return static_cast<int>(i);
  }
  return -1;
}

HandModel HandModel::load(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw ConfigError("hand model '" + path + "' cannot be read");
  std::ostringstream ss;
  ss << in.rdbuf();
  return parse(ss.str(), path);
}

HandModel HandModel::parse(const std::string& xml, const std::string& origin) {
  static std::mutex mu;  // console_bridge's handler is process-global
  urdf::ModelInterfaceSharedPtr urdf;
  std::string complaints;
  {
    std::lock_guard lock(mu);
    CollectingHandler handler;
    console_bridge::useOutputHandler(&handler);
    urdf = urdf::parseURDF(xml);
    console_bridge::restorePreviousOutputHandler();
    complaints = handler.messages;
  }
  auto fail = [&](const std::string& what) -> ConfigError {
    return ConfigError("hand model '" + origin + "': " + what);
  };
  if (!urdf) throw fail("not a valid URDF: " + (complaints.empty() ? "parse error" : complaints));
  const urdf::LinkConstSharedPtr root = urdf->getRoot();
  if (!root) throw fail("no root link");

  HandModel m;
  Bone root_bone;
  root_bone.name = root->name;
  m.bones_.push_back(root_bone);

  std::function<void(const urdf::Link&, int)> visit = [&](const urdf::Link& link, int bone_index) {
    for (const auto& first : link.child_joints) {
      Joint j;
      j.name = first->name;
      j.parent_bone = bone_index;
      j.frame_in_parent = toPose(first->parent_to_joint_origin_transform);
      urdf::JointConstSharedPtr cur = first;
      std::vector<int> order;
      while (true) {
        if (cur->type != urdf::Joint::REVOLUTE) {
          throw fail("joint '" + cur->name + "' must be revolute (found another type)");
        }
        if (!cur->limits || !(cur->limits->lower < cur->limits->upper)) {
          throw fail("joint '" + cur->name + "' needs <limit> with lower < upper");
        }
        const Vec3 axis(cur->axis.x, cur->axis.y, cur->axis.z);
        int a = -1;
        for (int i = 0; i < 3; ++i) {
          if ((axis - Vec3::Unit(i)).norm() < 1e-9) a = i;
        }
        if (a < 0) throw fail("joint '" + cur->name + "': <axis> must be 1 0 0, 0 1 0 or 0 0 1");
        if (j.dofOnAxis(a) >= 0)
          throw fail("joint '" + cur->name + "' repeats an axis of its chain");
        j.dofs.push_back({cur->name, a, cur->limits->lower, cur->limits->upper});
        order.push_back(a);
        const urdf::LinkConstSharedPtr child = urdf->getLink(cur->child_link_name);
        if (!child) throw fail("joint '" + cur->name + "' names a missing child link");
        if (isAxisLink(*child)) {
          cur = child->child_joints[0];
          continue;
        }
        // A real bone ends the chain.
        static constexpr int kRank[3] = {1, 0, 2};  // y, x, z
        for (std::size_t i = 1; i < order.size(); ++i) {
          if (kRank[order[i]] < kRank[order[i - 1]]) {
            throw fail("joint chain starting at '" + j.name +
                       "' must rotate in y (flexion), x (axial), z (abduction) order");
          }
        }
        Bone b;
        b.name = child->name;
        if (!child->inertial || child->inertial->mass <= 0.0) {
          throw fail("link '" + child->name + "' needs <inertial> with a positive mass");
        }
        const auto* cyl =
            child->collision && child->collision->geometry
                ? dynamic_cast<const urdf::Cylinder*>(child->collision->geometry.get())
                : nullptr;
        if (!cyl) throw fail("link '" + child->name + "' needs a <collision> <cylinder>");
        b.length_m = cyl->length;
        b.radius_m = cyl->radius;
        b.mass_kg = child->inertial->mass;
        b.inertia_kg_m2 = Vec3(child->inertial->ixx, child->inertial->iyy, child->inertial->izz);
        const auto& o = child->inertial->origin.position;
        b.com_m = Vec3(o.x, o.y, o.z);
        if (!(b.length_m > 0.0 && b.radius_m > 0.0)) {
          throw fail("link '" + child->name + "': cylinder length and radius must be positive");
        }
        b.parent_joint = static_cast<int>(m.joints_.size());
        b.pose0 = m.bones_[static_cast<std::size_t>(bone_index)].pose0 * j.frame_in_parent;
        j.child_bone = static_cast<int>(m.bones_.size());
        m.bones_.push_back(b);
        m.joints_.push_back(j);
        visit(*child, j.child_bone);
        break;
      }
    }
  };
  visit(*root, 0);
  if (m.joints_.empty()) throw fail("no joints");
  return m;
}

std::size_t HandModel::dofCount() const noexcept {
  std::size_t n = 0;
  for (const auto& j : joints_) n += j.dofs.size();
  return n;
}

std::vector<std::string> HandModel::dofNames() const {
  std::vector<std::string> out;
  for (const auto& j : joints_) {
    for (const auto& d : j.dofs) out.push_back(d.name);
  }
  return out;
}

int HandModel::bone(const std::string& name) const {
  for (std::size_t i = 0; i < bones_.size(); ++i) {
    if (bones_[i].name == name) return static_cast<int>(i);
  }
  throw ConfigError("hand model has no link '" + name + "'");
}

int HandModel::joint(const std::string& name) const {
  for (std::size_t i = 0; i < joints_.size(); ++i) {
    if (joints_[i].name == name) return static_cast<int>(i);
  }
  throw ConfigError("hand model has no joint '" + name + "'");
}

}  // namespace telehand::server::sim
