// The MF-2 wire protocol (codec, sequence checks), the calibration seam and the emulated
// firmware, without USB.
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "mf2_firmware.h"
#include "telehand/core/joint_model.h"
#include "telehand/devices/mf2_calibration.h"
#include "telehand/devices/mf2_protocol.h"

namespace telehand::devices::proto {
namespace {

std::vector<uint8_t> fromHex(const std::string& h) {
  std::vector<uint8_t> b;
  for (std::size_t i = 0; i + 1 < h.size(); i += 2) {
    b.push_back(static_cast<uint8_t>(std::stoi(h.substr(i, 2), nullptr, 16)));
  }
  return b;
}

// Golden packets built independently (Python struct + zlib.crc32) from the layout in
// docs/mf2-usb-protocol.md.
const char* kGoldenState =
    "4d320101040302010e0d0c0b0a000000ffffffff02000000206cfbff801a06000500000006000000f9ffffff"
    "6400000038ffffff2c01000070fefffff4010000a8fdffff000001000200ff0f6400c8002c01900105000700"
    "efbeadde10088434";
const char* kGoldenCommand = "4d3201022a000000e80318fc00000100ffffff7f00800500140000008088a62a";

StatePacket goldenState() {
  StatePacket s;
  s.seq = 0x01020304;
  s.device_time_us = 0x0000000A0B0C0D0E;
  s.actuator_counts = {-1, 2, -300000, 400000, 5, 6, -7};
  s.gimbal_counts = {100, -200, 300, -400, 500, -600};
  s.fsr_raw = {0, 1, 2, 4095, 100, 200, 300, 400};
  s.status = kStatusEnabled | kStatusEstopLatched;
  s.rx_errors = 7;
  s.last_command_seq = 0xDEADBEEF;
  return s;
}

CommandPacket goldenCommand() {
  CommandPacket c;
  c.seq = 42;
  c.current_ma = {1000, -1000, 0, 1, -1, 32767, -32768};
  c.flags = kCommandEnable | kCommandClearFault;
  c.watchdog_ms = 20;
  return c;
}

TEST(Mf2Protocol, Crc32MatchesTheStandardCheckValue) {
  const std::string check = "123456789";
  EXPECT_EQ(crc32({reinterpret_cast<const uint8_t*>(check.data()), check.size()}), 0xCBF43926u);
}

TEST(Mf2Protocol, StateEncodingMatchesTheDocumentedLayout) {
  std::array<uint8_t, kStateSize> buf{};
  ASSERT_EQ(encodeState(goldenState(), buf), kStateSize);
  EXPECT_EQ(std::vector<uint8_t>(buf.begin(), buf.end()), fromHex(kGoldenState));

  StatePacket back;
  ASSERT_EQ(decodeState(fromHex(kGoldenState), back), DecodeError::kOk);
  const StatePacket g = goldenState();
  EXPECT_EQ(back.seq, g.seq);
  EXPECT_EQ(back.device_time_us, g.device_time_us);
  EXPECT_EQ(back.actuator_counts, g.actuator_counts);
  EXPECT_EQ(back.gimbal_counts, g.gimbal_counts);
  EXPECT_EQ(back.fsr_raw, g.fsr_raw);
  EXPECT_EQ(back.status, g.status);
  EXPECT_EQ(back.rx_errors, g.rx_errors);
  EXPECT_EQ(back.last_command_seq, g.last_command_seq);
}

TEST(Mf2Protocol, CommandEncodingMatchesTheDocumentedLayout) {
  std::array<uint8_t, kCommandSize> buf{};
  ASSERT_EQ(encodeCommand(goldenCommand(), buf), kCommandSize);
  EXPECT_EQ(std::vector<uint8_t>(buf.begin(), buf.end()), fromHex(kGoldenCommand));
  CommandPacket back;
  ASSERT_EQ(decodeCommand(fromHex(kGoldenCommand), back), DecodeError::kOk);
  EXPECT_EQ(back.seq, 42u);
  EXPECT_EQ(back.current_ma, goldenCommand().current_ma);
  EXPECT_EQ(back.flags, goldenCommand().flags);
  EXPECT_EQ(back.watchdog_ms, 20);
}

TEST(Mf2Protocol, EncodersRefuseShortBuffers) {
  std::array<uint8_t, kStateSize - 1> small{};
  EXPECT_EQ(encodeState(goldenState(), small), 0u);
  std::array<uint8_t, kCommandSize - 1> small_c{};
  EXPECT_EQ(encodeCommand(goldenCommand(), small_c), 0u);
}

TEST(Mf2Protocol, EverySingleBitFlipIsRejected) {
  const std::vector<uint8_t> good = fromHex(kGoldenState);
  StatePacket out;
  out.seq = 777;
  for (std::size_t byte = 0; byte < good.size(); ++byte) {
    for (int bit = 0; bit < 8; ++bit) {
      std::vector<uint8_t> bad = good;
      bad[byte] ^= static_cast<uint8_t>(1u << bit);
      ASSERT_NE(decodeState(bad, out), DecodeError::kOk) << "byte " << byte << " bit " << bit;
    }
  }
  EXPECT_EQ(out.seq, 777u) << "a rejected packet must not touch the output";
  const std::vector<uint8_t> good_c = fromHex(kGoldenCommand);
  CommandPacket c;
  for (std::size_t byte = 0; byte < good_c.size(); ++byte) {
    for (int bit = 0; bit < 8; ++bit) {
      std::vector<uint8_t> bad = good_c;
      bad[byte] ^= static_cast<uint8_t>(1u << bit);
      ASSERT_NE(decodeCommand(bad, c), DecodeError::kOk) << "byte " << byte << " bit " << bit;
    }
  }
}

TEST(Mf2Protocol, LengthMagicVersionTypeAndCrcErrorsAreNamed) {
  const std::vector<uint8_t> good = fromHex(kGoldenState);
  StatePacket s;
  for (std::size_t n = 0; n < good.size(); ++n) {
    EXPECT_EQ(decodeState({good.data(), n}, s), DecodeError::kShort) << n;
  }
  std::vector<uint8_t> longer = good;
  longer.push_back(0);
  EXPECT_EQ(decodeState(longer, s), DecodeError::kLong);

  std::vector<uint8_t> bad = good;
  bad[1] = 'X';
  EXPECT_EQ(decodeState(bad, s), DecodeError::kBadMagic);

  std::array<uint8_t, kStateSize> v2{};
  encodeState(goldenState(), v2, 2);  // a future protocol with a valid CRC
  EXPECT_EQ(decodeState(v2, s), DecodeError::kBadVersion);

  // A command where a state is expected (and the reverse) is the wrong type, even padded.
  std::vector<uint8_t> cmd = fromHex(kGoldenCommand);
  CommandPacket c;
  EXPECT_EQ(decodeCommand(good, c), DecodeError::kLong);
  EXPECT_EQ(decodeState(cmd, s), DecodeError::kShort);
  std::array<uint8_t, kStateSize> typed{};
  encodeState(goldenState(), typed);
  typed[3] = kTypeCommand;
  EXPECT_EQ(decodeState(typed, s), DecodeError::kBadType);

  bad = good;
  bad[95] ^= 0xff;
  EXPECT_EQ(decodeState(bad, s), DecodeError::kBadCrc);
  EXPECT_EQ(toString(DecodeError::kBadCrc), "CRC mismatch");
}

TEST(Mf2Protocol, OutOfRangeValuesWithAValidCrcAreRejected) {
  StatePacket s = goldenState();
  std::array<uint8_t, kStateSize> buf{};
  s.fsr_raw[5] = kFsrMaxRaw + 1;
  encodeState(s, buf);
  StatePacket out;
  EXPECT_EQ(decodeState(buf, out), DecodeError::kBadValue);
  s = goldenState();
  s.status = 0x0100;
  encodeState(s, buf);
  EXPECT_EQ(decodeState(buf, out), DecodeError::kBadValue);

  std::array<uint8_t, kCommandSize> cb{};
  CommandPacket c = goldenCommand();
  CommandPacket cout;
  c.flags = 0x08;
  encodeCommand(c, cb);
  EXPECT_EQ(decodeCommand(cb, cout), DecodeError::kBadValue);
  c = goldenCommand();
  c.watchdog_ms = 1;
  encodeCommand(c, cb);
  EXPECT_EQ(decodeCommand(cb, cout), DecodeError::kBadValue);
  c.watchdog_ms = 1001;
  encodeCommand(c, cb);
  EXPECT_EQ(decodeCommand(cb, cout), DecodeError::kBadValue);
}

TEST(SequenceTracker, AcceptsInOrderCountsGapsRejectsStaleAndOutOfOrder) {
  SequenceTracker t;
  using V = SequenceTracker::Verdict;
  EXPECT_EQ(t.check(10, 10'000), V::kAccept);
  EXPECT_EQ(t.check(11, 11'000), V::kAccept);
  EXPECT_EQ(t.check(11, 11'000), V::kStale);     // duplicate
  EXPECT_EQ(t.check(12, 11'000), V::kStale);     // seq moved, device time did not
  EXPECT_EQ(t.check(9, 9'000), V::kOutOfOrder);  // older than the last accepted
  EXPECT_EQ(t.check(15, 15'000), V::kAccept);    // 12, 13, 14 lost
  EXPECT_EQ(t.accepted(), 3u);
  EXPECT_EQ(t.stale(), 2u);
  EXPECT_EQ(t.outOfOrder(), 1u);
  EXPECT_EQ(t.lost(), 3u);
}

TEST(SequenceTracker, FollowsTheCounterAcrossItsWrap) {
  SequenceTracker t;
  using V = SequenceTracker::Verdict;
  uint64_t time = 1;
  for (uint32_t s = 0xFFFFFFF0u; s != 0x10u; ++s) ASSERT_EQ(t.check(s, time++), V::kAccept) << s;
  EXPECT_EQ(t.lost(), 0u);
  EXPECT_EQ(t.check(0xFFFFFFFFu, time++), V::kOutOfOrder);
}

TEST(SequenceTracker, ResynchronizesAfterTheDeviceRestartsItsCounter) {
  SequenceTracker t;
  using V = SequenceTracker::Verdict;
  for (uint32_t s = 1000; s < 1010; ++s) ASSERT_EQ(t.check(s, s * 1000ull), V::kAccept);
  // The firmware rebooted: counters from zero. Rejected until a run proves it consistent.
  for (uint32_t s = 0; s + 1 < SequenceTracker::kResyncRun; ++s) {
    EXPECT_EQ(t.check(s, s * 1000ull + 1), V::kOutOfOrder) << s;
  }
  EXPECT_EQ(t.check(SequenceTracker::kResyncRun - 1, SequenceTracker::kResyncRun * 1000ull),
            V::kAccept);
  EXPECT_EQ(t.resyncs(), 1u);
  EXPECT_EQ(t.check(SequenceTracker::kResyncRun, SequenceTracker::kResyncRun * 1000ull + 1000),
            V::kAccept);
  // Scattered old packets never resynchronize.
  SequenceTracker u;
  ASSERT_EQ(u.check(100, 100), V::kAccept);
  for (int i = 0; i < 50; ++i) EXPECT_NE(u.check(static_cast<uint32_t>(i % 3), 5), V::kAccept);
  EXPECT_EQ(u.resyncs(), 0u);
}

}  // namespace
}  // namespace telehand::devices::proto

namespace telehand::test::usb {
namespace {

using devices::CurrentsMa;
using devices::FingerSample;
using devices::Mf2ModelCalibration;
using devices::Mf2Motors;

std::vector<uint8_t> command(uint32_t seq, std::array<int16_t, proto::kActuators> ma, uint8_t flags,
                             uint16_t watchdog_ms = 10) {
  proto::CommandPacket c;
  c.seq = seq;
  c.current_ma = ma;
  c.flags = flags;
  c.watchdog_ms = watchdog_ms;
  std::vector<uint8_t> b(proto::kCommandSize);
  proto::encodeCommand(c, b);
  return b;
}

TEST(Mf2Firmware, DrivesOnlyWhenEnabledAndWithinTheWatchdog) {
  Mf2Firmware fw;
  proto::StatePacket s = fw.tick();
  EXPECT_TRUE(s.status & proto::kStatusWatchdogExpired) << "no command yet";
  EXPECT_FALSE(s.status & proto::kStatusEnabled);

  ASSERT_TRUE(fw.receive(command(1, {500, 0, 0, 0, 0, 0, 0}, proto::kCommandEnable, 10)));
  s = fw.tick();
  EXPECT_TRUE(s.status & proto::kStatusEnabled);
  EXPECT_DOUBLE_EQ(fw.appliedCurrentA()[0], 0.5);
  EXPECT_EQ(s.last_command_seq, 1u);
  for (int i = 0; i < 9; ++i) fw.tick();
  EXPECT_DOUBLE_EQ(fw.appliedCurrentA()[0], 0.5) << "the 10th tick: still within 10 ms";
  s = fw.tick();
  EXPECT_TRUE(s.status & proto::kStatusWatchdogExpired);
  EXPECT_DOUBLE_EQ(fw.appliedCurrentA()[0], 0.0) << "10 ms without a command: zero";
  EXPECT_GT(fw.angleRad(0), 0.0) << "the joint turned the way it was pushed";

  ASSERT_TRUE(fw.receive(command(2, {500, 0, 0, 0, 0, 0, 0}, 0)));
  fw.tick();
  EXPECT_DOUBLE_EQ(fw.appliedCurrentA()[0], 0.0) << "enable bit off";
}

TEST(Mf2Firmware, EmergencyStopLatchesUntilCleared) {
  Mf2Firmware fw;
  ASSERT_TRUE(fw.receive(command(1, {800, 0, 0, 0, 0, 0, 0}, proto::kCommandEnable)));
  fw.tick();
  ASSERT_TRUE(fw.enabled());
  fw.pressEstopButton(true);
  proto::StatePacket s = fw.tick();
  EXPECT_TRUE(s.status & proto::kStatusEstopButton);
  EXPECT_DOUBLE_EQ(fw.appliedCurrentA()[0], 0.0);
  fw.pressEstopButton(false);
  ASSERT_TRUE(fw.receive(command(2, {800, 0, 0, 0, 0, 0, 0}, proto::kCommandEnable)));
  s = fw.tick();
  EXPECT_TRUE(s.status & proto::kStatusEstopLatched) << "released button: still latched";
  EXPECT_DOUBLE_EQ(fw.appliedCurrentA()[0], 0.0);
  ASSERT_TRUE(fw.receive(
      command(3, {800, 0, 0, 0, 0, 0, 0}, proto::kCommandEnable | proto::kCommandClearFault)));
  s = fw.tick();
  EXPECT_FALSE(s.status & proto::kStatusEstopLatched);
  EXPECT_DOUBLE_EQ(fw.appliedCurrentA()[0], 0.8);
  ASSERT_TRUE(fw.receive(
      command(4, {800, 0, 0, 0, 0, 0, 0}, proto::kCommandEnable | proto::kCommandEstop)));
  fw.tick();
  EXPECT_TRUE(fw.estopLatched()) << "the host's e-stop bit latches too";
  EXPECT_DOUBLE_EQ(fw.appliedCurrentA()[0], 0.0);
}

TEST(Mf2Firmware, RejectsBadCommandsAndClampsOvercurrent) {
  Mf2Firmware fw;
  std::vector<uint8_t> bad = command(1, {100, 0, 0, 0, 0, 0, 0}, proto::kCommandEnable);
  bad[10] ^= 1;
  EXPECT_FALSE(fw.receive(bad));
  proto::StatePacket s = fw.tick();
  EXPECT_EQ(s.rx_errors, 1);
  EXPECT_TRUE(s.status & proto::kStatusCommandRejected);
  ASSERT_TRUE(fw.receive(command(2, {-9000, 0, 0, 0, 0, 0, 0}, proto::kCommandEnable)));
  s = fw.tick();
  EXPECT_TRUE(s.status & proto::kStatusOvercurrent);
  EXPECT_DOUBLE_EQ(fw.appliedCurrentA()[0], -6.0) << "the driver's 6 A";
}

TEST(Mf2ModelCalibration, CountsGoThroughTheDeviceModel) {
  const mf2::Mf2Description d = mf2::defaultMf2();
  Mf2ModelCalibration cal(d);
  const mf2::Mf2Kinematics kin(d);
  const FirmwareParams fp = firmwareFor(d);  // the thimbles on the joint's grip
  proto::StatePacket s;
  s.actuator_counts = fp.start_counts;
  s.gimbal_counts = fp.gimbal_counts;
  for (int i = 0; i < proto::kFsrs; ++i) {
    s.fsr_raw[i] = static_cast<uint16_t>(
        std::lround(fp.fsr_zero_counts[i] + fp.fsr_counts_per_n[i] * (i + 1)));
  }
  PerFinger<FingerSample> f;
  ASSERT_TRUE(cal.toFingers(s, f));
  PerFinger<mf2::ThimblePose> pose;
  ASSERT_TRUE(kin.forward(kin.anglesFromCounts(Mf2ModelCalibration::encoderCounts(s)), pose));
  const JointModel joint(healthyIndexMcp());
  const PerFinger<Vec3> grip = joint.gripFromAngles(Vec3(degToRad(20.0), 0, 0), 0.008);
  for (int k = 0; k < 2; ++k) {
    EXPECT_EQ(f[k].position_m, pose[k].position_m);
    EXPECT_NEAR((f[k].position_m - grip[k]).norm(), 0.0, 1e-4) << "within encoder resolution";
    for (int j = 0; j < 4; ++j) {
      EXPECT_NEAR(f[k].fsr_n[j], 4 * k + j + 1, 0.01) << "thimble calibration, sensor " << j + 1;
    }
    EXPECT_EQ(f[k].fsr_fault_mask, 0);
  }
  // Counts beyond what the linkage can reach are no pose.
  proto::StatePacket broken = s;
  broken.actuator_counts[1] = static_cast<int32_t>(fp.counts_per_rad[1] * degToRad(70.0));
  EXPECT_FALSE(cal.toFingers(broken, f)) << "thumb yaw 10 degrees past its 60 degree stop";
  broken = s;
  broken.gimbal_counts[4] = static_cast<int32_t>(651.9 * degToRad(95.0));
  EXPECT_FALSE(cal.toFingers(broken, f)) << "index gimbal 2 past its 80 degree stop";
  broken = s;
  broken.actuator_counts[1] = static_cast<int32_t>(fp.counts_per_rad[1] * degToRad(62.0));
  EXPECT_TRUE(cal.toFingers(broken, f)) << "2 degrees past a stop: calibration tolerance";
}

TEST(Mf2ModelCalibration, CurrentsRenderTheForceThroughTheJacobian) {
  const mf2::Mf2Description d = mf2::defaultMf2();
  const Mf2Motors motors;
  const Mf2ModelCalibration cal(d, motors);
  const mf2::Mf2Kinematics kin(d);
  const FirmwareParams fp = firmwareFor(d);
  proto::StatePacket s;
  s.actuator_counts = fp.start_counts;
  s.gimbal_counts = fp.gimbal_counts;
  const mf2::ActuatorAngles q =
      kin.anglesFromCounts(Mf2ModelCalibration::encoderCounts(s)).actuators;
  const PerFinger<Vec3> want{Vec3(0.5, -1.0, 2.0), Vec3(-1.5, 0.25, -0.5)};
  CurrentsMa ma{};
  cal.toCurrents(want, s, ma);
  mf2::ActuatorTorques tau;
  for (int i = 0; i < proto::kActuators; ++i) tau[i] = ma[i] / 1000.0 * motors.nm_per_amp[i];
  PerFinger<Vec3> got;
  ASSERT_TRUE(kin.fingertipForces(q, tau, got));
  for (int k = 0; k < 2; ++k) {
    EXPECT_NEAR((got[k] - want[k]).norm(), 0.0, 0.02) << "1 mA of quantization";
  }
  // Beyond an actuator's limit the torques scale down together: same direction, less force.
  const PerFinger<Vec3> big{Vec3(0.0, 0.0, 400.0), Vec3::Zero()};
  cal.toCurrents(big, s, ma);
  for (int i = 0; i < proto::kActuators; ++i) {
    tau[i] = ma[i] / 1000.0 * motors.nm_per_amp[i];
    EXPECT_LE(std::abs(tau[i]), d.max_torque_nm[i] + 1e-3) << i;
  }
  ASSERT_TRUE(kin.fingertipForces(q, tau, got));
  EXPECT_GT(got[0].normalized().dot(Vec3::UnitZ()), 0.999);
  EXPECT_LT(got[0].norm(), 400.0);
  cal.toCurrents({Vec3(std::nan(""), 0, 0), Vec3::Zero()}, s, ma);
  EXPECT_EQ(ma, CurrentsMa{}) << "non-finite: zero";
}

}  // namespace
}  // namespace telehand::test::usb
