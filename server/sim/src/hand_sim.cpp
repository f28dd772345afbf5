#include "telehand/server/sim/hand_sim.h"

#include <btBulletDynamicsCommon.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <mutex>

#include "telehand/core/error.h"

namespace telehand::server::sim {

namespace {

constexpr int kBoneGroup = 1;
constexpr int kSphereGroup = 2;
constexpr double kMaxCouplingForceN = 60.0;  // bounds the pull if a target jumps
// Bullet index of each rotation axis -> index in the MCP angle vector.
constexpr int kAngleOfAxis[3] = {kAxial, kFlexion, kAbduction};

/// Limits of one joint per Bullet axis (our sign convention) and which axes currently hand
/// their limit rows to the solver.
struct JointLimits {
  btVector3 lo{0, 0, 0}, hi{0, 0, 0};
  std::array<bool, 3> rows{true, true, true};
};

// Bullet's Spring2 reads its Euler angles off the transposed relative rotation (docs/facts.md:
// a +0.30 rad turn reads -0.30), so R = Ry(a) Rx(g) Rz(b) is its RO_ZXY with every angle
// negated: limits are handed over mirrored. The middle axis is then x, the axial rotation.
// An axis whose rows are off is handed over free (lower > upper).
void applyLimits(btGeneric6DofSpring2Constraint& c, const JointLimits& l) {
  btVector3 lower = -l.hi, upper = -l.lo;
  for (int i = 0; i < 3; ++i) {
    if (!l.rows[static_cast<std::size_t>(i)]) {
      lower[i] = 1.0;
      upper[i] = -1.0;
    }
  }
  c.setAngularLowerLimit(lower);
  c.setAngularUpperLimit(upper);
}

void setLimits(btGeneric6DofSpring2Constraint& c, JointLimits& l, const btVector3& lo,
               const btVector3& hi) {
  l.lo = lo;
  l.hi = hi;
  l.rows = {true, true, true};
  applyLimits(c, l);
  for (int i = 0; i < 3; ++i) {
    // Firm stops: a 0.5 N·m push may not pass a limit by more than 0.5 deg.
    c.setParam(BT_CONSTRAINT_STOP_ERP, 0.9, 3 + i);
    c.setParam(BT_CONSTRAINT_STOP_CFM, 0.0, 3 + i);
  }
}

/// Spring2 puts two one-sided rows per limited axis into every solve, wherever the joint is.
/// A row only pushes when the joint would pass its stop within the step (approach · dt >
/// ERP · distance); further away its impulse is clamped to exactly zero and changes nothing,
/// but costs as much as any row in each of the 30 sweeps (the MCP's 6 of the ~27 rows of a
/// pinched index finger). Rows are handed over within this distance of a stop: 0.05 rad
/// plus five steps of the joint's present rate, far beyond where they could act. Results
/// are bitwise those with every row present.
constexpr double kLimitRowMarginRad = 0.05;
/// Error reduction of the locked translations. Bullet's default 0.2 let the index MCP's centre
/// give 0.18 mm under the 20 N of a stiff joint's extension (1 deg at the 1 cm lever arm: the
/// pads' load reaches the joint through contacts the 20 sweeps do not fully converge, and the
/// residual is corrected only a fifth a step); 0.9, as for the angular stops, leaves 0.04 mm.
constexpr double kLinearStopErp = 0.9;
constexpr double kLimitRowLookaheadSteps = 5.0;

btVector3 bt(const Vec3& v) { return {v.x(), v.y(), v.z()}; }
Vec3 eig(const btVector3& v) { return {v.x(), v.y(), v.z()}; }
Mat3 eig(const btMatrix3x3& m) {
  Mat3 r;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) r(i, j) = m[i][j];
  }
  return r;
}
btTransform bt(const Pose& p) {
  const Mat3& r = p.linear();
  btMatrix3x3 m(r(0, 0), r(0, 1), r(0, 2), r(1, 0), r(1, 1), r(1, 2), r(2, 0), r(2, 1), r(2, 2));
  return btTransform(m, bt(Vec3(p.translation())));
}
Pose eig(const btTransform& t) {
  Pose p = Pose::Identity();
  const btMatrix3x3& m = t.getBasis();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) p.linear()(i, j) = m[i][j];
  }
  p.translation() = eig(t.getOrigin());
  return p;
}

/// Bones are octahedra, as in the paper: two pyramids joined at a square ring. The ring's
/// sides face dorsal, palmar, radial and ulnar at the bone radius, so a pad pressing the
/// back of a phalanx meets a flat face, not a rounded ridge it would slide off (a pinch on a
/// capsule squirts sideways). The ring sits at 27 % of the length: for the index proximal
/// phalanx that is 1 cm from the MCP, where the paper's forces were applied.
btCollisionShape* makeBoneShape(const Bone& b, const Vec3& com) {
  auto* hull = new btConvexHullShape();
  const double x = 0.27 * b.length_m;
  constexpr double kMargin = 2e-5;  // Bullet adds this around the hull: keep faces at the radius
  // Before the points: the hull caches its bounding box, margin included, when the last point
  // goes in. Set afterwards, Bullet's default 4 cm margin stayed in that box, so every bone's
  // box reached the parked spheres: the broadphase paired them with every bone, which joined
  // all fingers with the never-sleeping spheres into one island (nothing ever slept) and ran
  // GJK on 38 pairs per step.
  hull->setMargin(kMargin);
  const double r = b.radius_m - kMargin;
  hull->addPoint(bt(Vec3(0, 0, 0) - com), false);
  hull->addPoint(bt(Vec3(b.length_m, 0, 0) - com), false);
  hull->addPoint(bt(Vec3(x, r, r) - com), false);
  hull->addPoint(bt(Vec3(x, -r, r) - com), false);
  hull->addPoint(bt(Vec3(x, -r, -r) - com), false);
  hull->addPoint(bt(Vec3(x, r, -r) - com), true);
  return hull;
}

