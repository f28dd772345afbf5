#pragma once
/// The 1 kHz haptic loop: read sample -> thimble forces (paper eqs. 1-2) -> local joint model
/// -> safety gate -> write command. `step()` allocates nothing, locks nothing, logs nothing
/// and throws nothing; other threads see what it does through LoopHealth and the SPSC rings.
#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <thread>

#include "telehand/client/loop/passivity.h"
#include "telehand/config/config.h"
#include "telehand/core/clock.h"
#include "telehand/core/joint_model.h"
#include "telehand/core/rt/spsc_ring.h"
#include "telehand/core/safety.h"
#include "telehand/core/sample.h"
#include "telehand/core/web_guide.h"
#include "telehand/devices/device.h"

namespace telehand::client::loop {

/// Counters the RT thread writes (relaxed) and any thread reads.
struct LoopHealth {
  std::atomic<uint64_t> ticks{0};
  std::atomic<uint64_t> overruns{0};  ///< ticks that finished after the next deadline
  std::atomic<uint64_t> device_read_failures{0};
  /// Device samples with a thimble position that is not finite: not taken (the tick renders
  /// as one without a new sample); rendered, one would leave the joint's rate filter NaN.
  std::atomic<uint64_t> device_nonfinite{0};
  std::atomic<uint64_t> device_write_failures{0};
  std::atomic<uint64_t> watchdog_trips{0};
  std::atomic<uint64_t> nonfinite{0};
  std::atomic<uint64_t> clamped{0};
  std::atomic<uint64_t> rate_limited{0};
  std::atomic<uint64_t> samples_dropped{0};  ///< sample ring full: the link thread fell behind
  std::atomic<uint64_t> models_applied{0};
  std::atomic<uint32_t> model_version{0};
  /// A lesson's guide: the largest per-axis guide torque rendered this tick (N·m, reference
  /// scale) and the authority of the guide in the model rendered (0: none).
  std::atomic<double> guide_nm{0.0};
  std::atomic<double> guide_authority{0.0};
  std::atomic<double> force_max_n{0.0};     ///< largest commanded per-finger force
  std::atomic<double> last_force_n{0.0};    ///< thumb + index commanded force magnitude
  std::atomic<double> applied_ref_n{0.0};   ///< student's applied force, reference scale
  std::atomic<int64_t> max_lateness_ns{0};  ///< worst wake-up after a deadline
  std::atomic<uint64_t> device_not_ok{0};   ///< ticks the device was not streaming (zero force)
  // Teleoperation.
  std::atomic<double> passivity_energy_j{0.0};      ///< observer energy now (device J)
  std::atomic<double> passivity_min_energy_j{0.0};  ///< lowest observer energy seen
  std::atomic<uint64_t> passivity_activations{0};   ///< ticks the controller added damping
  /// The most damping the controller may add now, N·s/m: its configured bound, or less on a
  /// light or delayed device (PassivityGuard::setDeviceLimit).
  std::atomic<double> passivity_bound_ns_per_m{0.0};
  /// The most damping the joint model renders at the device, N·s/m per unit lever speed:
  /// kMaxDeviceDampingNsPerM, or less on a light or delayed device.
  std::atomic<double> joint_damping_cap_ns_per_m{0.0};
  /// The two bounds above for the device now at the loop's nominal tick (what holds while
  /// the loop keeps time), and the lowest each has been since the loop started (after a
  /// late tick, or on a lighter device).
  std::atomic<double> passivity_bound_nominal_ns_per_m{0.0};
  std::atomic<double> joint_damping_cap_nominal_ns_per_m{0.0};
  std::atomic<double> passivity_bound_lowest_ns_per_m{0.0};
  std::atomic<double> joint_damping_cap_lowest_ns_per_m{0.0};
  std::atomic<double> update_step_max_n{0.0};      ///< largest force step from a model update
  std::atomic<double> update_step_max_ratio{0.0};  ///< ... over max(5 % of the force, 0.1 N)
  std::atomic<uint64_t> direct_forces{0};          ///< server forces taken (direct mode)
  /// Direct mode: ticks on which the server force held was older than
  /// TeleopOptions::direct_max_age_ns (no server force rendered: zero through the gate), and
  /// how many times it went that old (a server that stopped sending, a failover).
  std::atomic<uint64_t> direct_stale_ticks{0};
  std::atomic<uint64_t> direct_stale_gaps{0};
  /// Direct mode: server forces refused because they answer a sample this loop had not
  /// produced yet (a forged or corrupt device_seq).
  std::atomic<uint64_t> direct_forces_ahead{0};
  /// Energy model fades added that the passivity observer had not seen dissipated (device J):
  /// nonzero only when a stiffer model waited out JointProxy::kEnergyWaitNs.
  std::atomic<double> fade_unpaid_energy_j{0.0};
  // Faults (FaultLimits): the first one latches and the loop renders nothing from then on.
  std::atomic<double> request_max_n{0.0};         ///< largest per-finger force asked of the gate
  std::atomic<double> range_excess_max_deg{0.0};  ///< furthest the proxy went past a range end
  std::atomic<uint32_t> fault{0};                 ///< a LoopFault; 0 = none
  std::atomic<int64_t> fault_time_ns{0};          ///< when, from the first tick
  std::atomic<uint64_t> fault_clamps{0};          ///< clamps counted up to the fault
  std::atomic<double> fault_peak_force_n{0.0};    ///< request_max_n at the fault
  /// Clamps held for FaultLimits::clamp_hold_ns (a push beyond what the device renders): a
  /// warning the client reports, not a fault.
  std::atomic<uint64_t> clamp_holds{0};
  std::atomic<int64_t> clamp_hold_max_ns{0};  ///< longest clamp held (ns)
  std::atomic<uint64_t> outages{0};           ///< device outages the loop resumed from
  // Massage (the web's tissue model rendered instead of the joint).
  std::atomic<bool> massage{false};           ///< the model rendered is the web
  std::atomic<double> web_depth_m{0.0};       ///< deeper pad's depth in the web this tick
  std::atomic<double> web_normal_ref_n{0.0};  ///< the web's normal force, reference, largest finger
  /// Rendered massage ticks with a fresh sample, and those on which both thimbles measured
  /// a normal force (reference scale) within the paper's 10 ± 2 N.
  std::atomic<uint64_t> massage_ticks{0};
  std::atomic<uint64_t> massage_in_band{0};
  std::atomic<double> guide_web_n{0.0};  ///< a massage guide's force, reference N (both pads)
};

/// Why the loop stopped rendering. The thresholds are FaultLimits'.
enum class LoopFault : uint32_t {
  kNone = 0,
  kSustainedClamp = 1,  ///< the gate clamped the force on every tick for sustained_clamp_ns
  kClampStorm = 2,      ///< the force ran in and out of the clamp (clamp onsets) too often
  kRangeRunaway = 3,    ///< the rendered angles left the model's range by range_margin_deg
};
/// "sustained clamp", "clamp storm", "range runaway" ("none").
const char* faultName(LoopFault f) noexcept;

/// When the loop declares a rendering fault (docs/manual.md "Exit codes"). A stable
/// rendering never clamps (the stability suite checks 0 clamps for every shipped case and
/// random ones), so these only have to stay clear of a student deliberately pushing into
/// the device's limit: a push held beyond what the device renders clamps once and stays
/// clamped, an unstable rendering oscillates in and out of the clamp at tens to hundreds of
/// Hz, and a stable one never goes far past the end-of-range wall.
///
/// The detector judges only ticks on which the device streamed a fresh sample and the force
/// was rendered: a device outage (watchdog, a device that is not OK, a replug) restarts its
/// windows (clamp run, onset bucket, runaway timer), so that the outage's transient (the
/// finger moved while nothing was rendered) is not taken for a divergence.
struct FaultLimits {
  bool enabled = true;
  /// A clamp held this long is counted as a warning (LoopHealth::clamp_holds, the client's
  /// summary), not a fault: a student who pushes the joint beyond what the device renders
  /// (more than 16 N per finger at reference scale) is pushing, not diverging, and ending the
  /// session would be wrong for teaching. A diverging rendering shows itself as a clamp storm
  /// or a range runaway, which stay faults.
  int64_t clamp_hold_ns = 250'000'000;
  /// A clamp held this long, with no outage in between, is a sustained-clamp fault: a
  /// push on the end-feel lasts a second or two, a rendering that asks more than the device
  /// renders wherever the finger goes for this long is stuck (0 = never).
  int64_t sustained_clamp_ns = 5'000'000'000;
  double storm_onsets = 20.0;
  /// Rendered angles this far past a range end (or not finite) for runaway_ns, once they have
  /// been within it since the start or the last outage (a finger not yet on the joint is
  /// not a runaway); time back inside takes a quarter of its length off, so that a swing
  /// through the range and out again adds up as well. The end-of-range
  /// wall (1 N/deg at reference scale) asks 25 N more than the curve's end there: more than
  /// the device renders (16 N reference), so only a runaway gets there.
  double range_margin_deg = 25.0;
  int64_t runaway_ns = 20'000'000;
};

/// A force the server computed for the device sample `device_seq` (direct mode).
struct DirectForceSample {
  uint64_t device_seq = 0;
  PerFinger<Vec3> force_n{Vec3::Zero(), Vec3::Zero()};
};

/// How the loop renders: from the local joint model (model-mediated, the product), or the
/// force the server sends back (direct, the baseline design it is compared with).
enum class RenderMode { kModel, kDirect };

struct TeleopOptions {
  RenderMode render = RenderMode::kModel;
  PassivityConfig passivity;
  int64_t blend_ns = 200'000'000;  ///< nominal model fade
  FaultLimits fault;
  /// Direct mode: a server force taken longer ago than this is no longer rendered (zero,
  /// through the gate) until a fresh one arrives. The DeviceState deadline: the server sends
  /// a force for every DeviceState it receives, and the client sends one at least every
  /// 50 ms even with deadband coding (docs/teleoperation.md).
  int64_t direct_max_age_ns = 100'000'000;
};

enum class StepStatus { kOk, kNoSample, kSafetyFault };

/// The k-nearest-neighbour models the loop may still read (HapticLoop::knnInUse): those it
/// holds (JointProxy::knnInUse), and every one handed to it that it has not taken from its
/// model ring yet (the `models_taken`-th and later). The thread that handed them in frees one
/// only when neither holds it.
struct KnnInUse {
  uint64_t models_taken = 0;  ///< models taken from the model ring since the start
  std::array<const KnnTorqueModel*, 3> held{};
};

/// A pad this deep in the web has gone through it: the massage's range runaway. The web is
/// 12-18 mm thick and the paper's 10 N takes 3-9 mm of press (docs/massage.md).
constexpr double kWebRunawayDepthM = 0.03;

class HapticLoop {
 public:
  using SampleRing = SpscRing<Sample, 16384>;  // 16 s of samples at 1 kHz
  using ModelRing = SpscRing<JointModelParams, 8>;
  using ForceRing = SpscRing<DirectForceSample, 256>;

