#pragma once
/// The teleoperation harness: the client's HapticLoop (with the simulated MF-2 and its
/// virtual clinician) and the server's SessionManager (with the Bullet hand) in one process,
/// joined by an emulated link (common/link_emulation.h), in simulated time. Deterministic for
/// a given spec, and much faster than real time, so the whole RTT × loss × mode matrix runs
/// in seconds. The real processes over the same link model run through tools/linkem in
/// network namespaces (tests/system).
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "telehand/client/loop/haptic_loop.h"
#include "telehand/config/config.h"
#include "telehand/core/tissue_model.h"
#include "telehand/netem/link_emulation.h"
#include "telehand/protocol/deadband.h"
#include "telehand/server/sim/hand_model.h"

namespace telehand::teleop {

/// Who holds the device. The force-band clinician pushes a set force (the paper's
/// mobilization, 12-16 N): the force then hardly depends on what is rendered, the angle does.
/// The servo clinician moves the phalanx along a set flexion path through that band (a stiff
/// position servo at the grip): the force is then the rendered joint's at those angles, and
/// every difference in what is rendered shows in the force error.
enum class Clinician { kForceBand, kServo };

struct CellSpec {
  LinkProfile link;  ///< both directions
  client::loop::RenderMode render = client::loop::RenderMode::kModel;
  double seconds = 20.0;
  double steady_from_s = 4.0;  ///< metrics over [steady_from_s, seconds]: past the ramp
  bool passivity_control = true;
  DeadbandConfig deadband;           ///< DeviceState (client) and HandState (server)
  std::string case_name = "regain";  ///< tests/teleop/cases, then deploy/cases
  /// Treatment time over which the recovery case regains its range: short, so that the
  /// server publishes model updates all through the run.
  double recovery_treatment_s = 20.0;
  OperatorConfig op;
  uint64_t seed = 1;
  bool drift_correction = true;  ///< the server folds drift into the model
  Clinician clinician = Clinician::kForceBand;
  /// kMassage: a MODE_MASSAGE session, the simulated MF-2's clinician circling on the case's
  /// web with 10 ± 2 N (SimulatedMassageMf2), the client's loop rendering the web from the
  /// model the server sends (clinician and servo do not apply).
  Technique technique = Technique::kMobilization;
};

struct CellResult {
  std::vector<std::array<float, 6>> force;  ///< commanded per tick (thumb xyz, index xyz), N
  double po_min_j = 0.0;                    ///< lowest passivity observer energy
  double po_final_j = 0.0;
  uint64_t pc_ticks = 0;           ///< ticks the passivity controller damped
  double oscillation = 0.0;        ///< RMS of the force above 15 Hz / RMS of the force
  uint64_t clamped = 0;            ///< ticks the safety gate clamped to the device maximum
  double update_step_max_n = 0.0;  ///< largest force step from a model update
  double update_step_ratio = 0.0;  ///< ... over max(5 % of the force, 0.1 N)
  uint64_t models_applied = 0;
  double fade_unpaid_j = 0.0;         ///< energy fades added beyond what was seen dissipated
  double device_state_pps = 0.0;      ///< live DeviceState packets/s, client -> server
  double up_pps = 0.0;                ///< all packets/s client -> server (live + record chunks)
  double down_pps = 0.0;              ///< packets/s server -> client (models, direct forces)
  double hand_state_pps = 0.0;        ///< HandState/s to remote viewers
  double reconstruction_error = 0.0;  ///< server-side applied force (held) vs true, relative RMS
  uint64_t overruns = 0;              ///< ticks whose step() used more CPU time than the period
  double step_max_us = 0.0;           ///< largest step() CPU time
  uint64_t samples_recorded = 0;      ///< the server's record at the end
  /// Drift over the steady window: the server's MCP angles (HandState) against the angles the
  /// client's proxy rendered for the same device sample, degrees, the largest axis: its mean
  /// (persistent drift) and RMS (with the hand's lag behind the moving thimbles).
  double drift_mean_deg = 0.0;
  double drift_rms_deg = 0.0;
  uint64_t drift_corrections = 0;  ///< models the server published to correct drift
  uint64_t ticks = 0;
  uint32_t fault = 0;  ///< the client loop's latched LoopFault (0: none)
  // Massage (CellSpec::technique kMassage), over the steady window.
  double massage_in_band = 0.0;  ///< share of massage ticks with both pads in 10 ± 2 N
  double web_force_max_n = 0.0;  ///< largest web force the client recorded, reference N
  /// The server's web (HandState.web_force_n) against the client's proxy (the sample's
  /// tissue_force_n) for the same device sample, per finger: |F_server − F_client| /
  /// max(|F_client|, 1 N), its largest and its RMS over the HandStates compared.
  double web_error_max = 0.0;
  double web_error_rms = 0.0;
  uint64_t web_compared = 0;  ///< HandStates compared
};

/// Runs one cell. `hand` may be null (no Bullet hand: no treatment, no recovery updates).
CellResult runCell(const CellSpec& spec, const server::sim::HandModel* hand);

/// Relative RMS difference of the commanded force against a reference run, over the steady
/// window: sqrt(Σ|F − F_ref|²) / sqrt(Σ|F_ref|²).
double forceError(const CellResult& cell, const CellResult& reference, const CellSpec& spec);

/// Stable: no oscillation above the operator's band and the observer never far below zero.
bool stable(const CellResult& r) noexcept;
bool passive(const CellResult& r) noexcept;
/// The massage's stability: the loop rendered to the end without a fault (no clamp storm,
/// no sustained clamp, no pad through the web).
bool massageStable(const CellResult& r) noexcept;

/// Thresholds of stable() and passive().
constexpr double kMaxOscillation = 0.05;
constexpr double kPassivityToleranceJ = 1e-3;

}  // namespace telehand::teleop