/// Bullet's scale-dependent globals, set once per process (HandSim instances may be built
/// and stepped on several threads at once; writing them per instance would race).
void configureBulletForMillimetres() {
  static std::once_flag once;
  std::call_once(once, [] {
    // Contacts 2 cm apart would count as one and friction anchors would not follow the skin.
    gContactBreakingThreshold = 0.0005;
    // The dynamic broadphase tree fattens every moving box by 5 cm: the spheres pinching the
    // index would pair with every finger and keep them all awake (islands follow broadphase
    // pairs). 2 mm is still several steps of motion at the fastest mobilization.
    gDbvtMargin = 0.002;
  });
}

/// Skin friction of one pad as rows of Bullet's solver: the pad's point on the skin is held
/// to the point of the bone it touched down on, in the two directions across the contact normal,
/// by a spring-damper solved implicitly (ERP/CFM form), its force bounded by the friction
/// limit. Implicit, so the spring may be far stiffer than an explicit one could be against
/// the finger's small axial inertia at 1 ms; bounded, so the pad slips when the load
/// exceeds the friction. Body A is the sphere (no rotation), body B the bone.
class PadGrip final : public btTypedConstraint {
 public:
  PadGrip(btRigidBody& pad, btRigidBody& bone)
      : btTypedConstraint(CONTACT_CONSTRAINT_TYPE, pad, bone) {
    setJointFeedback(&feedback_);
    enableFeedback(true);
  }
  /// Per step: where the pad is anchored (bone frame), the contact normal (world), the spring
  /// and the friction limit (N). A zero limit switches the rows off.
  void set(const Vec3& anchor_local, const Vec3& normal, double pad_radius, double stiffness,
           double damping, double limit_n) noexcept {
    anchor_local_ = anchor_local;
    pad_radius_ = pad_radius;
    normal_ = normal;
    stiffness_ = stiffness;
    damping_ = damping;
    limit_n_ = limit_n;
  }
  /// Tangential force the bone exerted on the pad in the last step (world).
  Vec3 force() const noexcept { return eig(feedback_.m_appliedForceBodyA); }
  /// The friction limit the rows had in the last step (N).
  double limit() const noexcept { return limit_n_; }

  void getInfo1(btConstraintInfo1* info) override {
    info->m_numConstraintRows = limit_n_ > 0.0 ? 2 : 0;
    info->nub = 6 - info->m_numConstraintRows;
  }
  void getInfo2(btConstraintInfo2* info) override {
    const btRigidBody& pad = getRigidBodyA();
    const btRigidBody& bone = getRigidBodyB();
    const btVector3 anchor = bone.getCenterOfMassTransform() * bt(anchor_local_);
    const btVector3 r_b = anchor - bone.getCenterOfMassPosition();
    // The pad's point on the skin (the sphere does not rotate: no angular part on its side).
    const btVector3 x = pad.getCenterOfMassPosition() - bt(normal_) * pad_radius_ - anchor;
    btVector3 t[2];
    btPlaneSpace1(bt(normal_), t[0], t[1]);
    const double h = 1.0 / info->fps;
    const double kc = stiffness_ * h + damping_;  // implicit spring-damper: k·h + c
    const int s = info->rowskip;
    for (int r = 0; r < 2; ++r) {
      const btVector3 rxt = r_b.cross(t[r]);
      for (int i = 0; i < 3; ++i) {
        info->m_J1linearAxis[r * s + i] = t[r][i];
        info->m_J2linearAxis[r * s + i] = -t[r][i];
        info->m_J2angularAxis[r * s + i] = -rxt[i];
      }
      // Effective mass of the row, as the solver computes it (the pad has no rotational
      // inertia: it does not rotate).
      const double d = 1.0 / (pad.getInvMass() + bone.getInvMass() +
                              rxt.dot(bone.getInvInertiaTensorWorld() * rxt));
      // Relative velocity after the step: -k·x/(k·h + c) - impulse/(h·(k·h + c)).
      info->m_constraintError[r * s] = -stiffness_ * x.dot(t[r]) / kc;
      info->cfm[r * s] = d / (h * kc);
      info->m_lowerLimit[r * s] = -limit_n_ * h;
      info->m_upperLimit[r * s] = limit_n_ * h;
    }
  }
  void setParam(int, btScalar, int) override {}
  btScalar getParam(int, int) const override { return 0.0; }

 private:
  btJointFeedback feedback_{};
  Vec3 anchor_local_ = Vec3::Zero();
  Vec3 normal_ = Vec3::UnitZ();
  double pad_radius_ = 0.0, stiffness_ = 0.0, damping_ = 0.0, limit_n_ = 0.0;
};

/// Bullet's default pools hold 4,096 contact manifolds and 4,096 collision algorithms, about
/// 6 MB written through when the world is made: most of what a hand cost to build (tens of
/// ms of page faults on a server whose freed hands went back to the system) and to keep. A
/// hand has two pads against 20 bones, at most 40 pairs; beyond the pool Bullet takes
/// further ones from the heap.
btDefaultCollisionConstructionInfo handPools() {
  btDefaultCollisionConstructionInfo info;
  info.m_defaultMaxPersistentManifoldPoolSize = 64;
  info.m_defaultMaxCollisionAlgorithmPoolSize = 64;
  return info;
}
}  // namespace

