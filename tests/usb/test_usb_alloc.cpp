// HapticLoop::step() with the USB MF-2 allocates nothing, while the driver streams, while
// the device is unplugged and after it is back (the USB thread allocates as it likes: the
// guard counts only the thread that steps). Runs under umockdev-wrapper.
#include <gtest/gtest.h>
#include <sys/prctl.h>

#include <chrono>
#include <thread>

#include "alloc_guard.h"
#include "mf2_emulator.h"
#include "telehand/client/loop/haptic_loop.h"
#include "telehand/client/usb/usb_mf2.h"

namespace telehand::test::usb {
namespace {

using namespace std::chrono_literals;
using devices::DeviceStatus;

TEST(UsbMf2Alloc, StepAllocatesNothingWhileStreamingUnpluggedAndBack) {
  prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);
  EmulatorOptions opt;
  opt.pace_ns = 1'000'000;
  opt.firmware.damping_nm_s_per_rad = 0.03;  // a finger in each thimble (test_usb_mf2.cpp)
  Mf2Emulator emu(opt);
  SteadyClock clock;
  devices::Mf2ModelCalibration cal(mf2::defaultMf2());
  client::usb::UsbMf2 dev({}, cal, clock);
  dev.start();
  ASSERT_TRUE(dev.waitReady(5s)) << dev.statusText();
  // What is counted here is allocation while streaming; a test thread that a busy machine
  // stalls lets the free crank run off under the joint's spring, which the fault detector
  // rightly stops (zero force from then on), so it is off: its own tests judge it.
  client::loop::TeleopOptions teleop;
  teleop.fault.enabled = false;
  client::loop::HapticLoop loop(dev, clock, healthyIndexMcp(), SafetyLimits{}, LoopConfig{},
                                teleop);

  std::size_t allocations = 0, deallocations = 0;
  int fresh = 0, down = 0;
  Sample rec;
  for (int i = 0; i < 3000; ++i) {
    if (i == 1000) emu.unplug();
    if (i == 1500) emu.replug();
    {
      AllocationGuard guard;
      if (loop.step() == client::loop::StepStatus::kOk) ++fresh;
      allocations += guard.allocations();
      deallocations += guard.deallocations();
    }
    down += dev.status() != DeviceStatus::kOk;
    while (loop.samples().tryPop(rec)) {
    }
    std::this_thread::sleep_for(1ms);
  }
  EXPECT_EQ(allocations, 0u) << "HapticLoop::step() with the USB MF-2 allocated";
  EXPECT_EQ(deallocations, 0u);
  // The run really streamed, went through the unplug and came back.
  EXPECT_GT(fresh, 1000);
  EXPECT_GT(down, 10);
  EXPECT_EQ(dev.stats().connects.load(), 2u);
  EXPECT_EQ(dev.status(), DeviceStatus::kOk) << dev.statusText();
  dev.stop();
  EXPECT_EQ(emu.counters().unhandled_ioctls, 0u);
}

}  // namespace
}  // namespace telehand::test::usb
