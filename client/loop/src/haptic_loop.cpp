#include "telehand/client/loop/haptic_loop.h"

#include <pthread.h>
#include <sched.h>
#include <sys/prctl.h>
#include <time.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "telehand/core/error.h"
#include "telehand/devices/record.h"

namespace telehand::client::loop {

namespace {
void bump(std::atomic<uint64_t>& c) noexcept { c.fetch_add(1, std::memory_order_relaxed); }
void raise(std::atomic<double>& v, double x) noexcept {
  if (x > v.load(std::memory_order_relaxed)) v.store(x, std::memory_order_relaxed);
}
const PerFinger<Vec3> kNoForce{Vec3::Zero(), Vec3::Zero()};
}  // namespace

const char* faultName(LoopFault f) noexcept {
  switch (f) {
    case LoopFault::kNone:
      return "none";
    case LoopFault::kSustainedClamp:
      return "sustained clamp";
    case LoopFault::kClampStorm:
      return "clamp storm";
    case LoopFault::kRangeRunaway:
      return "range runaway";
  }
  return "unknown";
}

HapticLoop::HapticLoop(devices::Device& device, const Clock& clock,
                       const JointModelParams& initial_model, const SafetyLimits& limits,
                       const LoopConfig& config, const TeleopOptions& teleop)
    : device_(device),
      clock_(clock),
      config_(config),
      proxy_(initial_model, teleop.blend_ns),
      tissue_(initial_model.tissue, initial_model.force_scale, teleop.blend_ns),
      gate_(limits),
      samples_(std::make_unique<SampleRing>()),
      models_(std::make_unique<ModelRing>()),
      forces_(std::make_unique<ForceRing>()),
      passivity_(teleop.passivity),
      direct_(teleop.render == RenderMode::kDirect),
      direct_max_age_ns_(teleop.direct_max_age_ns),
      fault_limits_(teleop.fault) {
  health_.model_version.store(initial_model.version, std::memory_order_relaxed);
  nominal_tick_ns_ = static_cast<int64_t>(std::llround(1e9 / config_.rate_hz));
  for (auto* cap :
       {&health_.joint_damping_cap_ns_per_m, &health_.joint_damping_cap_nominal_ns_per_m,
        &health_.joint_damping_cap_lowest_ns_per_m}) {
    cap->store(kMaxDeviceDampingNsPerM, std::memory_order_relaxed);
  }
  for (auto* bound : {&health_.passivity_bound_ns_per_m, &health_.passivity_bound_nominal_ns_per_m,
                      &health_.passivity_bound_lowest_ns_per_m}) {
    bound->store(passivity_.dampingBoundNsPerM(), std::memory_order_relaxed);
  }
  wall_offset_ns_ = wallNs() - clock_.nowNs();
}

HapticLoop::~HapticLoop() { stop(); }

StepStatus HapticLoop::step() noexcept {
  const int64_t now = clock_.nowNs();
  if (health_.ticks.load(std::memory_order_relaxed) == 0) first_tick_ns_ = now;
  JointModelParams next;
  while (models_->tryPop(next)) {
    // A massage's guide leads the contact point on the web (its path is not the joint's).
    GuideParams web_guide{};
    if (next.technique == Technique::kMassage) std::swap(web_guide, next.guide);
    web_guide_.set(web_guide, last_sample_time_ns_);
    proxy_.setModel(next);
    tissue_.setParams(next.tissue, next.force_scale);
    ++models_taken_;
    bump(health_.models_applied);
    health_.model_version.store(next.version, std::memory_order_relaxed);
  }

  StepStatus status = StepStatus::kOk;
  bool fresh = device_.read(incoming_);
  if (fresh && !(incoming_.fingers[kThumb].position_m.allFinite() &&
                 incoming_.fingers[kIndex].position_m.allFinite())) {
    bump(health_.device_nonfinite);
    fresh = false;
  } else if (fresh) {
    sample_ = incoming_;
  }
  if (fresh) {
    last_sample_time_ns_ = sample_.time_ns;
  } else {
    bump(health_.device_read_failures);
    status = StepStatus::kNoSample;
  }
  // A device that reports itself unplugged, faulted or not streaming is stale now: the gate
  // zeroes the force on this tick instead of after the watchdog period.
  const bool device_ok = device_.status() == devices::DeviceStatus::kOk;
  if (!device_ok) {
    bump(health_.device_not_ok);
    last_sample_time_ns_ = std::min(last_sample_time_ns_, now - gate_.limits().watchdog_ns - 1);
  }
  // An outage: nothing is rendered (the gate's watchdog) or the device is not streaming. The
  // fault detector's windows restart with it, and the first fresh sample after it restarts
  // the passivity controller's velocity windows: the finger moved while nothing was
  // rendered, and that is neither a speed to damp nor a divergence.
  const bool outage = !device_ok || now - last_sample_time_ns_ > gate_.limits().watchdog_ns;
  if (outage && !in_outage_) restartFaultWindows();
  if (!outage && in_outage_ && health_.ticks.load(std::memory_order_relaxed) > 0) {
    passivity_.restart();
    bump(health_.outages);
  }
  in_outage_ = outage;

  followDeviceDynamics(now);

  PerFinger<Vec3> p{sample_.fingers[kThumb].position_m, sample_.fingers[kIndex].position_m};
  // The energy the last tick's force exchanged with the operator.
  passivity_.observe(p, last_command_, sample_.time_ns);
  const double energy = passivity_.energyJ();
  // A model fade may only add what the rendered joint has dissipated so far: the observed
  // energy minus what the joint stores now.
  proxy_.setEnergyBudget(energy - stored_energy_j_);
  // On the sample's clock: the rates difference positions over the time between them (a
  // repeated sample is not a still finger, a resumed one not a jump within one tick).
  const ProxyOutput rendered = proxy_.render(p, sample_.time_ns);
  // The web is stepped whatever the technique (its friction anchors follow the fingers); a
  // massage renders it instead of the joint.
  const TissueOutput web = tissue_.render(p, sample_.time_ns);
  publishKnnInUse();  // after the render: a fade may have started or ended
  const bool massage = proxy_.model().params().technique == Technique::kMassage;
  stored_energy_j_ = massage ? web.potential_j : rendered.potential_j;
  health_.guide_nm.store(rendered.guide_ref_nm.cwiseAbs().maxCoeff(), std::memory_order_relaxed);
  health_.guide_authority.store(
      massage ? web_guide_.current().authority : proxy_.model().params().guide.authority,
      std::memory_order_relaxed);
  const bool direct = direct_.load(std::memory_order_relaxed);
  // Server forces answer samples this loop produced (sequence numbers below next_seq_); one
  // for a later sample is forged or corrupt and, kept as the newest, would hold off every
  // real one after it.
  const uint64_t produced = next_seq_.load(std::memory_order_relaxed);
  DirectForceSample df;
  while (forces_->tryPop(df)) {
    if (df.device_seq >= produced) {
      bump(health_.direct_forces_ahead);
      continue;
    }
    if (!have_direct_ || df.device_seq >= direct_force_.device_seq) {  // reordered: keep newest
      direct_force_ = df;
      direct_taken_ns_ = now;
      have_direct_ = true;
    }
    bump(health_.direct_forces);
  }
  // A server that stopped sending (gone, failing over) leaves no force held: past its age
  // limit the server force is not rendered, until a fresh one arrives.
  const bool direct_fresh = have_direct_ && now - direct_taken_ns_ <= direct_max_age_ns_;
  const bool direct_stale = direct && have_direct_ && !direct_fresh;
  if (direct_stale) {
    bump(health_.direct_stale_ticks);
    if (!direct_stale_) {
      bump(health_.direct_stale_gaps);
      restartFaultWindows();  // nothing rendered meanwhile, as in a device outage
    }
  }
  direct_stale_ = direct_stale;
  PerFinger<Vec3> massage_force = web.force_device_n;
  if (massage) {
    const PerFinger<Vec3> guide =
        web_guide_.force(tissue_.model(), p, tissue_.velocities(), sample_.time_ns,
                         proxy_.model().params().force_scale);
    for (int k = 0; k < 2; ++k) massage_force[k] += guide[k];
    health_.guide_web_n.store(web_guide_.lastReferenceN(), std::memory_order_relaxed);
  }
  const PerFinger<Vec3>& request = direct    ? (direct_fresh ? direct_force_.force_n : kNoForce)
                                   : massage ? massage_force
                                             : rendered.force_device_n;
  PassivityOutput guarded = passivity_.control(request);
  // After a fault nothing is rendered: zero, still through the gate (its rate limit).
  const bool faulted = health_.fault.load(std::memory_order_relaxed) != 0;
  if (faulted) guarded = PassivityOutput{};
  raise(health_.request_max_n, std::max(guarded.force_n[0].norm(), guarded.force_n[1].norm()));
  // Capture (actuators off): the gate zeroes every output and flags it.
  const bool actuators = actuators_.load(std::memory_order_relaxed);
  gate_.setCapture(!actuators);
  const SafetyOutput safe = gate_.apply(guarded.force_n, now, last_sample_time_ns_);
  last_command_ = safe.force_n;
  if (guarded.damping_ns_per_m > 0.0) bump(health_.passivity_activations);
  health_.passivity_energy_j.store(energy, std::memory_order_relaxed);
  if (energy < health_.passivity_min_energy_j.load(std::memory_order_relaxed)) {
    health_.passivity_min_energy_j.store(energy, std::memory_order_relaxed);
  }
  if (rendered.unpaid_energy_j > 0.0) {
    health_.fade_unpaid_energy_j.store(
        health_.fade_unpaid_energy_j.load(std::memory_order_relaxed) + rendered.unpaid_energy_j,
        std::memory_order_relaxed);
  }
  if (rendered.update_step_n > 0.0) {
    double force = 0.0;
    for (int k = 0; k < 2; ++k) force = std::max(force, rendered.force_device_n[k].norm());
    const double ratio = rendered.update_step_n / JointProxy::updateStepBoundN(force);
    if (rendered.update_step_n > health_.update_step_max_n.load(std::memory_order_relaxed)) {
      health_.update_step_max_n.store(rendered.update_step_n, std::memory_order_relaxed);
    }
    if (ratio > health_.update_step_max_ratio.load(std::memory_order_relaxed)) {
      health_.update_step_max_ratio.store(ratio, std::memory_order_relaxed);
    }
  }
  if (safe.flags & kSafetyWatchdog) bump(health_.watchdog_trips);
  if (safe.flags & kSafetyNonFinite) bump(health_.nonfinite);
  if (safe.flags & kSafetyClamped) bump(health_.clamped);
  if (safe.flags & kSafetyRateLimited) bump(health_.rate_limited);
  if (safe.flags & (kSafetyWatchdog | kSafetyNonFinite)) status = StepStatus::kSafetyFault;
  // Only ticks that rendered a force on a fresh sample are judged: capture renders nothing,
  // a device that is not streaming has no angles to judge, and in direct mode nothing is
  // rendered until the server's first force arrives (a round trip after the start) nor
  // while the server force is too old.
  const bool rendering = !direct || direct_fresh;
  const double depth = std::max(web.contact[0].depth_m, web.contact[1].depth_m);
  double excess = 0.0;
  if (massage) {
    excess = depth > kWebRunawayDepthM ? 1e9 : 0.0;
  } else {
    excess = allFinite(rendered.angles_rad) ? proxy_.model().rangeExcessDeg(rendered.angles_rad)
                                            : std::numeric_limits<double>::infinity();
  }
  if (!faulted && actuators && fault_limits_.enabled && fresh && !outage && rendering &&
      !(safe.flags & (kSafetyWatchdog | kSafetyNonFinite)) &&
      detectFault(now, (safe.flags & kSafetyClamped) != 0, excess)) {
    status = StepStatus::kSafetyFault;
  }
  if (faulted) status = StepStatus::kSafetyFault;

  devices::ForceCommand cmd;
  cmd.force_n = safe.force_n;
  if (!device_.write(cmd)) bump(health_.device_write_failures);

  // The record of this tick.
  Sample s;
  s.session_id = session_id_.load(std::memory_order_relaxed);
  s.seq = next_seq_.load(std::memory_order_relaxed);
  s.source_time_ns = sample_.time_ns + wall_offset_ns_;  // wire timestamps are wall clock
  s.model_version = proxy_.version();
  static_assert(kSafetyCapture == sample_flags::kCapture, "safety flags are the record's");
  s.flags = safe.flags | (rendered.blending ? sample_flags::kModelBlending : 0u) |
            (guarded.damping_ns_per_m > 0.0 ? sample_flags::kPassivityControl : 0u) |
            (direct ? sample_flags::kDirectForce : 0u) |
            (overran_ ? sample_flags::kLoopOverrun : 0u);
  s.passivity_energy_j = static_cast<float>(energy);
  s.passivity_damping = static_cast<float>(guarded.damping_ns_per_m);
  const Vec3 applied = devices::recordTick(sample_, safe.force_n, rendered, s);
  if (massage) {
    double normal = 0.0;
    for (int k = 0; k < 2; ++k) {
      s.fingers[k].contact_depth_m = web.contact[k].depth_m;
      const Vec3 f = web.contact[k].force();
      for (int i = 0; i < 3; ++i) s.fingers[k].tissue_force_n[i] = f[i];
      normal = std::max(normal, web.contact[k].normal_n.norm());
    }
    health_.web_depth_m.store(depth, std::memory_order_relaxed);
    if (fresh && actuators) {
      const double scale = proxy_.model().params().force_scale;
      bool in_band = true;
      for (int k = 0; k < 2; ++k) {
        const double n = s.fingers[k].normal_n / scale;
        in_band = in_band && n >= 8.0 && n <= 12.0;
      }
      bump(health_.massage_ticks);
      if (in_band) bump(health_.massage_in_band);
    }
    health_.web_normal_ref_n.store(normal, std::memory_order_relaxed);
  }
  health_.massage.store(massage, std::memory_order_relaxed);
  const double force_max = std::max(safe.force_n[0].norm(), safe.force_n[1].norm());
  overran_ = false;
  if (samples_->tryPush(s)) {
    next_seq_.store(s.seq + 1, std::memory_order_release);
  } else {
    bump(health_.samples_dropped);
  }

  const double scale = proxy_.model().params().force_scale;
  health_.applied_ref_n.store(applied.norm() / scale, std::memory_order_relaxed);
  health_.last_force_n.store((safe.force_n[0] + safe.force_n[1]).norm(), std::memory_order_relaxed);
  if (force_max > health_.force_max_n.load(std::memory_order_relaxed)) {
    health_.force_max_n.store(force_max, std::memory_order_relaxed);
  }
  bump(health_.ticks);
  return status;
}

void HapticLoop::publishKnnInUse() noexcept {
  const std::array<const KnnTorqueModel*, 3> held = proxy_.knnInUse();
  if (held == knn_published_.held && models_taken_ == knn_published_.models_taken) return;
  knn_published_ = {models_taken_, held};
  // Seqlock (Boehm, "Can seqlocks get along with programming language memory models?",
  // 2012): the generation is odd while the fields change.
  const uint32_t gen = knn_gen_.load(std::memory_order_relaxed);
  knn_gen_.store(gen + 1, std::memory_order_relaxed);
  std::atomic_thread_fence(std::memory_order_release);
  knn_taken_.store(models_taken_, std::memory_order_relaxed);
  for (std::size_t i = 0; i < held.size(); ++i) {
    knn_held_[i].store(held[i], std::memory_order_relaxed);
  }
  knn_gen_.store(gen + 2, std::memory_order_release);
}

KnnInUse HapticLoop::knnInUse() const noexcept {
  for (;;) {
    const uint32_t gen = knn_gen_.load(std::memory_order_acquire);
    if (gen & 1u) continue;  // the loop is between two stores
    KnnInUse r;
    r.models_taken = knn_taken_.load(std::memory_order_relaxed);
    for (std::size_t i = 0; i < r.held.size(); ++i) {
      r.held[i] = knn_held_[i].load(std::memory_order_relaxed);
    }
    std::atomic_thread_fence(std::memory_order_acquire);
    if (knn_gen_.load(std::memory_order_relaxed) == gen) return r;
  }
}

void HapticLoop::followDeviceDynamics(int64_t now) noexcept {
  // The longest tick of the last second, at least the nominal one: a late tick holds the
  // force longer, and the same damper is then a larger step.
  const int64_t tick_ns = last_step_ns_ != 0 ? now - last_step_ns_ : nominal_tick_ns_;
  last_step_ns_ = now;
  if (now - long_tick_since_ns_ > kNsPerS || tick_ns > long_tick_ns_) {
    long_tick_ns_ = std::max(tick_ns, nominal_tick_ns_);
    long_tick_since_ns_ = now;
  }
  const devices::DeviceDynamics d = device_.dynamics();
  if (d.lightest_mass_kg == dynamics_.lightest_mass_kg &&
      d.command_delay_ticks == dynamics_.command_delay_ticks &&
      long_tick_ns_ == dynamics_tick_ns_) {
    return;
  }
  dynamics_ = d;
  dynamics_tick_ns_ = long_tick_ns_;
  // A damper rendered on the device acts a command delay after the velocity it is computed
  // from, and that velocity is a tick old besides. The joint may render half of what the
  // lightest direction takes at the nominal tick and all of it at the longest recent one,
  // the passivity controller 0.4 of the latter (docs/teleoperation.md).
  const int delay = d.command_delay_ticks + 1;
  const double nominal =
      stableDampingNsPerM(d.lightest_mass_kg, delay, static_cast<double>(nominal_tick_ns_) * 1e-9);
  const double late =
      stableDampingNsPerM(d.lightest_mass_kg, delay, static_cast<double>(long_tick_ns_) * 1e-9);
  const double joint_cap_nominal =
      nominal > 0.0 ? std::min(kMaxDeviceDampingNsPerM, kJointDampingShare * nominal)
                    : kMaxDeviceDampingNsPerM;
  const double joint_cap = nominal > 0.0 ? std::min(joint_cap_nominal, late) : joint_cap_nominal;
  proxy_.setDeviceDampingCap(joint_cap);
  passivity_.setDeviceLimit(late);
  const double bound = passivity_.dampingBoundNsPerM();
  health_.joint_damping_cap_ns_per_m.store(joint_cap, std::memory_order_relaxed);
  health_.passivity_bound_ns_per_m.store(bound, std::memory_order_relaxed);
  health_.joint_damping_cap_nominal_ns_per_m.store(joint_cap_nominal, std::memory_order_relaxed);
  health_.passivity_bound_nominal_ns_per_m.store(passivity_.boundFor(nominal),
                                                 std::memory_order_relaxed);
  if (joint_cap < health_.joint_damping_cap_lowest_ns_per_m.load(std::memory_order_relaxed)) {
    health_.joint_damping_cap_lowest_ns_per_m.store(joint_cap, std::memory_order_relaxed);
  }
  if (bound < health_.passivity_bound_lowest_ns_per_m.load(std::memory_order_relaxed)) {
    health_.passivity_bound_lowest_ns_per_m.store(bound, std::memory_order_relaxed);
  }
}

bool HapticLoop::detectFault(int64_t now, bool clamped, double excess_deg) noexcept {
  const FaultLimits& lim = fault_limits_;
  LoopFault fault = LoopFault::kNone;
  // Clamp onsets in a leaky bucket that drains storm_onsets per second.
  const int64_t tick_ns = bucket_ns_ == 0 ? 0 : std::max<int64_t>(now - bucket_ns_, 0);
  bucket_ns_ = now;
  onset_bucket_ =
      std::max(onset_bucket_ - lim.storm_onsets * static_cast<double>(tick_ns) * 1e-9, 0.0);
  if (clamped && !was_clamped_) {
    onset_bucket_ += 1.0;
    clamped_since_ns_ = now;
    hold_counted_ = false;
  }
  was_clamped_ = clamped;
  if (onset_bucket_ >= lim.storm_onsets) fault = LoopFault::kClampStorm;
  if (clamped) {
    const int64_t held = now - clamped_since_ns_;
    if (held > health_.clamp_hold_max_ns.load(std::memory_order_relaxed)) {
      health_.clamp_hold_max_ns.store(held, std::memory_order_relaxed);
    }
    if (!hold_counted_ && held >= lim.clamp_hold_ns) {
      hold_counted_ = true;
      bump(health_.clamp_holds);
    }
    if (lim.sustained_clamp_ns > 0 && held >= lim.sustained_clamp_ns) {
      fault = LoopFault::kSustainedClamp;
    }
  }
  // How far the rendering is past its range.
  const bool finite = std::isfinite(excess_deg);
  raise(health_.range_excess_max_deg, finite ? excess_deg : 1e9);
  const bool outside = !finite || excess_deg > lim.range_margin_deg;
  // A finger that starts (or resumes) away from the joint, before the grip is on it, is not
  // running away: the timer arms once the rendered angles have been within the margin.
  // Time outside adds up, time inside drains it a quarter as fast: a rendering that swings
  // through the range and out again, out a fifth of the time or more, is a runaway too.
  if (!outside) in_range_seen_ = true;
  if (outside && in_range_seen_) {
    outside_ns_ += outside_ ? tick_ns : 0;  // the first tick out starts the count
  } else {
    outside_ns_ = std::max<int64_t>(outside_ns_ - tick_ns / 4, 0);
  }
  outside_ = outside;
  if (outside && in_range_seen_ && outside_ns_ >= lim.runaway_ns) {
    fault = LoopFault::kRangeRunaway;
  }
  if (fault == LoopFault::kNone) return false;
  health_.fault_time_ns.store(now - first_tick_ns_, std::memory_order_relaxed);
  health_.fault_clamps.store(health_.clamped.load(std::memory_order_relaxed),
                             std::memory_order_relaxed);
  health_.fault_peak_force_n.store(health_.request_max_n.load(std::memory_order_relaxed),
                                   std::memory_order_relaxed);
  health_.fault.store(static_cast<uint32_t>(fault), std::memory_order_release);
  return true;
}

void HapticLoop::restartFaultWindows() noexcept {
  was_clamped_ = false;
  hold_counted_ = false;
  onset_bucket_ = 0.0;
  bucket_ns_ = 0;
  outside_ = false;
  outside_ns_ = 0;
  in_range_seen_ = false;
}

void HapticLoop::start() {
  if (running_.exchange(true)) return;
  thread_ = std::thread([this] { run(); });
}

void HapticLoop::stop() {
  if (!running_.exchange(false)) return;
  if (thread_.joinable()) thread_.join();
  device_.write(devices::ForceCommand{});
}

void HapticLoop::run() {
  // docs/facts.md: default timer slack wakes a 1 kHz sleep ~84 us late; 1 ns brings it to ~35 us.
  prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);
  pthread_setname_np(pthread_self(), "telehand-rt");
  if (config_.rt_priority > 0) {
    sched_param sp{};
    sp.sched_priority = config_.rt_priority;
    // Best effort: without CAP_SYS_NICE the loop runs at normal priority and says so.
    rt_error_.store(pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp),
                    std::memory_order_release);
  }
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  int64_t deadline = ts.tv_sec * kNsPerS + ts.tv_nsec;
  while (running_.load(std::memory_order_acquire)) {
    step();
    deadline += nominal_tick_ns_;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    const int64_t now = ts.tv_sec * kNsPerS + ts.tv_nsec;
    if (now > deadline) {
      bump(health_.overruns);
      overran_ = true;
      if (now - deadline > 100 * nominal_tick_ns_)
        deadline = now;  // after a long stall, resynchronize
      continue;
    }
    ts.tv_sec = deadline / kNsPerS;
    ts.tv_nsec = deadline % kNsPerS;
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
    }
    clock_gettime(CLOCK_MONOTONIC, &ts);
    const int64_t late = ts.tv_sec * kNsPerS + ts.tv_nsec - deadline;
    if (late > health_.max_lateness_ns.load(std::memory_order_relaxed)) {
      health_.max_lateness_ns.store(late, std::memory_order_relaxed);
    }
  }
}

}  // namespace telehand::client::loop