struct HandSim::Impl {
  btDefaultCollisionConfiguration collision_config{handPools()};
  btCollisionDispatcher dispatcher{&collision_config};
  btDbvtBroadphase broadphase;
  btSequentialImpulseConstraintSolver solver;
  btDiscreteDynamicsWorld world{&dispatcher, &broadphase, &solver, &collision_config};
  std::vector<std::unique_ptr<btCollisionShape>> shapes;
  std::vector<std::unique_ptr<btDefaultMotionState>> motion_states;
  std::vector<std::unique_ptr<btRigidBody>> bodies;  // per bone
  std::vector<Pose> com_in_link;                     // per bone
  std::vector<std::unique_ptr<btGeneric6DofSpring2Constraint>>
      constraints;                           // per joint; null if both ends fixed
  std::vector<JointLimits> limits;           // per joint
  std::vector<Pose> frame_in_a, frame_in_b;  // per joint: joint frame in each body
  std::vector<Vec3> axis_inertia;            // per joint, per angle: downstream inertia
  PerFinger<std::unique_ptr<btRigidBody>> spheres;
  int mcp_joint = -1;
  std::vector<Mat3> rot_in_a, rot_in_b;  // per joint: rotations of frame_in_a/b
  /// Per bone: the bones joined to it through joints, static ends excluded: one finger each
  /// with fixed metacarpals. A finger sleeps and wakes as one.
  std::vector<int> chain;             // per bone: component id (-1: static)
  Vec3 external_seen = Vec3::Zero();  // wakes the MCP's finger on a change

  /// Skin friction of one pad: anchored to the point of the bone it touched down on, held
  /// there by rows of the solver (PadGrip) up to the friction limit, and slipping beyond.
  /// Bullet's own point-contact friction made a pinched millimetre phalanx creep sideways,
  /// so its contacts are frictionless and this acts.
  struct Grip {
    btRigidBody* bone = nullptr;
    Vec3 anchor_local = Vec3::Zero();  // sphere centre at touch-down, bone frame
    Vec3 normal = Vec3::Zero();        // bone -> sphere, world
    double normal_n = 0.0;
    Vec3 force = Vec3::Zero();      // tangential force on the sphere, last step
    double load_n = 0.0;            // tangential pull of the finger on the pad, this step
    std::unique_ptr<PadGrip> rows;  // in the world while the pad touches `bone`
  };
  PerFinger<Grip> grips;

  btRigidBody& body(int bone) { return *bodies[static_cast<std::size_t>(bone)]; }
  const btRigidBody& body(int bone) const { return *bodies[static_cast<std::size_t>(bone)]; }

  /// Joint frame on the parent side and relative rotation of the child, world frame.
  struct JointState {
    Mat3 parent_frame;
    Vec3 angles;
    Vec3 rates;
    Mat3 basis;  // eulerAxisBasis(angles): w = E rates, tau_gen = E^T tau
  };
  JointState jointState(const Joint& j, std::size_t ji) const {
    // Rotations only: the angles do not depend on where the joint is.
    const Mat3 pa = eig(body(j.parent_bone).getCenterOfMassTransform().getBasis()) * rot_in_a[ji];
    const Mat3 pb = eig(body(j.child_bone).getCenterOfMassTransform().getBasis()) * rot_in_b[ji];
    JointState s;
    s.parent_frame = pa;
    s.angles = eulerFromRotation(pa.transpose() * pb);
    const Vec3 w_rel = pa.transpose() * (eig(body(j.child_bone).getAngularVelocity()) -
                                         eig(body(j.parent_bone).getAngularVelocity()));
    s.basis = eulerAxisBasis(s.angles);
    s.rates = s.basis.partialPivLu().solve(w_rel);
    return s;
  }

  /// Wakes every body of the finger `bone` belongs to (no-op for a static bone).
  void wakeChain(int bone) {
    const int c = chain[static_cast<std::size_t>(bone)];
    if (c < 0) return;
    for (std::size_t i = 0; i < bodies.size(); ++i) {
      if (chain[i] == c) bodies[i]->activate(true);
    }
  }
};

