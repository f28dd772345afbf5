#include "telehand/devices/mf2_device.h"

#include <algorithm>

namespace telehand::mf2 {

namespace {

Mat3 rotZ(double a) { return Eigen::AngleAxisd(a, Vec3::UnitZ()).toRotationMatrix(); }
Mat3 rotY(double a) { return Eigen::AngleAxisd(a, Vec3::UnitY()).toRotationMatrix(); }
Mat3 rotX(double a) { return Eigen::AngleAxisd(a, Vec3::UnitX()).toRotationMatrix(); }

/// Intersections of circle (c0, r0) and circle (c1, r1): `side` +1 picks the one to the
/// left of c0 -> c1, -1 the one to the right. False when they do not meet.
bool circleIntersection(const Eigen::Vector2d& c0, double r0, const Eigen::Vector2d& c1, double r1,
                        int side, Eigen::Vector2d& out) noexcept {
  const Eigen::Vector2d e = c1 - c0;
  const double dist = e.norm();
  if (!(dist > 1e-12) || dist > r0 + r1 || dist < std::abs(r0 - r1)) return false;
  const double a = (r0 * r0 - r1 * r1 + dist * dist) / (2.0 * dist);
  const double h = std::sqrt(std::max(r0 * r0 - a * a, 0.0));
  const Eigen::Vector2d perp(-e.y() / dist, e.x() / dist);
  out = c0 + e * (a / dist) + perp * (h * side);
  return true;
}

}  // namespace

uint8_t ThimbleReading::faultMask() const noexcept {
  unsigned m = 0;
  for (int i = 0; i < kFsrPerThimble; ++i) m |= fault[i] != kFsrOk ? (1u << i) : 0u;
  return static_cast<uint8_t>(m);
}

ThimbleReading calibrateThimble(const ThimbleCalibration& cal,
                                const std::array<uint16_t, kFsrPerThimble>& counts) noexcept {
  ThimbleReading r;
  for (int i = 0; i < kFsrPerThimble; ++i) {
    const FsrCalibration& c = cal.fsr[i];
    const double raw = counts[i];
    r.fsr_n[i] = static_cast<float>(std::max(c.forceN(raw), 0.0));
    if (raw >= c.saturation_counts) r.fault[i] |= kFsrSaturated;
    if (raw <= c.floor_counts) r.fault[i] |= kFsrDead;
  }
  r.forces = thimbleForces(r.fsr_n);
  // Eq. 1 uses sensors 2 and 3, eq. 2 sensors 1 and 4: a flagged sensor spoils its pair.
  r.tangential_valid = r.fault[1] == kFsrOk && r.fault[2] == kFsrOk;
  r.normal_valid = r.fault[0] == kFsrOk && r.fault[3] == kFsrOk;
  return r;
}

ThimbleReading FsrMonitor::update(const std::array<uint16_t, kFsrPerThimble>& counts) noexcept {
  ThimbleReading r = calibrateThimble(cal_, counts);
  for (int i = 0; i < kFsrPerThimble; ++i) {
    same_[i] = have_last_ && counts[i] == last_[i] ? same_[i] + 1 : 0;
    if (cal_.stuck_samples > 0 && same_[i] + 1 >= cal_.stuck_samples) r.fault[i] |= kFsrDead;
    last_[i] = counts[i];
  }
  have_last_ = true;
  r.tangential_valid = r.fault[1] == kFsrOk && r.fault[2] == kFsrOk;
  r.normal_valid = r.fault[0] == kFsrOk && r.fault[3] == kFsrOk;
  return r;
}

Mf2Kinematics::Mf2Kinematics(const Mf2Description& d) : d_(d) {}

JointAngles Mf2Kinematics::anglesFromCounts(const EncoderCounts& c) const noexcept {
  JointAngles q;
  for (int i = 0; i < kActuators; ++i)
    q.actuators[i] = d_.actuator_encoders[i].angle(c.actuators[i]);
  for (int f = 0; f < 2; ++f) {
    for (int j = 0; j < kGimbalAxes; ++j)
      q.gimbal[f][j] = d_.gimbal_encoders[f][j].angle(c.gimbal[f][j]);
  }
  return q;
}

EncoderCounts Mf2Kinematics::countsFromAngles(const JointAngles& q) const noexcept {
  EncoderCounts c;
  for (int i = 0; i < kActuators; ++i)
    c.actuators[i] = d_.actuator_encoders[i].counts(q.actuators[i]);
  for (int f = 0; f < 2; ++f) {
    for (int j = 0; j < kGimbalAxes; ++j)
      c.gimbal[f][j] = d_.gimbal_encoders[f][j].counts(q.gimbal[f][j]);
  }
  return c;
}

bool Mf2Kinematics::withinLimits(const JointAngles& q) const noexcept {
  for (int i = 0; i < kActuators; ++i) {
    const auto& e = d_.actuator_encoders[i];
    if (!(q.actuators[i] >= e.min_rad && q.actuators[i] <= e.max_rad)) return false;
  }
  for (int f = 0; f < 2; ++f) {
    for (int j = 0; j < kGimbalAxes; ++j) {
      const auto& e = d_.gimbal_encoders[f][j];
      if (!(q.gimbal[f][j] >= e.min_rad && q.gimbal[f][j] <= e.max_rad)) return false;
    }
    FiveBar fb;
    if (!fiveBar(f, q.actuators[actuatorIndex(f, 1)], q.actuators[actuatorIndex(f, 2)], fb)) {
      return false;
    }
  }
  return true;
}

bool Mf2Kinematics::fiveBar(int finger, double q1, double q2, FiveBar& out) const noexcept {
  const FingerLinkage& l = d_.fingers[finger];
  const Eigen::Vector2d a1(-l.crank_half_spacing_m, 0.0), a2(l.crank_half_spacing_m, 0.0);
  const Eigen::Vector2d t1(-std::sin(q1), std::cos(q1)), t2(-std::sin(q2), std::cos(q2));
  const Eigen::Vector2d b1 = a1 + l.crank_m[0] * Eigen::Vector2d(std::cos(q1), std::sin(q1));
  const Eigen::Vector2d b2 = a2 + l.crank_m[1] * Eigen::Vector2d(std::cos(q2), std::sin(q2));
  Eigen::Vector2d p;
  // The distal links meet above the line from elbow 1 to elbow 2.
  if (!circleIntersection(b1, l.distal_m[0], b2, l.distal_m[1], +1, p)) return false;
  const Eigen::Vector2d r1 = p - b1, r2 = p - b2;
  // (p - b_i) . (dp - db_i) = 0 for both distal links.
  Eigen::Matrix2d m;
  m.row(0) = r1.transpose();
  m.row(1) = r2.transpose();
  const double det = m.determinant();
  if (std::abs(det) < 1e-12) return false;  // distal links aligned: singular
  const Eigen::Matrix2d minv = m.inverse();
  out.u = p.x();
  out.w = p.y();
  out.psi = std::atan2(r1.y(), r1.x());
  out.dpdq.col(0) = minv * Eigen::Vector2d(r1.dot(l.crank_m[0] * t1), 0.0);
  out.dpdq.col(1) = minv * Eigen::Vector2d(0.0, r2.dot(l.crank_m[1] * t2));
  return true;
}

bool Mf2Kinematics::forward(const JointAngles& q, PerFinger<ThimblePose>& out) const noexcept {
  PerFinger<ThimblePose> poses;
  const double qb = q.actuators[0];
  for (int f = 0; f < 2; ++f) {
    const FingerLinkage& l = d_.fingers[f];
    const double qy = q.actuators[actuatorIndex(f, 0)];
    FiveBar fb;
    if (!fiveBar(f, q.actuators[actuatorIndex(f, 1)], q.actuators[actuatorIndex(f, 2)], fb)) {
      return false;
    }
    const Mat3 yaw = rotZ(qb + qy);
    poses[f].position_m = d_.base_pivot_m + rotZ(qb) * l.yaw_pivot_m + yaw * Vec3(fb.u, 0.0, fb.w);
    const Vec3& g = q.gimbal[f];
    const Mat3 r = yaw * rotY(-fb.psi) * rotZ(g[0]) * rotY(g[1]) * rotX(g[2]) *
                   l.gimbal_mount.toRotationMatrix();
    poses[f].orientation = Quat(r);
  }
  out = poses;
  return true;
}

bool Mf2Kinematics::jacobian(const ActuatorAngles& q, Jacobian& out) const noexcept {
  out.setZero();
  const double qb = q[0];
  const Vec3 z = Vec3::UnitZ();
  for (int f = 0; f < 2; ++f) {
    const FingerLinkage& l = d_.fingers[f];
    const double qy = q[actuatorIndex(f, 0)];
    FiveBar fb;
    if (!fiveBar(f, q[actuatorIndex(f, 1)], q[actuatorIndex(f, 2)], fb)) return false;
    const Mat3 yaw = rotZ(qb + qy);
    const Vec3 pivot = d_.base_pivot_m + rotZ(qb) * l.yaw_pivot_m;
    const Vec3 p = pivot + yaw * Vec3(fb.u, 0.0, fb.w);
    auto rows = out.block<3, kActuators>(3 * f, 0);
    rows.col(0) = z.cross(p - d_.base_pivot_m);
    rows.col(actuatorIndex(f, 0)) = z.cross(p - pivot);
    for (int j = 0; j < 2; ++j) {
      rows.col(actuatorIndex(f, 1 + j)) = yaw * Vec3(fb.dpdq(0, j), 0.0, fb.dpdq(1, j));
    }
  }
  return true;
}

bool Mf2Kinematics::actuatorTorques(const ActuatorAngles& q, const PerFinger<Vec3>& force_n,
                                    ActuatorTorques& out) const noexcept {
  Jacobian j;
  if (!jacobian(q, j)) return false;
  Eigen::Matrix<double, 6, 1> f;
  f << force_n[kThumb], force_n[kIndex];
  out = j.transpose() * f;
  return true;
}

bool Mf2Kinematics::fingertipForces(const ActuatorAngles& q, const ActuatorTorques& tau,
                                    PerFinger<Vec3>& out) const noexcept {
  Jacobian j;
  if (!jacobian(q, j)) return false;
  // Least squares J^T F = tau: F = (J J^T)^-1 J tau (J has full row rank away from
  // singularities).
  const Eigen::Matrix<double, 6, 6> jjt = j * j.transpose();
  const Eigen::Matrix<double, 6, 1> f = jjt.ldlt().solve(j * tau);
  if (!f.allFinite()) return false;
  out[kThumb] = f.head<3>();
  out[kIndex] = f.tail<3>();
  return true;
}

bool Mf2Kinematics::inverse(const PerFinger<ThimblePose>& target, double base_rad,
                            JointAngles& out) const noexcept {
  JointAngles q;
  q.actuators[0] = base_rad;
  for (int f = 0; f < 2; ++f) {
    const FingerLinkage& l = d_.fingers[f];
    const Vec3 t = rotZ(-base_rad) * (target[f].position_m - d_.base_pivot_m) - l.yaw_pivot_m;
    const double qy = std::atan2(t.y(), t.x());
    const Eigen::Vector2d p(std::hypot(t.x(), t.y()), t.z());
    const Eigen::Vector2d a1(-l.crank_half_spacing_m, 0.0), a2(l.crank_half_spacing_m, 0.0);
    Eigen::Vector2d b1, b2;
    // Elbows out: elbow 1 left of the line from its pivot to P, elbow 2 right of it.
    if (!circleIntersection(a1, l.crank_m[0], p, l.distal_m[0], +1, b1)) return false;
    if (!circleIntersection(a2, l.crank_m[1], p, l.distal_m[1], -1, b2)) return false;
    q.actuators[actuatorIndex(f, 0)] = qy;
    q.actuators[actuatorIndex(f, 1)] = std::atan2(b1.y() - a1.y(), b1.x() - a1.x());
    q.actuators[actuatorIndex(f, 2)] = std::atan2(b2.y() - a2.y(), b2.x() - a2.x());
    const double psi = std::atan2(p.y() - b1.y(), p.x() - b1.x());
    // Gimbal: Rz(g1) Ry(g2) Rx(g3) = (Rz(yaw) Ry(-psi))^T R mount^T.
    const Mat3 g = (rotZ(base_rad + qy) * rotY(-psi)).transpose() *
                   target[f].orientation.toRotationMatrix() *
                   l.gimbal_mount.toRotationMatrix().transpose();
    q.gimbal[f] = Vec3(std::atan2(g(1, 0), g(0, 0)), std::asin(std::clamp(-g(2, 0), -1.0, 1.0)),
                       std::atan2(g(2, 1), g(2, 2)));
  }
  out = q;
  return true;
}

}  // namespace telehand::mf2