  HapticLoop(devices::Device& device, const Clock& clock, const JointModelParams& initial_model,
             const SafetyLimits& limits, const LoopConfig& config = {},
             const TeleopOptions& teleop = {});
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

  SampleRing& samples() noexcept { return *samples_; }     ///< RT produces, link consumes
  ModelRing& models() noexcept { return *models_; }        ///< link produces, RT consumes
  ForceRing& directForces() noexcept { return *forces_; }  ///< link produces, RT consumes
  /// Set before start or between ticks.
  void setRenderMode(RenderMode m) noexcept {
    direct_.store(m == RenderMode::kDirect, std::memory_order_release);
  }
  RenderMode renderMode() const noexcept {
    return direct_.load(std::memory_order_acquire) ? RenderMode::kDirect : RenderMode::kModel;
  }
  const LoopHealth& health() const noexcept { return health_; }
  /// The joint as rendered (read between ticks, or from the loop's thread).
  const JointProxy& proxy() const noexcept { return proxy_; }
  /// The latched fault (kNone while rendering normally). After a fault the loop commands zero
  /// force (through the gate's rate limit) until it is destroyed.
  LoopFault fault() const noexcept {
    return static_cast<LoopFault>(health_.fault.load(std::memory_order_acquire));
  }
  uint64_t nextSeq() const noexcept { return next_seq_.load(std::memory_order_acquire); }
  /// Any thread: a consistent view of the k-NN models the loop may still read, as of a
  /// recent tick (a seqlock the loop writes without waiting; a reader retries a torn read).
  /// What it does not list, of the models taken from the ring, the loop never reads again.
  KnnInUse knnInUse() const noexcept;