HandSim::HandSim(const HandModel& model, const JointModelParams& mcp, const HandSimConfig& config)
    : model_(model), config_(config), mcp_(mcp), impl_(std::make_unique<Impl>()) {
  // Bullet's contact thresholds assume metre-sized objects; bones are millimetres.
  configureBulletForMillimetres();
  Impl& im = *impl_;
  im.world.setGravity(
      btVector3(0, 0, 0));  // the measured curves already include the finger's weight
  im.world.getSolverInfo().m_numIterations = config_.solver_iterations;
  im.world.setInternalTickCallback(&HandSim::preTick, this, true);

  const auto& bones = model_.bones();
  for (std::size_t i = 0; i < bones.size(); ++i) {
    const Bone& b = bones[i];
    const bool fixed = i == 0 || (config_.fix_metacarpals && b.name.ends_with("_metacarpal"));
    btCollisionShape* shape = nullptr;
    if (i == 0) {
      shape = new btSphereShape(0.001);
    } else {
      shape = makeBoneShape(b, b.com_m);
    }
    im.shapes.emplace_back(shape);
    Pose com = Pose::Identity();
    com.translation() = i == 0 ? Vec3::Zero() : b.com_m;
    im.com_in_link.push_back(com);
    const double mass = fixed ? 0.0 : b.mass_kg;
    im.motion_states.push_back(std::make_unique<btDefaultMotionState>(bt(b.pose0 * com)));
    btRigidBody::btRigidBodyConstructionInfo info(mass, im.motion_states.back().get(), shape,
                                                  bt(b.inertia_kg_m2));
    info.m_friction = 0.0;
    auto body = std::make_unique<btRigidBody>(info);
    // Fingers nobody touches come to rest and sleep (each is an island of its own behind a
    // fixed metacarpal) once every bone moved slower than this for 2 s (Bullet's
    // gDeactivationTime): 0.2 mm/s, 0.3 deg/s, so a finger that sleeps has settled.
    // Contacts, resetMcp, setMcpModel and a new external MCP torque wake them.
    body->setSleepingThresholds(0.0002, 0.005);
    im.world.addRigidBody(body.get(), kBoneGroup, kSphereGroup);
    im.bodies.push_back(std::move(body));
  }

  const auto& joints = model_.joints();
  im.frame_in_a.resize(joints.size());
  im.frame_in_b.resize(joints.size());
  im.rot_in_a.resize(joints.size());
  im.rot_in_b.resize(joints.size());
  im.chain.assign(bones.size(), -1);
  im.limits.resize(joints.size());
  im.constraints.resize(joints.size());
  for (std::size_t ji = 0; ji < joints.size(); ++ji) {
    const Joint& j = joints[ji];
    const Pose joint_world = bones[static_cast<std::size_t>(j.child_bone)].pose0;
    const Pose body_a = bones[static_cast<std::size_t>(j.parent_bone)].pose0 *
                        im.com_in_link[static_cast<std::size_t>(j.parent_bone)];
    const Pose body_b = joint_world * im.com_in_link[static_cast<std::size_t>(j.child_bone)];
    im.frame_in_a[ji] = body_a.inverse() * joint_world;
    im.frame_in_b[ji] = body_b.inverse() * joint_world;
    im.rot_in_a[ji] = im.frame_in_a[ji].linear();
    im.rot_in_b[ji] = im.frame_in_b[ji].linear();
    if (j.name == config_.mcp_joint) im.mcp_joint = static_cast<int>(ji);
    btRigidBody& a = im.body(j.parent_bone);
    btRigidBody& b = im.body(j.child_bone);
    if (a.getInvMass() == 0.0 && b.getInvMass() == 0.0) continue;  // fixed to fixed: no joint
    auto c = std::make_unique<btGeneric6DofSpring2Constraint>(a, b, bt(im.frame_in_a[ji]),
                                                              bt(im.frame_in_b[ji]), RO_ZXY);
    c->setLinearLowerLimit(btVector3(0, 0, 0));
    c->setLinearUpperLimit(btVector3(0, 0, 0));
    for (int i = 0; i < 3; ++i) {
      c->setParam(BT_CONSTRAINT_STOP_ERP, kLinearStopErp, i);
      c->setParam(BT_CONSTRAINT_STOP_CFM, 0.0, i);
    }
    btVector3 lo(0, 0, 0), hi(0, 0, 0);
    for (const Dof& d : j.dofs) {
      lo[d.axis] = d.lower_rad;
      hi[d.axis] = d.upper_rad;
    }
    setLimits(*c, im.limits[ji], lo, hi);
    im.world.addConstraint(c.get(), true);
    im.constraints[ji] = std::move(c);
  }
  im.axis_inertia.resize(joints.size());
  for (std::size_t ji = 0; ji < joints.size(); ++ji) {
    for (int axis = 0; axis < 3; ++axis) {
      im.axis_inertia[ji][kAngleOfAxis[axis]] = axisInertia(static_cast<int>(ji), axis);
    }
  }
  if (im.mcp_joint < 0) throw ConfigError("hand model has no joint '" + config_.mcp_joint + "'");
  // Fingers: bones joined through joints with two dynamic ends (bones are stored parents
  // first, so one pass in joint order labels each chain from its first dynamic bone).
  for (std::size_t i = 0; i < bones.size(); ++i) {
    if (im.bodies[i]->getInvMass() != 0.0) im.chain[i] = static_cast<int>(i);
  }
  for (const Joint& j : joints) {
    const auto p = static_cast<std::size_t>(j.parent_bone);
    const auto c = static_cast<std::size_t>(j.child_bone);
    if (im.chain[p] >= 0 && im.chain[c] >= 0) im.chain[c] = im.chain[p];
  }

  // Index pad first: the pads' contacts then reach the solver in the order they had when
  // every bone was paired with both spheres from the start. Gauss-Seidel stops short of
  // convergence and its answer depends on row order; this is the order the tests were
  // calibrated with (the other one is as valid, but with skin friction a held pinch settles
  // up to 0.6 deg elsewhere).
  for (int k = kIndex; k >= kThumb; --k) {
    auto* shape = new btSphereShape(config_.sphere_radius_m);
    im.shapes.emplace_back(shape);
    // No rotational inertia: the pad translates only (see the angular factor below).
    btRigidBody::btRigidBodyConstructionInfo info(config_.sphere_mass_kg, nullptr, shape,
                                                  btVector3(0, 0, 0));
    info.m_friction = 0.0;
    im.spheres[k] = std::make_unique<btRigidBody>(info);
    im.spheres[k]->setActivationState(DISABLE_DEACTIVATION);
    // A fingertip does not roll on the skin it presses: without this the sphere is a ball
    // bearing and friction cannot hold the phalanx against sideways escape.
    im.spheres[k]->setAngularFactor(btVector3(0, 0, 0));
    im.world.addRigidBody(im.spheres[k].get(), kSphereGroup, kBoneGroup);
  }
  setMcpModel(mcp);
  pinch_n_ = config_.pinch_preload_n;
  setFingerTargets({Vec3::Zero(), Vec3::Zero()}, false);
}

