#pragma once
/// Synthetic massage captures: the clinician's thumb and index circling on a ground-truth web
/// (the tissue model of common/core) with the actuators off, as the thimbles would measure
/// it: per finger the force the pad presses through paper eqs. 1-2 (the component along the
/// thimble's side axis, and the one along its pad normal) with the paper's ±1.43 N error.
/// Self-contained: the fingers' path is given directly in the device frame (no linkage, no
/// loop), the forces come from tissueContact, so the fit can be checked against a known web.
///
/// The clinician (docs/capture.md "Massage"): first characterises the web as a clinician
/// examining tissue does, then massages it. The characterisation: indentations from the air
/// to depths of up to 10 mm at speeds from 2 to 30 cm/s (how the force grows with the depth
/// and with the depth rate: k, n, λ), then light, fast strokes back and forth (the skin's
/// viscous drag apart from its friction: b·v does not grow with the press, μ·F does not
/// grow with the speed). The massage: contacts of a few seconds, each pressed in from the
/// air at its own speed, a few circles at 10 ± 2 N (harder on one side of each circle),
/// speeding up and slowing down, now and then turning back the other way, then lifted off.
/// The thimbles sit a few degrees off the surface normal and turn about it as a hand does.
#include <cstdint>
#include <string>
#include <vector>

#include "telehand/core/sample.h"
#include "telehand/core/tissue_model.h"
#include "telehand/server/store/store.h"

namespace telehand::server::estimate {

struct SyntheticMassageOptions {
  TissueParams truth = tissueCase("healthy");
  double noise_n = 1.43;  ///< thimble error per measured component, N RMS (docs/facts.md)
  double seconds = 60.0;
  double rate_hz = 1000.0;
  /// Normal force the clinician presses with: a mean per contact within force_n ± spread,
  /// and a swing over each circle (the paper's 10 ± 2 N together).
  double force_n = 10.0;
  double force_spread_n = 0.5;
  double force_swing_n = 1.5;
  double speed_m_s[2] = {0.02, 0.12};  ///< speed on the circle, drawn per contact
  /// Circle radius, drawn per contact: wide enough that the skin slips over part of most
  /// circles (a finger circling inside the stretch the skin allows, mu_static·F / lateral
  /// stiffness, 7 mm on the healthy web at 10 N, drags the skin along and never slides).
  double radius_m[2] = {0.004, 0.012};
  /// How fast the pad goes in at the touch and out at the release (peak), drawn per contact.
  double press_speed_m_s[2] = {0.02, 0.15};
  double contact_s[2] = {2.0, 6.0};  ///< time on the skin per contact
  /// The characterisation before the massage (0 s: none), per finger.
  double indent_s = 20.0;  ///< indentations
  double stroke_s = 20.0;  ///< strokes
  /// An indentation presses in from the air gap to the depth of a force drawn from this
  /// range (log-uniform; no deeper than indent_depth_max_m), holds it for indent_hold_s and
  /// comes back out, in and out each at a peak depth rate drawn from indent_speed_m_s
  /// (log-uniform).
  double indent_force_n[2] = {4.0, 30.0};
  double indent_depth_max_m = 0.010;
  double indent_speed_m_s[2] = {0.1, 0.5};
  double indent_hold_s[2] = {0.02, 0.1};
  double indent_air_s[2] = {0.03, 0.1};  ///< in the air between indentations
  /// A stroke contact: back and forth along a line through the contact area (half length
  /// drawn from stroke_half_m) at a peak speed drawn from stroke_speed_m_s, pressing with a
  /// force drawn from stroke_force_n, for stroke_contact_s.
  double stroke_force_n[2] = {0.5, 2.5};
  double stroke_speed_m_s[2] = {0.15, 0.5};
  double stroke_half_m[2] = {0.008, 0.014};
  double stroke_contact_s[2] = {1.5, 3.0};
  double air_s[2] = {0.15, 0.5};     ///< time in the air between contacts
  double air_gap_m = 0.002;          ///< how far above the skin the pad lifts
  double reverse_probability = 0.5;  ///< a contact turns its circling back once
  double tilt_deg = 6.0;             ///< the pad normal's largest angle off the surface normal
  double yaw_deg = 40.0;             ///< the side axis' largest turn about the normal
  uint64_t seed = 1;
};

struct SyntheticMassage {
  std::vector<Sample> samples;  ///< as a capture session records them (kCapture set)
  TissueParams truth;
};

/// Runs the capture (deterministic for a seed).
SyntheticMassage synthesizeMassage(const SyntheticMassageOptions& o);

/// The ranges randomTissue draws from (docs/capture.md "Massage"): webs that hold the
/// paper's 10 N at a press of 3.5-8 mm.
struct RandomTissueRanges {
  double depth_at_10n_m[2] = {0.0035, 0.008};
  double exponent[2] = {1.2, 2.2};
  double damping_s_per_m[2] = {0.1, 1.5};
  double mu_static[2] = {0.3, 0.9};
  /// How far the skin stretches before it slips at 10 N (mu_static · 10 N / lateral
  /// stiffness; healthy 6.9 mm), which sets the lateral stiffness.
  double stretch_at_10n_m[2] = {0.002, 0.008};
  double mu_ratio[2] = {0.55, 0.9};          ///< mu_kinetic / mu_static
  double viscous_n_s_per_m[2] = {0.5, 5.0};  ///< log-uniform
  double thickness_m[2] = {0.008, 0.02};
  double patch_probability = 1.0 / 3.0;
  double patch_stiffness_factor[2] = {1.5, 3.0};
  double patch_friction_factor[2] = {1.3, 2.5};
};

/// A web drawn at random within the ranges, at a random pose in the device frame (within
/// 5 cm of the origin, tilted up to 30°). The same seed gives the same web.
TissueParams randomTissue(uint64_t seed, const RandomTissueRanges& r = {});

/// Store as a capture session (mode "capture", the case name given); returns its id.
uint64_t storeMassageCapture(store::SessionStore& store, const SyntheticMassage& capture,
                             const std::string& case_name, const std::string& user);

}  // namespace telehand::server::estimate
