#pragma once
/// Assessment by exploration (paper section V.B): the angle reached in each of the six
/// directions of the MCP and the force at that moment, per phase (a baseline, then a
/// reassessment after treatment), and how the reassessment compares.
#include <array>
#include <string>
#include <vector>

#include "telehand/core/math.h"
#include "telehand/server/store/store.h"

namespace telehand::server::session {

using store::EventRecord;
using store::SessionFile;
using store::SessionInfo;
using store::SessionStore;

class Exploration {
 public:
  /// Direction names, in the order finish() returns them.
  static constexpr std::array<const char*, 6> kDirections = {
      "flexion", "extension", "abduction", "adduction", "supination", "pronation"};

  void begin(const std::string& phase);
  bool active() const noexcept { return active_; }
  const std::string& phase() const noexcept { return phase_; }
  /// One authoritative sample: MCP angles (flexion, abduction, axial) and the force holding
  /// the joint there (N at the lever arm).
  void observe(const Vec3& angles_rad, double force_n) noexcept;
  /// The six reaches of the phase (nothing observed: empty); the phase ends.
  std::vector<SessionStore::Reach> finish();

  /// "flexion 72.1 deg (+3.4 vs baseline), ..." for people.
  static std::string summary(const std::vector<SessionStore::Reach>& now,
                             const std::vector<SessionStore::Reach>& baseline);

 private:
  bool active_ = false;
  bool seen_ = false;
  std::string phase_;
  std::array<double, 6> angle_deg_{};
  std::array<double, 6> force_n_{};
};

}  // namespace telehand::server::session