HandSim::~HandSim() {
  Impl& im = *impl_;
  for (auto& c : im.constraints) {
    if (c) im.world.removeConstraint(c.get());
  }
  for (auto& g : im.grips) {
    if (g.rows) im.world.removeConstraint(g.rows.get());
  }
  for (auto& s : im.spheres) im.world.removeRigidBody(s.get());
  for (auto& b : im.bodies) im.world.removeRigidBody(b.get());
}

void HandSim::setMcpModel(const JointModelParams& mcp) {
  mcp_ = JointModel(mcp);
  Impl& im = *impl_;
  const Joint& j = model_.joints()[static_cast<std::size_t>(im.mcp_joint)];
  // The device frame sits where the model says the MCP is: world <- joint <- device.
  Pose device_joint = Pose::Identity();
  device_joint.linear() = mcp.joint_orientation.toRotationMatrix();
  device_joint.translation() = mcp.joint_origin_m;
  device_to_world_ =
      model_.bones()[static_cast<std::size_t>(j.child_bone)].pose0 * device_joint.inverse();
  // New stiffness: the finger's rest pose moves, so it must not stay asleep in the old one.
  im.wakeChain(j.child_bone);
  auto& c = im.constraints[static_cast<std::size_t>(im.mcp_joint)];
  if (!c) return;
  btVector3 lo(0, 0, 0), hi(0, 0, 0);
  for (const Dof& d : j.dofs) {
    const CubicCurve& curve = mcp.axes[static_cast<std::size_t>(kAngleOfAxis[d.axis])];
    lo[d.axis] = degToRad(curve.min_deg);
    hi[d.axis] = degToRad(curve.max_deg);
  }
  setLimits(*c, im.limits[static_cast<std::size_t>(im.mcp_joint)], lo, hi);
}

void HandSim::setFingerTargets(const PerFinger<Vec3>& p_device, bool engaged) noexcept {
  Impl& im = *impl_;
  for (int k = 0; k < 2; ++k) {
    Vec3 target = device_to_world_ * p_device[k];
    if (!engaged) {
      // Parked above the back of the hand, apart, out of reach of every bone.
      target = device_to_world_ * Vec3(0.0, k == kThumb ? 0.03 : -0.03, 0.08);
    }
    const bool jump = engaged != engaged_ || (target - target_world_[k]).norm() > 0.01;
    if (jump) {
      // Re-engaging (or a large jump): place the sphere instead of pulling it across the hand.
      btTransform t = im.spheres[k]->getCenterOfMassTransform();
      t.setOrigin(bt(target));
      im.spheres[k]->setCenterOfMassTransform(t);
      im.spheres[k]->setLinearVelocity(btVector3(0, 0, 0));
      target_velocity_[k].setZero();
    } else {
      const Vec3 v = (target - target_world_[k]) / config_.dt_s;
      target_velocity_[k] += 0.2 * (v - target_velocity_[k]);  // 5 ms smoothing of 1 kHz samples
    }
    target_world_[k] = target;
  }
  if (engaged != engaged_) pinch_n_ = config_.pinch_preload_n;  // a new grip starts light
  engaged_ = engaged;
}

void HandSim::resetMcp(const Vec3& angles_rad) {
  Impl& im = *impl_;
  const auto& bones = model_.bones();
  const auto& joints = model_.joints();
  std::vector<Pose> link(bones.size(), Pose::Identity());
  for (std::size_t i = 0; i < bones.size(); ++i) {
    const Bone& b = bones[i];
    if (b.parent_joint < 0) {
      link[i] = b.pose0;
      continue;
    }
    const Joint& j = joints[static_cast<std::size_t>(b.parent_joint)];
    Pose rot = Pose::Identity();
    if (b.parent_joint == im.mcp_joint) rot.linear() = eulerToRotation(angles_rad);
    link[i] = link[static_cast<std::size_t>(j.parent_bone)] * j.frame_in_parent * rot;
  }
  for (std::size_t i = 0; i < bones.size(); ++i) {
    btRigidBody& body = *im.bodies[i];
    if (body.getInvMass() == 0.0) continue;
    const btTransform t = bt(link[i] * im.com_in_link[i]);
    // A sleeping bone already at the pose is at rest there (Bullet zeroes the velocities of
    // sleepers): leave its finger asleep. Anything else moves and wakes.
    if (!body.isActive() && (t.getOrigin() - body.getCenterOfMassPosition()).length() < 1e-12 &&
        eig(t.getBasis()).isApprox(eig(body.getCenterOfMassTransform().getBasis()), 1e-12)) {
      continue;
    }
    body.setCenterOfMassTransform(t);
    body.setLinearVelocity(btVector3(0, 0, 0));
    body.setAngularVelocity(btVector3(0, 0, 0));
    im.wakeChain(static_cast<int>(i));
  }
}

void HandSim::preTick(btDynamicsWorld* world, double) {
  static_cast<HandSim*>(world->getWorldUserInfo())->applyJointTorques();
}

