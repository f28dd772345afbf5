#pragma once
/// Drift between the authoritative hand and the client's proxy, and its correction.
///
/// The proxy renders the joint at the angles the thimbles imply (JointModel::proxyAngles).
/// The server's Bullet hand is the truth: its pads hold the phalanx through skin friction and
/// can slip (a load past the friction limit, a model update that reached the server a round
/// trip before the client, a hard limit), after which the hand's MCP sits a little away from
/// where the thimbles say. Left alone, the client would render forces for a joint angle the
/// record, the score and the supervisors never see.
///
/// The corrector low-passes the drift (hand minus proxy, the same device sample) well below
/// the mobilization band, and when it persists beyond a threshold folds it into the model's
/// grip offset (JointModelParams::grip_offset_rad). The server publishes that as a new model
/// version, which the client fades in like any update: no tick's force steps by more than
/// the update bound and the energy gate pays for it.
#include <cstdint>

#include "telehand/core/math.h"

namespace telehand::server::session {

struct DriftOptions {
  /// Low-pass time constant: a 1-6 Hz mobilization (docs/facts.md) passes at under a tenth of its
  /// amplitude; a slip that stays is corrected within about a second.
  double tau_s = 0.5;
  /// Correct when the filtered drift exceeds this on any axis: half the ±1° to which an
  /// exploration must measure the joint.
  double threshold_deg = 0.5;
  /// Never move the rendered joint further than this from the thimbles.
  double max_offset_deg = 15.0;
  /// At most one correction per this long (each is a reliable model update).
  double min_interval_s = 0.5;
  /// Both pads must hold the phalanx with at least this force (N, device scale): a released
  /// finger springs back to rest wherever the thimbles are, which is not drift.
  double min_grip_n = 0.5;
};

class DriftCorrector {
 public:
  explicit DriftCorrector(const DriftOptions& options = {}) noexcept : o_(options) {}

  /// One live sample. `hand_rad`: the hand's MCP angles after the sample's steps;
  /// `proxy_rad`: the angles the proxy renders for the same sample under the server's
  /// current model (proxyAngles, which includes offset()); `held`: both pads grip;
  /// `dt_s`: simulated time the sample stands for. True when offset() changed and should be
  /// published.
  bool observe(const Vec3& hand_rad, const Vec3& proxy_rad, bool held, double dt_s,
               int64_t now_ns) noexcept;

  /// The correction the current model carries.
  const Vec3& offset() const noexcept { return offset_rad_; }
  /// Filtered drift still to correct (hand minus proxy), rad.
  const Vec3& drift() const noexcept { return drift_rad_; }
  uint64_t corrections() const noexcept { return corrections_; }
  const DriftOptions& options() const noexcept { return o_; }

 private:
  DriftOptions o_;
  Vec3 offset_rad_ = Vec3::Zero();
  Vec3 drift_rad_ = Vec3::Zero();
  int64_t last_correction_ns_ = 0;
  uint64_t corrections_ = 0;
};

}  // namespace telehand::server::session
