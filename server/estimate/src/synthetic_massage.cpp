#include "telehand/server/estimate/synthetic_massage.h"

#include <algorithm>
#include <cmath>
#include <random>

#include "telehand/core/clock.h"

namespace telehand::server::estimate {

namespace {

/// One contact of one finger: pressed in at its start point, circled, stroked or held (an
/// indentation), lifted.
struct Contact {
  enum Kind { kCircle, kIndent, kStroke } kind = kCircle;
  double start_s = 0.0;
  double press_s = 0.0, hold_s = 0.0, release_s = 0.0, air_s = 0.0;
  /// Circle: centre (cx, cy), radius r, start angle phi0. Stroke: through (cx, cy) along
  /// the direction phi0, half length r (the angle is the stroke's phase, from 0). Indent:
  /// at (cx, cy).
  double cx = 0.0, cy = 0.0, r = 0.0, phi0 = 0.0;
  double omega = 0.0;  ///< rad/s, signed (the circling direction)
  double reverse_at_s = -1.0;
  double mod_amp = 0.0, mod_hz = 0.0, mod_phase = 0.0;  ///< speed modulation
  double force_n = 10.0, swing_n = 0.0, swing_phase = 0.0;
  double depth_max_m = 1.0;  ///< no deeper than this
  double end() const { return start_s + press_s + hold_s + release_s + air_s; }
  double startAngle() const { return kind == kStroke ? 0.0 : phi0; }
  /// The surface point at an angle.
  void point(double a, double& x, double& y) const {
    if (kind == kCircle) {
      x = cx + r * std::cos(a);
      y = cy + r * std::sin(a);
    } else if (kind == kStroke) {
      x = cx + r * std::sin(a) * std::cos(phi0);
      y = cy + r * std::sin(a) * std::sin(phi0);
    } else {
      x = cx;
      y = cy;
    }
  }
};

double uniform(std::mt19937_64& rng, const double (&range)[2]) {
  return std::uniform_real_distribution<double>(range[0], range[1])(rng);
}

double logUniform(std::mt19937_64& rng, const double (&range)[2]) {
  return std::exp(
      std::uniform_real_distribution<double>(std::log(range[0]), std::log(range[1]))(rng));
}

/// The contacts of one finger over the capture: the characterisation's indentations and
/// strokes, then the massage's circles.
std::vector<Contact> planContacts(const SyntheticMassageOptions& o, const TissueModel& m,
                                  std::mt19937_64& rng) {
  std::vector<Contact> out;
  const TissueParams& p = m.params();
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const double indent_end = o.indent_s, stroke_end = o.indent_s + o.stroke_s;
  double t = uniform(rng, o.air_s);
  while (t < o.seconds) {
    Contact c;
    c.start_s = t;
    c.kind = t < indent_end   ? Contact::kIndent
             : t < stroke_end ? Contact::kStroke
                              : Contact::kCircle;
    c.phi0 = 2.0 * kPi * unit(rng);
    c.swing_phase = 2.0 * kPi * unit(rng);
    c.mod_amp = 0.3 * unit(rng);
    c.mod_hz = 0.3 + 0.7 * unit(rng);
    c.mod_phase = 2.0 * kPi * unit(rng);
    if (c.kind == Contact::kIndent) {
      const double room = std::max(p.half_extent_m - 0.004, 0.0);
      c.cx = (2.0 * unit(rng) - 1.0) * room;
      c.cy = (2.0 * unit(rng) - 1.0) * room;
      c.force_n = logUniform(rng, o.indent_force_n);
      c.depth_max_m = o.indent_depth_max_m;
      c.hold_s = uniform(rng, o.indent_hold_s);
    } else if (c.kind == Contact::kStroke) {
      c.r = uniform(rng, o.stroke_half_m);
      const double room = std::max(p.half_extent_m - c.r - 0.003, 0.0);
      c.cx = (2.0 * unit(rng) - 1.0) * room;
      c.cy = (2.0 * unit(rng) - 1.0) * room;
      c.omega = uniform(rng, o.stroke_speed_m_s) / c.r;
      c.force_n = uniform(rng, o.stroke_force_n);
      c.swing_n = 0.1 * c.force_n;
      c.hold_s = uniform(rng, o.stroke_contact_s);
    } else {
      c.r = uniform(rng, o.radius_m);
      const double room = std::max(p.half_extent_m - c.r - 0.003, 0.0);
      c.cx = (2.0 * unit(rng) - 1.0) * room;
      c.cy = (2.0 * unit(rng) - 1.0) * room;
      c.omega = uniform(rng, o.speed_m_s) / c.r * (unit(rng) < 0.5 ? 1.0 : -1.0);
      c.force_n = o.force_n + (2.0 * unit(rng) - 1.0) * o.force_spread_n;
      c.swing_n = o.force_swing_n;
      c.hold_s = uniform(rng, o.contact_s);
      if (unit(rng) < o.reverse_probability) c.reverse_at_s = c.hold_s * (0.3 + 0.4 * unit(rng));
    }
    // Press in (and later lift off) from the air gap to the depth of the first force, at
    // the drawn peak speed (a smoothstep's peak slope is 1.5 times its mean).
    double x0 = 0.0, y0 = 0.0;
    c.point(c.startAngle(), x0, y0);
    const double f0 = c.force_n + c.swing_n * std::sin(c.startAngle() + c.swing_phase);
    const double depth0 = std::min(m.depthForForce(f0, x0, y0), c.depth_max_m);
    if (c.kind == Contact::kIndent) {
      c.press_s = 1.5 * (depth0 + o.air_gap_m) / logUniform(rng, o.indent_speed_m_s);
      c.release_s = 1.5 * (depth0 + o.air_gap_m) / logUniform(rng, o.indent_speed_m_s);
    } else {
      c.press_s = 1.5 * (depth0 + o.air_gap_m) / uniform(rng, o.press_speed_m_s);
      c.release_s = 1.5 * (depth0 + o.air_gap_m) / uniform(rng, o.press_speed_m_s);
    }
    c.air_s = uniform(rng, c.kind == Contact::kIndent ? o.indent_air_s : o.air_s);
    out.push_back(c);
    t = c.end();
  }
  return out;
}

/// The signed angular speed at `u` seconds into a contact's circling.
double angularSpeed(const Contact& c, double u) {
  constexpr double kRamp = 0.4, kTurn = 0.3;  // s: start, stop, turn back
  double w = c.omega * smoothRamp(u, kRamp) * smoothRamp(c.hold_s - u, kRamp) *
             (1.0 + c.mod_amp * std::sin(2.0 * kPi * c.mod_hz * u + c.mod_phase));
  if (c.reverse_at_s >= 0.0) w *= 1.0 - 2.0 * smoothRamp(u - c.reverse_at_s + 0.5 * kTurn, kTurn);
  return w;
}

/// One finger's path in the web frame: surface point (x, y) and depth, at every tick.
struct Path {
  std::vector<double> x, y, depth;
};

Path fingerPath(const SyntheticMassageOptions& o, const TissueModel& m,
                const std::vector<Contact>& contacts, std::size_t ticks) {
  Path path;
  path.x.resize(ticks);
  path.y.resize(ticks);
  path.depth.resize(ticks);
  const double dt = 1.0 / o.rate_hz;
  std::size_t k = 0;  // current contact
  double phi = contacts.empty() ? 0.0 : contacts[0].startAngle();
  double x = 0.0, y = 0.0, depth = -o.air_gap_m;
  if (!contacts.empty()) contacts[0].point(phi, x, y);
  double hold_end_depth = 0.0, last_u = 0.0;
  for (std::size_t i = 0; i < ticks; ++i) {
    const double t = static_cast<double>(i) * dt;
    while (k + 1 < contacts.size() && t >= contacts[k].end()) {
      ++k;
      phi = contacts[k].startAngle();
      last_u = 0.0;
    }
    if (k >= contacts.size() || t < contacts[k].start_s) {
      // Before the first contact: in the air above its start.
      path.x[i] = x;
      path.y[i] = y;
      path.depth[i] = -o.air_gap_m;
      continue;
    }
    const Contact& c = contacts[k];
    const double u = t - c.start_s;
    const double hold0 = c.press_s, release0 = c.press_s + c.hold_s,
                 air0 = c.press_s + c.hold_s + c.release_s;
    auto target = [&](double phase, double px, double py) {
      const double f = c.force_n + c.swing_n * std::sin(phase + c.swing_phase);
      return std::min(m.depthForForce(f, px, py), c.depth_max_m);
    };
    if (u < hold0) {
      phi = c.startAngle();
      c.point(phi, x, y);
      depth = -o.air_gap_m + (target(phi, x, y) + o.air_gap_m) * smoothRamp(u, c.press_s);
    } else if (u < release0) {
      // Integrate the angle at the midpoint of each tick.
      const double uh = u - hold0;
      if (last_u < hold0) last_u = hold0;
      const double step = u - last_u;
      phi += angularSpeed(c, uh - 0.5 * step) * step;
      last_u = u;
      c.point(phi, x, y);
      depth = target(phi, x, y);
      hold_end_depth = depth;
    } else if (u < air0) {
      depth =
          hold_end_depth + (-o.air_gap_m - hold_end_depth) * smoothRamp(u - release0, c.release_s);
    } else {
      // In the air: glide to where the next contact starts.
      depth = -o.air_gap_m;
      if (k + 1 < contacts.size()) {
        const Contact& n = contacts[k + 1];
        double nx = 0.0, ny = 0.0, lx = 0.0, ly = 0.0;
        n.point(n.startAngle(), nx, ny);
        c.point(phi, lx, ly);
        const double w = smoothRamp(u - air0, c.air_s);
        x = lx + w * (nx - lx);
        y = ly + w * (ny - ly);
      }
    }
    path.x[i] = x;
    path.y[i] = y;
    path.depth[i] = depth;
  }
  return path;
}

/// The thimble's orientation in the web frame: its pad normal into the skin (the thumb
/// down, the index up), turned about the normal by `yaw` and tilted by `tilt` about an axis
/// at `axis` in the pad plane.
Quat thimbleInWeb(int finger, double yaw, double tilt, double axis) {
  const Quat base =
      finger == kThumb ? Quat(Eigen::AngleAxisd(kPi, Vec3::UnitX())) : Quat::Identity();
  const Quat tilt_q(Eigen::AngleAxisd(tilt, Vec3(std::cos(axis), std::sin(axis), 0.0)));
  return Quat(Eigen::AngleAxisd(yaw, Vec3::UnitZ())) * base * tilt_q;
}

}  // namespace

SyntheticMassage synthesizeMassage(const SyntheticMassageOptions& o) {
  SyntheticMassage out;
  out.truth = o.truth;
  const TissueModel model(o.truth);
  const TissueParams& p = o.truth;
  const auto ticks = static_cast<std::size_t>(o.seconds * o.rate_hz);
  const double dt = 1.0 / o.rate_hz;
  std::mt19937_64 noise_rng(o.seed * 0x9E3779B97F4A7C15ull + 7);
  std::normal_distribution<double> gauss(0.0, 1.0);
  std::uniform_real_distribution<double> unit(0.0, 1.0);

  PerFinger<Path> paths;
  PerFinger<std::array<double, 4>> pose_phase{};
  for (int k = 0; k < 2; ++k) {
    std::seed_seq seq{o.seed, static_cast<uint64_t>(k)};
    std::mt19937_64 rng(seq);
    const auto contacts = planContacts(o, model, rng);
    paths[k] = fingerPath(o, model, contacts, ticks);
    for (double& ph : pose_phase[k]) ph = 2.0 * kPi * unit(rng);
  }
  const double surface = 0.5 * p.thickness_m + p.pad_radius_m;
  auto webPoint = [&](int k, std::size_t i) {
    const Path& path = paths[k];
    const double z = k == kThumb ? surface - path.depth[i] : -surface + path.depth[i];
    return Vec3(path.x[i], path.y[i], z);
  };

  constexpr double kPadSin = 0.5, kPadCos = 0.8660254037844386;  // FSRs 1 and 4 share the normal
  PerFinger<TissueAnchor> anchor{};
  out.samples.resize(ticks);
  for (std::size_t i = 0; i < ticks; ++i) {
    const double t = static_cast<double>(i) * dt;
    Sample& s = out.samples[i];
    s.seq = i;
    s.source_time_ns = kNsPerS + static_cast<int64_t>(std::llround(t * 1e9));
    s.flags = sample_flags::kCapture;
    for (int k = 0; k < 2; ++k) {
      const Vec3 w = webPoint(k, i);
      const Vec3 w_prev = webPoint(k, i > 0 ? i - 1 : i);
      const Vec3 w_next = webPoint(k, i + 1 < ticks ? i + 1 : i);
      const double span = static_cast<double>((i + 1 < ticks ? i + 1 : i) - (i > 0 ? i - 1 : i));
      const Vec3 v_web = span > 0.0 ? Vec3((w_next - w_prev) / (span * dt)) : Vec3::Zero();
      const Vec3 pos = model.fromWeb(w);
      const Vec3 vel = p.orientation * v_web;
      const TissueContact c = tissueContact(model, k, pos, vel, anchor[k]);
      const auto& ph = pose_phase[k];
      const double yaw = degToRad(o.yaw_deg) * std::sin(2.0 * kPi * 0.07 * t + ph[0]);
      const double tilt =
          degToRad(o.tilt_deg) * (0.5 + 0.5 * std::sin(2.0 * kPi * 0.13 * t + ph[1]));
      const double axis = 2.0 * kPi * 0.05 * t + ph[2];
      const Quat q = (p.orientation * thimbleInWeb(k, yaw, tilt, axis)).normalized();
      // What the pad presses on the skin, in the thimble's frame, as its FSRs see it.
      const Vec3 local = q.conjugate() * (-c.force());
      const double normal = std::max(std::max(local.z(), 0.0) + o.noise_n * gauss(noise_rng), 0.0);
      const double tangential = local.y() + o.noise_n * gauss(noise_rng);
      SampleFinger& f = s.fingers[k];
      for (int j = 0; j < 3; ++j) f.position_m[j] = pos[j];
      f.orientation_q[0] = q.w();
      f.orientation_q[1] = q.x();
      f.orientation_q[2] = q.y();
      f.orientation_q[3] = q.z();
      f.fsr_n[0] = static_cast<float>(normal * kPadSin);
      f.fsr_n[1] = static_cast<float>(std::max(tangential, 0.0));
      f.fsr_n[2] = static_cast<float>(std::max(-tangential, 0.0));
      f.fsr_n[3] = static_cast<float>(normal * kPadCos);
      f.tangential_n = static_cast<float>(tangential);  // eq. 1
      f.normal_n = static_cast<float>(normal);          // eq. 2
    }
  }
  return out;
}

TissueParams randomTissue(uint64_t seed, const RandomTissueRanges& r) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  TissueParams p;
  p.origin_m = Vec3(0.1 * unit(rng) - 0.05, 0.1 * unit(rng) - 0.05, 0.1 * unit(rng) - 0.05);
  const Vec3 axis = Vec3(unit(rng) - 0.5, unit(rng) - 0.5, unit(rng) - 0.5).normalized();
  p.orientation = Quat(Eigen::AngleAxisd(degToRad(30.0) * unit(rng), axis));
  p.thickness_m = uniform(rng, r.thickness_m);
  p.exponent = uniform(rng, r.exponent);
  p.stiffness_n_per_m_pow = 10.0 / std::pow(uniform(rng, r.depth_at_10n_m), p.exponent);
  p.damping_s_per_m = uniform(rng, r.damping_s_per_m);
  p.mu_static = uniform(rng, r.mu_static);
  p.lateral_stiffness_n_per_m = p.mu_static * 10.0 / uniform(rng, r.stretch_at_10n_m);
  p.mu_kinetic = p.mu_static * uniform(rng, r.mu_ratio);
  p.viscous_n_s_per_m = logUniform(rng, r.viscous_n_s_per_m);
  if (unit(rng) < r.patch_probability) {
    p.patch_radius_m = 0.004 + 0.004 * unit(rng);
    p.patch_x_m = 0.012 * unit(rng) - 0.006;
    p.patch_y_m = 0.012 * unit(rng) - 0.006;
    p.patch_stiffness_factor = uniform(rng, r.patch_stiffness_factor);
    p.patch_friction_factor = uniform(rng, r.patch_friction_factor);
  }
  return p;
}

uint64_t storeMassageCapture(store::SessionStore& store, const SyntheticMassage& capture,
                             const std::string& case_name, const std::string& user) {
  store::SessionInfo info;
  info.user = user;
  info.case_name = case_name;
  info.mode = "capture";
  info.state = "active";
  info.started_ns = capture.samples.empty() ? 0 : capture.samples.front().source_time_ns;
  const uint64_t id = store.createSession(info);
  constexpr std::size_t kBatch = 5000;
  for (std::size_t i = 0; i < capture.samples.size(); i += kBatch) {
    std::vector<Sample> batch(capture.samples.begin() + static_cast<std::ptrdiff_t>(i),
                              capture.samples.begin() + static_cast<std::ptrdiff_t>(std::min(
                                                            i + kBatch, capture.samples.size())));
    for (auto& s : batch) s.session_id = id;
    const std::vector<uint8_t> valid(batch.size(), 1);
    store.appendSamples(id, batch, valid);
  }
  const int64_t end = capture.samples.empty() ? 0 : capture.samples.back().source_time_ns;
  store.closeSession(id, end, capture.samples.size(), "closed");
  return id;
}

}  // namespace telehand::server::estimate