void HandSim::applyJointTorques() {
  Impl& im = *impl_;
  const auto& joints = model_.joints();
  if (external_ != im.external_seen) {  // a sleeping finger is in balance only with the old push
    im.external_seen = external_;
    im.wakeChain(joints[static_cast<std::size_t>(im.mcp_joint)].child_bone);
  }
  for (std::size_t ji = 0; ji < joints.size(); ++ji) {
    const Joint& j = joints[ji];
    btRigidBody& parent = im.body(j.parent_bone);
    btRigidBody& child = im.body(j.child_bone);
    if (child.getInvMass() == 0.0 || !child.isActive()) continue;
    const Impl::JointState s = im.jointState(j, ji);
    // Explicit damping diverges once b·dt/I passes 2, and the finger's axial inertia is
    // under 1e-6 kg·m²: damping is capped at a quarter of that bound, and exact below it
    // (flexion, where the ODE ground truth applies, is far below).
    const Vec3& inertia = im.axis_inertia[ji];
    auto implicit = [&](double damping) {
      Vec3 out;
      for (int i = 0; i < 3; ++i) out[i] = std::min(damping, 0.5 * inertia[i] / config_.dt_s);
      return out;
    };
    Vec3 tau_gen;
    if (static_cast<int>(ji) == im.mcp_joint) {
      // The shared model's torque at rest, plus its rate-dependent part (damping and spasm) as
      // a damping per axis, kept stable: within the explicit bound above, and never negative.
      // A rate term that pushes the joint along its motion (the spasm's pull toward rest
      // while it returns there) would add energy; against the finger's axial inertia at 1 ms
      // it threw the pinched phalanx out of the grip.
      const Vec3 still = mcp_.passiveTorqueNm(s.angles, Vec3::Zero());
      const Vec3 moving = mcp_.passiveTorqueNm(s.angles, s.rates);
      const Vec3 cap = implicit(1e300);
      for (int i = 0; i < 3; ++i) {
        const double rate = s.rates[i];
        const double b = std::abs(rate) > 1e-12 ? (still[i] - moving[i]) / rate
                                                : mcp_.params().damping_nms_per_rad;
        last_passive_[i] = still[i] - std::clamp(b, 0.0, cap[i]) * rate;
      }
      tau_gen = last_passive_ + external_;
    } else {
      tau_gen = -config_.other_stiffness_nm_per_rad * s.angles -
                implicit(config_.other_damping_nms_per_rad).cwiseProduct(s.rates);
    }
    const Vec3 tau_world = s.parent_frame * s.basis.transpose().partialPivLu().solve(tau_gen);
    if (btGeneric6DofSpring2Constraint* c = im.constraints[ji].get()) {
      JointLimits& l = im.limits[ji];
      bool changed = false;
      for (int axis = 0; axis < 3; ++axis) {
        if (!(l.lo[axis] < l.hi[axis])) continue;  // locked: one row, always needed
        const double a = s.angles[kAngleOfAxis[axis]];
        const double reach = kLimitRowMarginRad + kLimitRowLookaheadSteps *
                                                      std::abs(s.rates[kAngleOfAxis[axis]]) *
                                                      config_.dt_s;
        const bool near = a - l.lo[axis] < reach || l.hi[axis] - a < reach;
        auto& on = l.rows[static_cast<std::size_t>(axis)];
        changed |= near != on;
        on = near;
      }
      if (changed) applyLimits(*c, l);
    }
    child.applyTorque(bt(tau_world));
    if (parent.getInvMass() != 0.0) parent.applyTorque(bt(Vec3(-tau_world)));
  }
  // A pinch squeezes: each target moves toward the other by pinch / stiffness, so the two
  // spheres hold the phalanx between them with that force (and friction) on every axis.
  Vec3 squeeze = Vec3::Zero();
  if (engaged_) {
    const Vec3 across = target_world_[kIndex] - target_world_[kThumb];
    const double gap = across.norm();
    if (gap > 1e-9) squeeze = across / gap * (pinch_n_ / config_.coupling_stiffness_n_per_m);
  }
  for (int k = 0; k < 2; ++k) {
    btRigidBody& s = *im.spheres[k];
    const Vec3 target = target_world_[k] + (k == kThumb ? squeeze : Vec3(-squeeze));
    // Damping as backward Euler would apply it, so a light sphere stays stable at 1 ms.
    const double c =
        config_.coupling_damping_ns_per_m /
        (1.0 + config_.coupling_damping_ns_per_m * config_.dt_s / config_.sphere_mass_kg);
    Vec3 f = config_.coupling_stiffness_n_per_m * (target - eig(s.getCenterOfMassPosition())) +
             c * (target_velocity_[k] - eig(s.getLinearVelocity()));
    const double n = f.norm();
    if (n > kMaxCouplingForceN) f *= kMaxCouplingForceN / n;
    s.applyCentralForce(bt(f));

    Impl::Grip& g = im.grips[k];
    // The load the pad must carry by friction: the finger's pull across the contact normal.
    // While the pad holds it equals the friction force; once it slips it exceeds it, which
    // is what makes people squeeze harder.
    g.load_n = g.bone ? (f - g.normal * g.normal.dot(f)).norm() : 0.0;
    if (g.rows) {
      g.rows->set(g.anchor_local, g.normal, config_.sphere_radius_m, config_.grip_stiffness_n_per_m,
                  config_.grip_damping_ns_per_m, config_.skin_friction * g.normal_n);
    }
  }
}

void HandSim::step() {
  impl_->world.stepSimulation(config_.dt_s, 0);
  time_s_ += config_.dt_s;
  readContacts();
}

