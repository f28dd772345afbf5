#pragma once
/// The 1 kHz haptic loop: read sample -> thimble forces (paper eqs. 1-2) -> local joint model
/// -> safety gate -> write command. `step()` allocates nothing, locks nothing, logs nothing
/// and throws nothing; other threads see what it does through LoopHealth and the SPSC rings.
#include <atomic>
#include <cstdint>
#include <memory>
#include <thread>

#include "client/device/device.h"
#include "telehand.h"
#include "telehand/common/clock.h"
#include "telehand/common/config.h"
#include "telehand/common/joint_model.h"
#include "telehand/common/safety.h"
#include "telehand/common/spsc_ring.h"

namespace telehand::client::loop {

/// Counters the RT thread writes (relaxed) and any thread reads.
struct LoopHealth {
  std::atomic<uint64_t> ticks{0};
  std::atomic<uint64_t> overruns{0};          ///< ticks that finished after the next deadline
  std::atomic<uint64_t> device_read_failures{0};
  std::atomic<uint64_t> device_write_failures{0};
  std::atomic<uint64_t> watchdog_trips{0};
  std::atomic<uint64_t> nonfinite{0};
  std::atomic<uint64_t> clamped{0};
  std::atomic<uint64_t> rate_limited{0};
  std::atomic<uint64_t> samples_dropped{0};   ///< sample ring full: the link thread fell behind
  std::atomic<uint64_t> models_applied{0};
  std::atomic<uint32_t> model_version{0};
  std::atomic<double> force_max_n{0.0};       ///< largest commanded per-finger force
  std::atomic<double> last_force_n{0.0};      ///< thumb + index commanded force magnitude
  std::atomic<double> applied_ref_n{0.0};     ///< student's applied force, reference scale
  std::atomic<int64_t> max_lateness_ns{0};    ///< worst wake-up after a deadline
  std::atomic<uint64_t> device_not_ok{0};     ///< ticks the device was not streaming (zero force)
};

enum class StepStatus { kOk, kNoSample, kSafetyFault };

class HapticLoop {
 public:
  using SampleRing = SpscRing<telehand_msg_DeviceState, 16384>;  // 16 s of samples at 1 kHz
  using ModelRing = SpscRing<JointModelParams, 8>;

  HapticLoop(device::Device& device, const Clock& clock, const JointModelParams& initial_model,
             const SafetyLimits& limits, const LoopConfig& config = {});
  ~HapticLoop();
  HapticLoop(const HapticLoop&) = delete;
  HapticLoop& operator=(const HapticLoop&) = delete;

  /// One tick. Real-time safe.
  StepStatus step() noexcept;

  /// Run step() on a thread at the configured rate, sleeping to absolute deadlines
  /// (CLOCK_MONOTONIC: use with a SteadyClock). stop() joins and commands zero force.
  void start();
  void stop();
  bool running() const noexcept { return running_.load(std::memory_order_acquire); }
  /// 0, or the errno of the failed SCHED_FIFO request (e.g. EPERM), once the thread runs.
  int realtimeError() const noexcept { return rt_error_.load(std::memory_order_acquire); }

  /// Tag outgoing samples with this session (set before start or between ticks).
  void setSession(uint64_t session_id) noexcept {
    session_id_.store(session_id, std::memory_order_release);
  }
  /// Zero actuator output whatever the model says (capture mode).
  void setActuatorsEnabled(bool on) noexcept { actuators_.store(on, std::memory_order_release); }

  SampleRing& samples() noexcept { return *samples_; }   ///< RT produces, link consumes
  ModelRing& models() noexcept { return *models_; }      ///< link produces, RT consumes
  const LoopHealth& health() const noexcept { return health_; }
  uint64_t nextSeq() const noexcept { return next_seq_.load(std::memory_order_acquire); }

 private:
  void run();

  device::Device& device_;
  const Clock& clock_;
  LoopConfig config_;
  JointProxy proxy_;
  SafetyGate gate_;
  std::unique_ptr<SampleRing> samples_;
  std::unique_ptr<ModelRing> models_;
  LoopHealth health_;
  std::atomic<uint64_t> session_id_{0};
  std::atomic<bool> actuators_{true};
  std::atomic<uint64_t> next_seq_{0};
  std::atomic<bool> running_{false};
  std::atomic<int> rt_error_{0};
  std::thread thread_;
  device::DeviceSample sample_{};
  int64_t wall_offset_ns_ = 0;  // wall clock minus the loop clock, fixed at construction
  int64_t last_sample_time_ns_ = INT64_MIN / 2;
};

}  // namespace telehand::client::loop
