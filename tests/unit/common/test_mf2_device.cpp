// The MF-2 device model: encoders, forward/inverse kinematics, Jacobian (finite differences
// and virtual work), FSR calibration and fault flags, device and thimble files.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <random>

#include "telehand/core/error.h"
#include "telehand/core/joint_model.h"
#include "telehand/devices/mf2_device.h"

namespace telehand::mf2 {
namespace {

namespace fs = std::filesystem;

JointAngles homeAngles(const Mf2Kinematics& k) {
  const JointModel m(healthyIndexMcp());
  PerFinger<ThimblePose> home;
  const auto p = m.gripFromAngles(Vec3::Zero(), 0.008);
  for (int f = 0; f < 2; ++f) {
    home[f].position_m = p[f];
    home[f].orientation = m.thimbleOrientation(f, Vec3::Zero());
  }
  JointAngles q;
  EXPECT_TRUE(k.inverse(home, 0.0, q));
  return q;
}

/// Random poses around the MCP grip: the workspace the therapy uses.
JointAngles randomAngles(const Mf2Kinematics& k, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> ang(-0.6, 0.6), base(-0.3, 0.3);
  const JointModel m(healthyIndexMcp());
  const Vec3 a(ang(rng), 0.5 * ang(rng), 0.3 * ang(rng));
  const auto p = m.gripFromAngles(a, 0.008);
  PerFinger<ThimblePose> target;
  for (int f = 0; f < 2; ++f) {
    target[f].position_m = p[f];
    target[f].orientation = m.thimbleOrientation(f, a);
  }
  JointAngles q;
  EXPECT_TRUE(k.inverse(target, base(rng), q));
  return q;
}

TEST(Mf2Encoders, CountsAndAnglesRoundTrip) {
  EncoderCalibration e{26076.0, 1000, -1.0, 1.0};
  EXPECT_DOUBLE_EQ(e.angle(1000), 0.0);
  EXPECT_NEAR(e.angle(1000 + 26076), 1.0, 1e-12);
  EXPECT_EQ(e.counts(0.5), 1000 + 13038);
  EncoderCalibration reversed{-651.9, 0, -3.0, 3.0};
  EXPECT_NEAR(reversed.angle(-652), 652.0 / 651.9, 1e-12);
  const Mf2Kinematics k(defaultMf2());
  const JointAngles q = homeAngles(k);
  const JointAngles back = k.anglesFromCounts(k.countsFromAngles(q));
  for (int i = 0; i < kActuators; ++i) {
    // Quantization: half a count of a 26076 counts/rad encoder.
    EXPECT_NEAR(back.actuators[i], q.actuators[i], 0.5 / 26076.0 + 1e-12) << i;
  }
  for (int f = 0; f < 2; ++f)
    EXPECT_LT((back.gimbal[f] - q.gimbal[f]).cwiseAbs().maxCoeff(), 0.5 / 651.9 + 1e-12);
}

TEST(Mf2Kinematics, SymmetricFiveBarKnownCase) {
  // Equal links, cranks mirrored (120 and 60 deg): the gimbal centre lies on the plane's
  // centre line, at the elbow height plus the distal link's rise.
  const Mf2Description d = defaultMf2();
  const Mf2Kinematics k(d);
  JointAngles q;
  q.actuators[actuatorIndex(kIndex, 1)] = degToRad(120.0);
  q.actuators[actuatorIndex(kIndex, 2)] = degToRad(60.0);
  q.actuators[actuatorIndex(kThumb, 1)] = degToRad(120.0);
  q.actuators[actuatorIndex(kThumb, 2)] = degToRad(60.0);
  PerFinger<ThimblePose> pose;
  ASSERT_TRUE(k.forward(q, pose));
  const double half = 0.015 + 0.10 * std::cos(degToRad(60.0));  // elbow offset from the centre line
  const double rise = 0.10 * std::sin(degToRad(60.0)) + std::sqrt(0.12 * 0.12 - half * half);
  const Vec3 expect_index = d.base_pivot_m + d.fingers[kIndex].yaw_pivot_m + Vec3(0.0, 0.0, rise);
  EXPECT_LT((pose[kIndex].position_m - expect_index).norm(), 1e-12);
  // Distal link 1 pitches up at atan2(rise - elbow height, half); zero gimbal angles leave
  // the thimble at the mount orientation pitched by it.
  const double psi = std::atan2(std::sqrt(0.12 * 0.12 - half * half), half);
  const Mat3 expect_r = Eigen::AngleAxisd(-psi, Vec3::UnitY()).toRotationMatrix() *
                        d.fingers[kIndex].gimbal_mount.toRotationMatrix();
  EXPECT_LT((pose[kIndex].orientation.toRotationMatrix() - expect_r).norm(), 1e-12);
  // The base joint turns both fingers about the base pivot.
  q.actuators[0] = degToRad(30.0);
  PerFinger<ThimblePose> turned;
  ASSERT_TRUE(k.forward(q, turned));
  const Mat3 rz = Eigen::AngleAxisd(degToRad(30.0), Vec3::UnitZ()).toRotationMatrix();
  for (int f = 0; f < 2; ++f) {
    EXPECT_LT((turned[f].position_m - (d.base_pivot_m + rz * (pose[f].position_m - d.base_pivot_m)))
                  .norm(),
              1e-12);
  }
}

TEST(Mf2Kinematics, FiveBarThatCannotCloseIsRejected) {
  // Cranks splayed to 190 and -10 deg: the elbows are 2 (h + 0.1 cos 10) apart. With
  // h = 15 mm that is 0.227 m and the 0.12 m distal links still meet; with h = 40 mm it is
  // 0.277 m and they cannot (bad encoder data looks like this).
  JointAngles q;
  for (int f = 0; f < 2; ++f) {
    q.actuators[actuatorIndex(f, 1)] = degToRad(190.0);
    q.actuators[actuatorIndex(f, 2)] = degToRad(-10.0);
  }
  PerFinger<ThimblePose> pose;
  EXPECT_TRUE(Mf2Kinematics(defaultMf2()).forward(q, pose));
  Mf2Description wide = defaultMf2();
  wide.fingers[kIndex].crank_half_spacing_m = 0.04;
  const Mf2Kinematics kw(wide);
  PerFinger<ThimblePose> untouched;
  untouched[kThumb].position_m = Vec3(1, 2, 3);
  EXPECT_FALSE(kw.forward(q, untouched));
  EXPECT_EQ(untouched[kThumb].position_m, Vec3(1, 2, 3)) << "a failed FK leaves the output alone";
  EXPECT_FALSE(kw.withinLimits(q));
  Jacobian j;
  EXPECT_FALSE(kw.jacobian(q.actuators, j));
}

TEST(Mf2Kinematics, InverseThenForwardReturnsThePose) {
  const Mf2Kinematics k(defaultMf2());
  std::mt19937_64 rng(7);
  const JointModel m(healthyIndexMcp());
  for (int trial = 0; trial < 200; ++trial) {
    const JointAngles q = randomAngles(k, rng);
    ASSERT_TRUE(k.withinLimits(q)) << trial;
    PerFinger<ThimblePose> pose;
    ASSERT_TRUE(k.forward(q, pose));
    JointAngles q2;
    ASSERT_TRUE(k.inverse(pose, q.actuators[0], q2));
    EXPECT_LT((q2.actuators - q.actuators).cwiseAbs().maxCoeff(), 1e-9) << trial;
    for (int f = 0; f < 2; ++f) EXPECT_LT((q2.gimbal[f] - q.gimbal[f]).cwiseAbs().maxCoeff(), 1e-9);
  }
  // The home grip sits near the middle of every gimbal range.
  const JointAngles home = homeAngles(k);
  for (int f = 0; f < 2; ++f) EXPECT_LT(home.gimbal[f].cwiseAbs().maxCoeff(), degToRad(45.0)) << f;
}

TEST(Mf2Kinematics, JacobianMatchesFiniteDifferences) {
  const Mf2Kinematics k(defaultMf2());
  std::mt19937_64 rng(11);
  for (int trial = 0; trial < 100; ++trial) {
    const JointAngles q = randomAngles(k, rng);
    Jacobian j;
    ASSERT_TRUE(k.jacobian(q.actuators, j));
    constexpr double h = 1e-6;
    for (int c = 0; c < kActuators; ++c) {
      JointAngles qp = q, qm = q;
      qp.actuators[c] += h;
      qm.actuators[c] -= h;
      PerFinger<ThimblePose> pp, pm;
      ASSERT_TRUE(k.forward(qp, pp));
      ASSERT_TRUE(k.forward(qm, pm));
      Eigen::Matrix<double, 6, 1> fd;
      fd << (pp[kThumb].position_m - pm[kThumb].position_m) / (2 * h),
          (pp[kIndex].position_m - pm[kIndex].position_m) / (2 * h);
      EXPECT_LT((fd - j.col(c)).cwiseAbs().maxCoeff(), 1e-7)
          << "trial " << trial << " column " << c;
    }
  }
}

TEST(Mf2Kinematics, VirtualWorkPowerAtFingertipsEqualsPowerAtActuators) {
  // Power through the fingertips (F . v, v from the forward kinematics alone) equals the
  // power through the actuators (tau . qdot, tau from the Jacobian transpose).
  const Mf2Kinematics k(defaultMf2());
  std::mt19937_64 rng(3);
  std::normal_distribution<double> n(0.0, 1.0);
  for (int trial = 0; trial < 100; ++trial) {
    const JointAngles q = randomAngles(k, rng);
    ActuatorAngles qdot;
    for (int i = 0; i < kActuators; ++i) qdot[i] = 2.0 * n(rng);  // rad/s
    const PerFinger<Vec3> force{Vec3(n(rng), n(rng), n(rng)) * 2.0,
                                Vec3(n(rng), n(rng), n(rng)) * 2.0};
    ActuatorTorques tau;
    ASSERT_TRUE(k.actuatorTorques(q.actuators, force, tau));
    constexpr double dt = 1e-7;
    JointAngles qp = q, qm = q;
    qp.actuators += qdot * dt;
    qm.actuators -= qdot * dt;
    PerFinger<ThimblePose> pp, pm;
    ASSERT_TRUE(k.forward(qp, pp));
    ASSERT_TRUE(k.forward(qm, pm));
    double p_tip = 0.0;
    for (int f = 0; f < 2; ++f)
      p_tip += force[f].dot((pp[f].position_m - pm[f].position_m) / (2 * dt));
    const double p_act = tau.dot(qdot);
    EXPECT_NEAR(p_tip, p_act, 1e-6 * (1.0 + std::abs(p_act))) << trial;
  }
}

TEST(Mf2Kinematics, TorquesRenderTheRequestedForces) {
  // 4 N at each thimble (the MF-2 maximum) needs well under the actuators' limits at home,
  // and the least-squares inverse of J^T gives the same forces back.
  const Mf2Description d = defaultMf2();
  const Mf2Kinematics k(d);
  const JointAngles q = homeAngles(k);
  const PerFinger<Vec3> f{Vec3(0.0, 0.0, -4.0), Vec3(0.0, 4.0, 0.0)};
  ActuatorTorques tau;
  ASSERT_TRUE(k.actuatorTorques(q.actuators, f, tau));
  EXPECT_TRUE((tau.cwiseAbs().array() < d.max_torque_nm.array()).all()) << tau.transpose();
  PerFinger<Vec3> back;
  ASSERT_TRUE(k.fingertipForces(q.actuators, tau, back));
  for (int i = 0; i < 2; ++i) EXPECT_LT((back[i] - f[i]).norm(), 1e-9);
  // Known case: a vertical force on the index loads only that finger's joints and the
  // base; the thumb's actuators feel nothing.
  const PerFinger<Vec3> down{Vec3::Zero(), Vec3(0.0, 0.0, -1.0)};
  ASSERT_TRUE(k.actuatorTorques(q.actuators, down, tau));
  for (int j = 0; j < 3; ++j) EXPECT_EQ(tau[actuatorIndex(kThumb, j)], 0.0);
  EXPECT_NEAR(tau[0], 0.0, 1e-12) << "a vertical force has no moment about the vertical base axis";
  EXPECT_NEAR(tau[actuatorIndex(kIndex, 0)], 0.0, 1e-12);
}

TEST(ThimbleCalibration, CountsToNewtonsKnownCases) {
  ThimbleCalibration cal;
  cal.fsr = {FsrCalibration{40, 200, 4000, 10}, FsrCalibration{30, 100, 4000, 10},
             FsrCalibration{50, 150, 4000, 10}, FsrCalibration{40, 200, 4000, 10}};
  // sensors: end 3 N, side+ 5 N, side- 2 N, pad 4 N.
  const ThimbleReading r = calibrateThimble(cal, {640, 530, 350, 840});
  EXPECT_FLOAT_EQ(r.fsr_n[0], 3.0f);
  EXPECT_FLOAT_EQ(r.fsr_n[1], 5.0f);
  EXPECT_FLOAT_EQ(r.fsr_n[2], 2.0f);
  EXPECT_FLOAT_EQ(r.fsr_n[3], 4.0f);
  EXPECT_NEAR(r.forces.tangential_n, 3.0, 1e-6);  // eq. 1
  EXPECT_NEAR(r.forces.normal_n, 5.0, 1e-6);      // eq. 2
  EXPECT_TRUE(r.normal_valid && r.tangential_valid);
  EXPECT_EQ(r.faultMask(), 0);
  // Below the zero reading is no negative pressure.
  EXPECT_EQ(calibrateThimble(cal, {30, 30, 50, 40}).fsr_n[0], 0.0f);
}

TEST(ThimbleCalibration, SaturatedAndOpenChannelsAreFlaggedNotSilentlyUsed) {
  ThimbleCalibration cal;
  for (auto& s : cal.fsr) s = FsrCalibration{40, 180, 4000, 10};
  const ThimbleReading sat = calibrateThimble(cal, {4095, 400, 400, 500});
  EXPECT_EQ(sat.fault[0], kFsrSaturated);
  EXPECT_FALSE(sat.normal_valid) << "eq. 2 needs sensor 1";
  EXPECT_TRUE(sat.tangential_valid);
  EXPECT_EQ(sat.faultMask(), 0b0001);
  const ThimbleReading open = calibrateThimble(cal, {400, 400, 3, 500});
  EXPECT_EQ(open.fault[2], kFsrDead);
  EXPECT_FALSE(open.tangential_valid);
  EXPECT_TRUE(open.normal_valid);
  EXPECT_EQ(open.faultMask(), 0b0100);
}

TEST(ThimbleCalibration, StuckChannelIsDeadAfterItsWindow) {
  ThimbleCalibration cal;
  for (auto& s : cal.fsr) s = FsrCalibration{40, 180, 4000, 10};
  cal.stuck_samples = 100;
  FsrMonitor mon(cal);
  std::mt19937_64 rng(1);
  std::uniform_int_distribution<int> jitter(-2, 2);
  ThimbleReading r;
  for (int i = 0; i < 99; ++i) {
    r = mon.update({static_cast<uint16_t>(400 + jitter(rng)), 777,
                    static_cast<uint16_t>(400 + (i % 2)), static_cast<uint16_t>(500 + (i % 3))});
    EXPECT_EQ(r.fault[1], kFsrOk) << i;
  }
  r = mon.update({401, 777, 400, 500});
  EXPECT_EQ(r.fault[1], kFsrDead) << "100 identical readings: no ADC noise, no sensor";
  EXPECT_FALSE(r.tangential_valid);
  EXPECT_EQ(r.fault[2], kFsrOk);
  r = mon.update({401, 778, 401, 501});
  EXPECT_EQ(r.fault[1], kFsrOk) << "it comes back as soon as it moves";
}

TEST(Mf2DeviceFile, ShippedDeviceFileLoads) {
  const Mf2Description d =
      loadMf2Description(std::string(TELEHAND_DEPLOY_DIR) + "/devices/mf2.toml");
  EXPECT_EQ(d.name, "mf2-sim");
  EXPECT_EQ(d.thimbles[kThumb].serial, "T01");
  EXPECT_EQ(d.thimbles[kIndex].serial, "T02");
  EXPECT_DOUBLE_EQ(d.thimbles[kThumb].fsr[0].counts_per_n, 176.0);
  // The file states the built-in values.
  const Mf2Description def = defaultMf2();
  EXPECT_LT((d.base_pivot_m - def.base_pivot_m).norm(), 1e-12);
  for (int f = 0; f < 2; ++f) {
    EXPECT_LT((d.fingers[f].yaw_pivot_m - def.fingers[f].yaw_pivot_m).norm(), 1e-12);
    EXPECT_LT(d.fingers[f].gimbal_mount.angularDistance(def.fingers[f].gimbal_mount), 1e-9);
    EXPECT_EQ(d.fingers[f].crank_m, def.fingers[f].crank_m);
    EXPECT_EQ(d.fingers[f].distal_m, def.fingers[f].distal_m);
  }
  for (int i = 0; i < kActuators; ++i) {
    EXPECT_NEAR(d.actuator_encoders[i].counts_per_rad, def.actuator_encoders[i].counts_per_rad,
                0.5);
  }
}

class Mf2DeviceFileErrors : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("telehand-mf2-" + std::to_string(getpid()));
    fs::create_directories(dir_);
    fs::copy(std::string(TELEHAND_DEPLOY_DIR) + "/devices", dir_ / "devices",
             fs::copy_options::recursive);
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::string rewrite(const std::string& from, const std::string& to) {
    const fs::path p = dir_ / "devices" / "mf2.toml";
    std::ifstream in(p);
    std::string text((std::istreambuf_iterator<char>(in)), {});
    const auto at = text.find(from);
    EXPECT_NE(at, std::string::npos) << from;
    text.replace(at, from.size(), to);
    std::ofstream(p) << text;
    return p.string();
  }
  std::string error(const std::string& path) {
    try {
      loadMf2Description(path);
    } catch (const ConfigError& e) {
      return e.what();
    }
    return "";
  }
  fs::path dir_;
};

TEST_F(Mf2DeviceFileErrors, NamesFileLineAndKey) {
  const std::string p = rewrite("crank_half_spacing_m = 0.015", "crank_spacing = 0.015");
  const std::string e = error(p);
  EXPECT_NE(e.find("mf2.toml"), std::string::npos) << e;
  EXPECT_NE(e.find("unknown key 'thumb.crank_spacing'"), std::string::npos) << e;
  EXPECT_NE(e.find("line "), std::string::npos) << e;
}

TEST_F(Mf2DeviceFileErrors, MissingThimbleFileIsNamed) {
  const std::string p = rewrite("thimbles/index-T02.toml", "thimbles/index-T99.toml");
  const std::string e = error(p);
  EXPECT_NE(e.find("index-T99.toml"), std::string::npos) << e;
}

TEST_F(Mf2DeviceFileErrors, BadCalibrationIsNamed) {
  const fs::path t = dir_ / "devices" / "thimbles" / "thumb-T01.toml";
  std::ifstream in(t);
  std::string text((std::istreambuf_iterator<char>(in)), {});
  text.replace(text.find("counts_per_n = 183.0"), 20, "counts_per_n = -5.0");
  std::ofstream(t) << text;
  const std::string e = error((dir_ / "devices" / "mf2.toml").string());
  EXPECT_NE(e.find("thumb-T01.toml"), std::string::npos) << e;
  EXPECT_NE(e.find("fsr2.counts_per_n"), std::string::npos) << e;
}

// Encoder zeros and ranges whose counts the device's 32-bit counters cannot carry are refused,
// and an empty range names its keys and element.
TEST_F(Mf2DeviceFileErrors, EncoderValuesTheWireCannotCarryAreNamed) {
  const std::string p = rewrite("zero_counts = [0, 0, 0]", "zero_counts = [0, 3e9, 0]");
  const std::string e = error(p);
  EXPECT_NE(e.find("32-bit"), std::string::npos) << e;
  EXPECT_NE(e.find("'thumb.counts_per_rad', 'zero_counts'"), std::string::npos) << e;
  EXPECT_NE(e.find("element 2"), std::string::npos) << e;
}

TEST_F(Mf2DeviceFileErrors, AnEmptyEncoderRangeNamesItsKeysAndElement) {
  const std::string p =
      rewrite("min_deg = [-60.0, -90.0, -90.0]", "min_deg = [-60.0, 250.0, -90.0]");
  const std::string e = error(p);
  EXPECT_NE(e.find("range is empty"), std::string::npos) << e;
  EXPECT_NE(e.find("'thumb.counts_per_rad', 'zero_counts', 'min_deg', 'max_deg' element 2"),
            std::string::npos)
      << e;
}

// A thimble's FSR counts are a 12-bit ADC's, and its zero and slope are its own: a value the ADC
// cannot read, or a sensor without its calibration, is refused naming the key.
TEST_F(Mf2DeviceFileErrors, ThimbleCountsTheAdcCannotReadOrMissingAreNamed) {
  const fs::path t = dir_ / "devices" / "thimbles" / "thumb-T01.toml";
  std::ifstream in(t);
  const std::string original((std::istreambuf_iterator<char>(in)), {});
  in.close();
  auto tried = [&](const std::string& from, const std::string& to) {
    std::string text = original;
    const auto at = text.find(from);
    EXPECT_NE(at, std::string::npos) << from;
    text.replace(at, from.size(), to);
    std::ofstream(t) << text;
    return error((dir_ / "devices" / "mf2.toml").string());
  };
  std::string e = tried("saturation_counts = 4000.0", "saturation_counts = 5000.0");
  EXPECT_NE(e.find("fsr1.saturation_counts"), std::string::npos) << e;
  EXPECT_NE(e.find("4095"), std::string::npos) << e;
  e = tried("counts_per_n = 183.0", "");
  EXPECT_NE(e.find("fsr2.counts_per_n' must be set"), std::string::npos) << e;
}

TEST_F(Mf2DeviceFileErrors, LinkageThatCannotReachTheGripIsRejected) {
  const std::string p = rewrite("distal_m = [0.12, 0.12]", "distal_m = [0.03, 0.03]");
  EXPECT_NE(error(p).find("cannot reach the home grip"), std::string::npos) << error(p);
}

}  // namespace
}  // namespace telehand::mf2