void HandSim::readContacts() {
  Impl& im = *impl_;
  PerFinger<Vec3> f{Vec3::Zero(), Vec3::Zero()};
  PerFinger<btRigidBody*> touched{nullptr, nullptr};
  PerFinger<double> strongest{0.0, 0.0};
  const int n = im.dispatcher.getNumManifolds();
  for (int i = 0; i < n; ++i) {
    const btPersistentManifold* m = im.dispatcher.getManifoldByIndexInternal(i);
    for (int k = 0; k < 2; ++k) {
      const bool is_a = m->getBody0() == im.spheres[k].get();
      const bool is_b = m->getBody1() == im.spheres[k].get();
      if (!is_a && !is_b) continue;
      const btCollisionObject* other = is_a ? m->getBody1() : m->getBody0();
      double sum = 0.0;
      for (int p = 0; p < m->getNumContacts(); ++p) {
        const btManifoldPoint& pt = m->getContactPoint(p);
        // The solver pushes body A along the normal on B, body B against it.
        const Vec3 impulse = eig(pt.m_normalWorldOnB) * pt.getAppliedImpulse();
        f[k] += (is_a ? impulse : Vec3(-impulse)) / config_.dt_s;
        sum += pt.getAppliedImpulse();
      }
      if (sum > strongest[k]) {
        strongest[k] = sum;
        touched[k] = const_cast<btRigidBody*>(btRigidBody::upcast(other));
      }
    }
  }
  const Mat3 to_device = device_to_world_.linear().transpose();
  double shortfall_n = -1e9;  // the most any pad lacks of the normal force it needs
  for (int k = 0; k < 2; ++k) {
    Impl::Grip& g = im.grips[k];
    g.force = g.rows ? g.rows->force() : Vec3::Zero();  // what the rows carried this step
    const double normal_n = f[k].norm();
    if (!touched[k] || normal_n <= 0.0) {
      if (g.rows) im.world.removeConstraint(g.rows.get());
      g = {};
    } else {
      g.normal = f[k] / normal_n;
      g.normal_n = normal_n;
      const Pose bone = eig(touched[k]->getCenterOfMassTransform());
      const Vec3 skin =
          eig(im.spheres[k]->getCenterOfMassPosition()) - g.normal * config_.sphere_radius_m;
      if (g.bone != touched[k]) {
        if (g.rows) im.world.removeConstraint(g.rows.get());
        g.bone = touched[k];
        g.anchor_local = bone.inverse() * skin;
        g.rows = std::make_unique<PadGrip>(*im.spheres[k], *g.bone);
        im.world.addConstraint(g.rows.get(), false);  // the pad still collides with the bone
      }
      // At the friction limit (a row at its bound, or past the cone at a corner of the box
      // the rows bound) the pad slides: the anchor follows it so that the spring holds just
      // the limit.
      const double used = g.rows->limit();
      if (used > 0.0 && g.force.norm() >= used * (1.0 - 1e-6)) {
        Vec3 slip = skin - bone * g.anchor_local;
        slip -= g.normal * g.normal.dot(slip);
        const double keep_m = config_.skin_friction * normal_n / config_.grip_stiffness_n_per_m;
        const double slip_m = slip.norm();
        if (slip_m > keep_m)
          g.anchor_local = bone.inverse() * Vec3(skin - slip * (keep_m / slip_m));
      }
    }
    // The squeeze this pad asks for: enough normal force to carry its tangential load with a
    // margin, and at least a light touch.
    const double need = std::max(config_.min_pad_force_n,
                                 config_.grip_safety_margin * std::max(g.force.norm(), g.load_n) /
                                     std::max(config_.skin_friction, 1e-6));
    shortfall_n = std::max(shortfall_n, need - (g.bone ? normal_n : 0.0));
    contact_device_[k] = to_device * (f[k] + g.force);
    const Vec3 centre = eig(im.spheres[k]->getCenterOfMassPosition());
    contact_point_device_[k] =
        device_to_world_.inverse() * Vec3(centre - g.normal * config_.sphere_radius_m);
  }
  // Grip follows load, as people hold objects: the squeeze rises (fast) and relaxes (slowly)
  // until the pad that needs it most has a safety margin above slipping. Both pads must touch:
  // a pad that does not lacks the whole light touch.
  if (!engaged_) return;
  const double want =
      std::clamp(pinch_n_ + shortfall_n, config_.pinch_preload_n, config_.max_pinch_n);
  const double tau = want > pinch_n_ ? config_.grip_rise_s : config_.grip_fall_s;
  pinch_n_ += (want - pinch_n_) * std::min(1.0, config_.dt_s / tau);
}

namespace {
constexpr double kStateMagic = 24061.0;  // the first number of a saved state
constexpr std::size_t kPerBody = 13;     // origin, rotation (x y z w), linear, angular velocity
constexpr std::size_t kPerGrip = 8;      // bone (-1: none), anchor in the bone, normal, force

void saveBody(const btRigidBody& b, std::vector<double>& out) {
  const btTransform& t = b.getCenterOfMassTransform();
  const btQuaternion q = t.getRotation();
  const btVector3 v = b.getLinearVelocity(), w = b.getAngularVelocity();
  for (double x : {t.getOrigin().x(), t.getOrigin().y(), t.getOrigin().z(), q.x(), q.y(), q.z(),
                   q.w(), v.x(), v.y(), v.z(), w.x(), w.y(), w.z()}) {
    out.push_back(x);
  }
}

void restoreBody(btRigidBody& b, const double* p) {
  btTransform t;
  t.setOrigin(btVector3(p[0], p[1], p[2]));
  t.setRotation(btQuaternion(p[3], p[4], p[5], p[6]));
  b.setCenterOfMassTransform(t);
  b.setLinearVelocity(btVector3(p[7], p[8], p[9]));
  b.setAngularVelocity(btVector3(p[10], p[11], p[12]));
  b.activate(true);
}
}  // namespace

