// The programs against an emulated MF-2: the probe lists and streams it, the client says
// clearly when it is missing, and a session with `--device usb` is recorded by the server.
// This process hosts the emulated bus (under umockdev-wrapper); the programs it starts
// inherit the preload and reach the emulation's ioctl handler. Processes are stopped by PID.
#include <gtest/gtest.h>
#include <stdlib.h>
#include <sys/prctl.h>

#include <cmath>
#include <filesystem>
#include <regex>

#include "mf2_emulator.h"
#include "process.h"
#include "process_test.h"
#include "telehand/server/store/sqlite_store.h"

namespace telehand::test::usb {
namespace {

using namespace std::chrono_literals;
namespace fs = std::filesystem;

class UsbProgramsTest : public ProcessTest {
 protected:
  UsbProgramsTest() : ProcessTest("usb", TELEHAND_LOOPBACK_XML) {}
  void SetUp() override {
    prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);
    ProcessTest::SetUp();
  }
};

TEST_F(UsbProgramsTest, ProbeListsAndStreamsTheDevice) {
  Mf2Emulator emu;
  Process list({TELEHAND_PROBE_BIN}, path("list.log"));
  EXPECT_EQ(list.wait(20s), 0) << list.output();
  EXPECT_NE(list.output().find("MF-2 1209:4d32 at bus 001 address 001, firmware 1.00, serial "
                               "MF2-EMU-0001: ready"),
            std::string::npos)
      << list.output();

  Process client({TELEHAND_CLIENT_BIN, "--list-devices"}, path("client-list.log"));
  EXPECT_EQ(client.wait(20s), 0) << client.output();
  EXPECT_NE(client.output().find("serial MF2-EMU-0001: ready"), std::string::npos)
      << client.output();

  emu.withFirmware([](Mf2Firmware& fw) { fw.setFsrForces({0, 0, 0, 10.0, 0, 0, 0, 0}); });
  Process live({TELEHAND_PROBE_BIN, "--live", "1"}, path("live.log"));
  EXPECT_EQ(live.wait(20s), 0) << live.output();
  const std::string out = live.output();
  EXPECT_GE(matchNumber(out, R"(seq (\d+) t )"), 1u) << out;
  EXPECT_TRUE(
      std::regex_search(out, std::regex(R"(\| fsr N 0\.0\d 0\.0\d 0\.0\d (9\.99|10\.0\d) )")))
      << "the thumb's pad FSR at 10 N, the others at 0 (one count of ADC noise)\n"
      << out;
  EXPECT_NE(out.find("rejected 0, lost"), std::string::npos) << out;

  Process none({TELEHAND_PROBE_BIN, "--usb-pid", "beef"}, path("none.log"));
  EXPECT_EQ(none.wait(20s), 1) << none.output();
  EXPECT_NE(none.output().find("no MF-2 (USB 1209:beef) attached"), std::string::npos);
  Process bad({TELEHAND_PROBE_BIN, "--usb-pid", "xyz"}, path("bad.log"));
  EXPECT_EQ(bad.wait(20s), 2) << bad.output();
  EXPECT_NE(bad.output().find("--usb-pid: 'xyz' is not a 16-bit hex USB ID"), std::string::npos)
      << bad.output();
  EXPECT_EQ(emu.counters().unhandled_ioctls, 0u);
}

TEST_F(UsbProgramsTest, ClientSaysWhenTheDeviceIsMissing) {
  EmulatorOptions other;
  other.product_id = 0x0001;  // something else on the bus
  Mf2Emulator emu(other);
  Process client(cmd(TELEHAND_CLIENT_BIN, {"--device", "usb", "--device-timeout", "1"}),
                 path("client.log"));
  EXPECT_EQ(client.wait(30s), 2) << client.output();
  EXPECT_NE(client.output().find("the MF-2 is not streaming after 1.0 s: no MF-2 (USB 1209:4d32) "
                                 "attached"),
            std::string::npos)
      << client.output();
}

TEST_F(UsbProgramsTest, SessionWithTheUsbDeviceIsRecorded) {
  // A paced device (1 ms, as the real one), held by an operator who pushes the thumb to and
  // fro and presses the index pad with 3 N.
  EmulatorOptions opt;
  opt.pace_ns = 1'000'000;
  opt.firmware.operator_actuator = 2;  // the thumb's first crank
  opt.firmware.operator_amplitude_nm = 0.05;
  opt.firmware.operator_hz = 2.0;
  Mf2Emulator emu(opt);
  emu.withFirmware([](Mf2Firmware& fw) {
    fw.keepHistory(false);
    fw.setFsrForces({0, 0, 0, 0, 0, 0, 0, 3.0});
  });

  const std::string db = path("records.db");
  Process server(cmd(TELEHAND_SERVER_BIN, {"--db", db, "--seconds", "60", "--hand", "none"}),
                 path("server.log"));
  // The emulator's operator swings the thumb's crank with no finger on a joint between the
  // thimbles: the rendered angles go wherever it throws them, which the fault detector would
  // rightly call a runaway. This test is about the link and the record.
  Process client(
      cmd(TELEHAND_CLIENT_BIN, {"--device", "usb", "--seconds", "4", "-q", "--no-fault-stop"}),
      path("client.log"));
  const auto rc = client.wait(60s);
  ASSERT_TRUE(rc.has_value()) << "client did not finish\n" << client.output();
  EXPECT_EQ(*rc, 0) << client.output();
  EXPECT_EQ(server.stop(), 0) << server.output();

  const std::string out = client.output();
  EXPECT_NE(out.find("device usb"), std::string::npos) << out;
  const uint64_t session = matchNumber(out, R"(session (\d+) open)");
  const uint64_t sent = matchNumber(out, R"((\d+) samples sent)");
  ASSERT_GT(session, 0u) << out;
  ASSERT_GT(sent, 3000u) << out;
  EXPECT_GT(matchNumber(out, R"(usb: (\d+) state packets)"), 2000u) << out;
  EXPECT_NE(out.find("0 rejected"), std::string::npos) << out;
  const auto c = emu.counters();
  EXPECT_GT(c.commands_received, 2000u);
  EXPECT_EQ(c.unhandled_ioctls, 0u);

  server::store::SqliteStore store(db, server::store::SqliteStore::Mode::kReadOnly);
  const auto info = store.session(session);
  ASSERT_TRUE(info.has_value());
  EXPECT_EQ(info->state, "closed");
  EXPECT_EQ(info->samples, sent);
  uint64_t expect_seq = 0, gaps = 0, pressed = 0, forced = 0;
  double force_max = 0.0;
  double z_min = 1e9, z_max = -1e9;
  store.forEachSample(session, [&](const Sample& s, bool valid) {
    gaps += s.seq != expect_seq;
    expect_seq = s.seq + 1;
    EXPECT_TRUE(valid);
    // The index pad's 3 N arrives through the protocol and the calibration (12-bit ADC).
    pressed += std::abs(s.fingers[1].fsr_n[3] - 3.0f) < 0.02f;
    const Vec3 f(s.fingers[0].command_n[0], s.fingers[0].command_n[1], s.fingers[0].command_n[2]);
    forced += f.norm() > 0.05;
    force_max = std::max(force_max, f.norm());
    z_min = std::min(z_min, s.fingers[0].position_m[2]);
    z_max = std::max(z_max, s.fingers[0].position_m[2]);
  });
  EXPECT_EQ(gaps, 0u);
  EXPECT_EQ(expect_seq, sent);
  EXPECT_GT(pressed, sent * 9 / 10) << "the index pad force in the record";
  EXPECT_GT(forced, sent / 10) << "the joint pushed back through the device";
  EXPECT_GT(force_max, 0.3);
  EXPECT_GT(z_max - z_min, 0.0005) << "the operator moved the thumb";
}

}  // namespace
}  // namespace telehand::test::usb
