#pragma once
/// Haptic guidance for a massage (docs/lessons.md "Massage lessons"): a bounded spring that
/// leads the contact point (the midpoint of the two thimbles) round the demonstration's
/// circle on the web, as the joint's guide leads the MCP angles along the demonstration's
/// path. A massage guide is a GuideParams whose path holds the contact point's position on
/// the web over one lap (x, y in metres in the web frame W, z = 0), evenly in time, whose
/// stiffness is newtons per millimetre and whose bound is newtons per web axis, both at
/// reference scale. Its force, authority times the bounded spring, is shared by the two
/// fingers and lies in the web's plane: it leads the circling, never the press.
///
/// A guide where there was none starts at its path's beginning; a guide that replaces another
/// fades in over 200 ms while the other fades out on its own clock, so the force never steps.
/// Allocation-free: called from the haptic loop's step.
#include <cstdint>

#include "telehand/core/joint_model.h"
#include "telehand/core/math.h"
#include "telehand/core/tissue_model.h"

namespace telehand {

class WebGuide {
 public:
  static constexpr int64_t kFadeNs = 200'000'000;

  /// Adopt `g` at time `t_ns` (the sample clock); nothing changes if it is the guide in use.
  void set(const GuideParams& g, int64_t t_ns) noexcept;
  /// The guide's force on each finger (device frame, device scale: reference times
  /// `force_scale`) with the thimbles at `p_device` moving at `v_device`, at time `t_ns`.
  PerFinger<Vec3> force(const TissueModel& web, const PerFinger<Vec3>& p_device,
                        const PerFinger<Vec3>& v_device, int64_t t_ns,
                        double force_scale) const noexcept;
  /// The last force's magnitude at reference scale (both fingers together), for the loop's
  /// health figures.
  double lastReferenceN() const noexcept { return last_ref_n_; }
  const GuideParams& current() const noexcept { return current_; }

  /// Where the guide leads the contact point at time t (web frame), and how fast.
  static void target(const GuideParams& g, double t_s, Vec3& point, Vec3& velocity) noexcept;

 private:
  GuideParams current_{}, previous_{};
  int64_t start_ns_ = 0, previous_start_ns_ = 0;
  int64_t adopted_ns_ = 0;
  bool fading_ = false;
  mutable double last_ref_n_ = 0.0;
};

}  // namespace telehand