std::vector<double> HandSim::saveState() const {
  const Impl& im = *impl_;
  std::vector<double> out;
  out.reserve(4 + kPerBody * (im.bodies.size() + 2) + 2 * kPerGrip);
  out.push_back(kStateMagic);
  out.push_back(static_cast<double>(im.bodies.size()));
  out.push_back(time_s_);
  out.push_back(pinch_n_);
  for (const auto& b : im.bodies) saveBody(*b, out);
  for (const auto& sp : im.spheres) saveBody(*sp, out);
  for (const auto& g : im.grips) {
    int bone = -1;
    for (std::size_t i = 0; i < im.bodies.size(); ++i) {
      if (g.rows && im.bodies[i].get() == g.bone) bone = static_cast<int>(i);
    }
    out.push_back(bone);
    for (int i = 0; i < 3; ++i) out.push_back(g.anchor_local[i]);
    for (int i = 0; i < 3; ++i) out.push_back(g.normal[i]);
    out.push_back(g.normal_n);
  }
  return out;
}

bool HandSim::restoreState(const std::vector<double>& state) {
  Impl& im = *impl_;
  const std::size_t bodies = im.bodies.size();
  if (state.size() != 4 + kPerBody * (bodies + 2) + 2 * kPerGrip || state[0] != kStateMagic ||
      state[1] != static_cast<double>(bodies)) {
    return false;
  }
  for (double x : state) {
    if (!std::isfinite(x)) return false;
  }
  time_s_ = state[2];
  pinch_n_ = state[3];
  const double* p = state.data() + 4;
  for (std::size_t i = 0; i < bodies; ++i, p += kPerBody) {
    if (im.bodies[i]->getInvMass() != 0.0) restoreBody(*im.bodies[i], p);
  }
  for (auto& sp : im.spheres) {
    restoreBody(*sp, p);
    p += kPerBody;
  }
  for (int k = 0; k < 2; ++k, p += kPerGrip) {
    Impl::Grip& g = im.grips[k];
    if (g.rows) im.world.removeConstraint(g.rows.get());
    g = {};
    const int bone = static_cast<int>(p[0]);
    if (bone < 0 || static_cast<std::size_t>(bone) >= bodies) continue;
    g.bone = im.bodies[static_cast<std::size_t>(bone)].get();
    g.anchor_local = Vec3(p[1], p[2], p[3]);
    g.normal = Vec3(p[4], p[5], p[6]);
    g.normal_n = p[7];
    g.rows = std::make_unique<PadGrip>(*im.spheres[k], *g.bone);
    im.world.addConstraint(g.rows.get(), false);
  }
  for (std::size_t i = 0; i < bodies; ++i) im.wakeChain(static_cast<int>(i));
  return true;
}

Vec3 HandSim::mcpAngles() const {
  const auto ji = static_cast<std::size_t>(impl_->mcp_joint);
  return impl_->jointState(model_.joints()[ji], ji).angles;
}

Vec3 HandSim::mcpRates() const {
  const auto ji = static_cast<std::size_t>(impl_->mcp_joint);
  return impl_->jointState(model_.joints()[ji], ji).rates;
}

std::vector<double> HandSim::jointAngles() const {
  std::vector<double> out;
  out.reserve(model_.dofCount());
  const auto& joints = model_.joints();
  for (std::size_t ji = 0; ji < joints.size(); ++ji) {
    const Vec3 a = impl_->jointState(joints[ji], ji).angles;
    for (const Dof& d : joints[ji].dofs) out.push_back(a[kAngleOfAxis[d.axis]]);
  }
  return out;
}

Pose HandSim::bonePose(int bone) const {
  const auto i = static_cast<std::size_t>(bone);
  return eig(impl_->bodies[i]->getCenterOfMassTransform()) * impl_->com_in_link[i].inverse();
}

PerFinger<Vec3> HandSim::spherePositionsDevice() const {
  const Pose to_device = device_to_world_.inverse();
  return {to_device * eig(impl_->spheres[0]->getCenterOfMassPosition()),
          to_device * eig(impl_->spheres[1]->getCenterOfMassPosition())};
}

double HandSim::mcpFlexionInertia() const { return axisInertia(impl_->mcp_joint, 1); }

double HandSim::axisInertia(int joint, int axis) const {
  const Impl& im = *impl_;
  const auto ji = static_cast<std::size_t>(joint);
  const Joint& jt = model_.joints()[ji];
  const Pose frame = eig(im.body(jt.parent_bone).getCenterOfMassTransform()) * im.frame_in_a[ji];
  const Vec3 origin = frame.translation();
  const Vec3 a = frame.linear() * Vec3::Unit(axis);
  double inertia = 0.0;
  // Every bone downstream of the joint (bones are stored parents first).
  std::vector<bool> downstream(model_.bones().size(), false);
  downstream[static_cast<std::size_t>(jt.child_bone)] = true;
  for (std::size_t i = 0; i < model_.bones().size(); ++i) {
    const int pj = model_.bones()[i].parent_joint;
    if (pj >= 0 && downstream[static_cast<std::size_t>(
                       model_.joints()[static_cast<std::size_t>(pj)].parent_bone)]) {
      downstream[i] = true;
    }
    const btRigidBody& b = *im.bodies[i];
    if (!downstream[i] || b.getInvMass() == 0.0) continue;
    const Mat3 r = eig(b.getCenterOfMassTransform()).linear();
    const Vec3 inv = eig(b.getInvInertiaDiagLocal());
    const Mat3 i_local = Vec3(1.0 / inv.x(), 1.0 / inv.y(), 1.0 / inv.z()).asDiagonal();
    const Vec3 d = eig(b.getCenterOfMassPosition()) - origin;
    const Vec3 d_perp = d - a * a.dot(d);
    inertia += a.dot(r * i_local * r.transpose() * a) + d_perp.squaredNorm() / b.getInvMass();
  }
  return inertia;
}

}  // namespace telehand::server::sim