 private:
  void run();
  /// Updates the fault detector with this tick; true when a fault has latched. `excess_deg`:
  /// how far the rendering is past its range (degrees past a joint's range end, or for the
  /// web 1e9 once a pad is deeper than kWebRunawayDepthM; non-finite counts as past).
  /// The device's lightest mass and delay bound the damping the joint model and the passivity
  /// controller add, over the longest tick of the last second (a late tick holds the force
  /// longer: the same damper is then a larger step). Re-read every tick; acted on when they
  /// change.
  void followDeviceDynamics(int64_t now) noexcept;
  /// Publish the models taken and the k-NN models the proxy holds, when they changed.
  void publishKnnInUse() noexcept;
  bool detectFault(int64_t now, bool clamped, double excess_deg) noexcept;
  /// Restart the detector's windows (after a device outage).
  void restartFaultWindows() noexcept;

  devices::Device& device_;
  const Clock& clock_;
  LoopConfig config_;
  JointProxy proxy_;
  TissueProxy tissue_;
  WebGuide web_guide_;  // a massage lesson's guided trial
  SafetyGate gate_;
  std::unique_ptr<SampleRing> samples_;
  std::unique_ptr<ModelRing> models_;
  std::unique_ptr<ForceRing> forces_;
  PassivityGuard passivity_;
  devices::DeviceDynamics dynamics_;  // as last followed
  int64_t dynamics_tick_ns_ = 0;      // the tick the bounds were worked out for
  int64_t nominal_tick_ns_ = 0;       // 1 / LoopConfig::rate_hz
  int64_t last_step_ns_ = 0;          // when the last tick ran (0: none yet)
  int64_t long_tick_ns_ = 0;          // the longest tick since long_tick_since_ns_
  int64_t long_tick_since_ns_ = 0;
  LoopHealth health_;
  std::atomic<bool> direct_{false};
  PerFinger<Vec3> last_command_{Vec3::Zero(), Vec3::Zero()};
  DirectForceSample direct_force_{};
  int64_t direct_max_age_ns_ = 0;
  int64_t direct_taken_ns_ = 0;  // when the loop took direct_force_
  bool have_direct_ = false;     // a server force was taken since the start
  bool direct_stale_ = false;    // the last tick held no fresh server force
  // k-NN models in use (knnInUse): written by the RT thread only, as a seqlock.
  uint64_t models_taken_ = 0;
  KnnInUse knn_published_{};
  std::atomic<uint32_t> knn_gen_{0};  // odd while the loop writes
  std::atomic<uint64_t> knn_taken_{0};
  std::array<std::atomic<const KnnTorqueModel*>, 3> knn_held_{};
  double stored_energy_j_ = 0.0;  // the rendered joint's potential energy last tick
  std::atomic<uint64_t> session_id_{0};
  std::atomic<bool> actuators_{true};
  std::atomic<uint64_t> next_seq_{0};
  std::atomic<bool> running_{false};
  std::atomic<int> rt_error_{0};
  std::thread thread_;
  devices::DeviceSample sample_{};
  devices::DeviceSample incoming_{};  // read into; taken into sample_ when its positions are finite
  int64_t wall_offset_ns_ = 0;        // wall clock minus the loop clock, fixed at construction
  int64_t last_sample_time_ns_ = INT64_MIN / 2;
  // Fault detector state (RT thread only).
  FaultLimits fault_limits_;
  int64_t first_tick_ns_ = 0;
  bool was_clamped_ = false;
  int64_t clamped_since_ns_ = 0;
  double onset_bucket_ = 0.0;
  int64_t bucket_ns_ = 0;
  bool outside_ = false;
  bool in_range_seen_ = false;  // since the detector (re)started
  int64_t outside_ns_ = 0;      // time past the margin, drained a quarter as fast inside
  bool hold_counted_ = false;   // this clamp run already counted as a clamp hold
  bool in_outage_ = false;      // the device is not streaming (nothing rendered)
  bool overran_ = false;        // the last tick finished late: the next sample says so
};

}  // namespace telehand::client::loop
