#include "telehand/server/estimate/tissue_fit.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numeric>
#include <sstream>

namespace telehand::server::estimate {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

Quat sampleOrientation(const SampleFinger& f) {
  return Quat(f.orientation_q[0], f.orientation_q[1], f.orientation_q[2], f.orientation_q[3])
      .normalized();
}

/// +1 for the thumb (the skin pushes it toward +z of the web), −1 for the index.
double sideOf(int finger) { return finger == kThumb ? 1.0 : -1.0; }

double surfaceOf(const TissueParams& p) { return 0.5 * p.thickness_m + p.pad_radius_m; }

/// Depth of a thimble centre given in the web frame, against the nominal surfaces.
double nominalDepth(const TissueParams& p, int finger, const Vec3& w) {
  return finger == kThumb ? surfaceOf(p) - w.z() : w.z() + surfaceOf(p);
}

/// E[max(m + e, 0)] for e ~ N(0, σ²), and its slope in m.
double cutMean(double m, double sigma) {
  if (!(sigma > 0.0)) return std::max(m, 0.0);
  const double z = m / sigma;
  const double cdf = 0.5 * std::erfc(-z / std::sqrt(2.0));
  const double pdf = std::exp(-0.5 * z * z) / std::sqrt(2.0 * kPi);
  return m * cdf + sigma * pdf;
}
double cutSlope(double m, double sigma) {
  if (!(sigma > 0.0)) return m > 0.0 ? 1.0 : 0.0;
  return 0.5 * std::erfc(-m / sigma / std::sqrt(2.0));
}

/// The per-point quantities that do not change during the fit.
struct Prepared {
  int finger = 0;
  std::vector<double> x, y, vx, vy, d_nom, rate, w;
  std::vector<double> gx, gy;    ///< patch weight gradient
  std::vector<double> a_n, a_t;  ///< the pressed normal force's share in eq. 2 and eq. 1
  std::vector<double> pad_x, pad_y, side_x, side_y;
  std::vector<double> meas_n, meas_t;
  std::vector<double> acc_n, acc_t;  ///< the acceleration along the pad normal and side axis
  std::vector<double> dt;            ///< to the next point, s (0 at the last or across a gap)
  std::vector<uint8_t> over;
};

Prepared prepare(const TissueParams& nominal, int finger, const std::vector<TissuePoint>& pts) {
  const TissueModel m(nominal);
  Prepared d;
  d.finger = finger;
  const std::size_t n = pts.size();
  for (auto* v : {&d.x,      &d.y,      &d.vx,     &d.vy,    &d.d_nom, &d.rate,  &d.w,
                  &d.gx,     &d.gy,     &d.a_n,    &d.a_t,   &d.pad_x, &d.pad_y, &d.side_x,
                  &d.side_y, &d.meas_n, &d.meas_t, &d.acc_n, &d.acc_t, &d.dt})
    v->resize(n);
  d.over.resize(n);
  const double side = sideOf(finger);
  for (std::size_t i = 0; i < n; ++i) {
    const TissuePoint& p = pts[i];
    d.x[i] = p.p_web.x();
    d.y[i] = p.p_web.y();
    d.vx[i] = p.v_web.x();
    d.vy[i] = p.v_web.y();
    d.d_nom[i] = nominalDepth(nominal, finger, p.p_web);
    d.rate[i] = finger == kThumb ? -p.v_web.z() : p.v_web.z();
    d.w[i] = m.patchWeight(d.x[i], d.y[i]);
    const Vec3 g = m.patchGradient(d.x[i], d.y[i]);
    d.gx[i] = g.x();
    d.gy[i] = g.y();
    // The pad presses into the skin along −side·z.
    d.a_n[i] = -side * p.pad_web.z();
    d.a_t[i] = -side * p.side_web.z();
    d.pad_x[i] = p.pad_web.x();
    d.pad_y[i] = p.pad_web.y();
    d.side_x[i] = p.side_web.x();
    d.side_y[i] = p.side_web.y();
    d.meas_n[i] = p.normal_n;
    d.meas_t[i] = p.tangential_n;
    d.acc_n[i] = p.a_web.dot(p.pad_web);
    d.acc_t[i] = p.a_web.dot(p.side_web);
    if (i + 1 < n && pts[i + 1].seq == p.seq + 1)
      d.dt[i] = static_cast<double>(pts[i + 1].t_ns - p.t_ns) * 1e-9;
    d.over[i] =
        std::abs(d.x[i]) <= nominal.half_extent_m && std::abs(d.y[i]) <= nominal.half_extent_m;
  }
  return d;
}

/// The normal block's parameters.
struct NormalParams {
  double ln_k = std::log(2.2e4), n = 1.5, lambda = 0.0;
  PerFinger<double> offset{0.0, 0.0};
  double ln_fk = 0.0;  ///< ln patch stiffness factor
  double mass = 0.0;   ///< kg between the sensors and the skin
};

/// The friction block's parameters.
/// The sliding skin's force as the fit holds it: mu_mid = (mu_static + mu_kinetic) / 2, the
/// level a slipping skin's sawtooth (kinetic up to static, then back) averages to.
struct FrictionParams {
  double ln_kt = std::log(800.0), ln_mus = std::log(0.5), ln_mum = std::log(0.45), b = 1.0;
  double ln_fg = 0.0;  ///< ln patch friction factor
};

/// Per point, what the normal block gives the friction block: in contact, the normal force
/// magnitude, the depth and the rim force (web x, y).
struct NormalState {
  std::vector<uint8_t> contact;
  std::vector<double> force, depth, rim_x, rim_y;
  std::vector<double> inertia_t;  ///< the mass's share in eq. 1 (every point)
};

NormalState normalState(const Prepared& d, const NormalParams& q) {
  NormalState s;
  const std::size_t n = d.x.size();
  s.contact.assign(n, 0);
  s.force.assign(n, 0.0);
  s.depth.assign(n, 0.0);
  s.rim_x.assign(n, 0.0);
  s.rim_y.assign(n, 0.0);
  s.inertia_t.resize(n);
  const double k = std::exp(q.ln_k), fk = std::exp(q.ln_fk);
  for (std::size_t i = 0; i < n; ++i) {
    s.inertia_t[i] = q.mass * d.acc_t[i];
    const double depth = d.d_nom[i] + q.offset[d.finger];
    if (!(depth > 0.0) || !d.over[i]) continue;
    s.contact[i] = 1;
    s.depth[i] = depth;
    const double kk = k * (1.0 + d.w[i] * (fk - 1.0));
    const double el = kk * std::pow(depth, q.n);
    s.force[i] = std::max(el * (1.0 + q.lambda * d.rate[i]), 0.0);
    const double e = -(fk - 1.0) * k * std::pow(depth, q.n + 1.0) / (q.n + 1.0);
    s.rim_x[i] = e * d.gx[i];
    s.rim_y[i] = e * d.gy[i];
  }
  return s;
}

/// The friction force on the finger (web x, y) per point: the skin's anchor stepped as
/// tissueContact does (`exact`), or averaged over the sawtooth of a slipping skin. Where the
/// skin slips, its stretch drops to the kinetic limit and it sticks again until the static
/// one: a sawtooth whose teeth (a stretch of (mu_s − mu_k)·F / kt each, 1.9 mm on the healthy
/// web at 10 N) a fit cannot follow: a simulation with them drifts out of step with the data
/// within a few teeth, and the residual sum then jumps by hundreds of σ² for a change of a
/// per cent in a parameter. The averaged model holds a slipping skin's stretch at the teeth's
/// mean, mu_mid·F / kt with mu_mid = (mu_s + mu_k) / 2, and yields at the static limit only
/// the first time after the finger touches down (where the skin has stuck since the touch):
/// an elastic–plastic play whose residual is smooth in the parameters.
struct FrictionState {
  std::vector<double> tx, ty;
  std::vector<uint8_t> slip;
  std::vector<double> ux, uy;  ///< where slipping: the stretch's direction (unit)
};

void simulateFriction(const Prepared& d, const NormalState& ns, const FrictionParams& q,
                      FrictionState& out, bool exact = false) {
  const std::size_t n = d.x.size();
  // Every element is written below (zeroing them first as well cost a tenth of the fit).
  out.tx.resize(n);
  out.ty.resize(n);
  out.slip.resize(n);
  out.ux.resize(n);
  out.uy.resize(n);
  const double kt = std::exp(q.ln_kt), mus = std::exp(q.ln_mus), mum = std::exp(q.ln_mum);
  const double muk = std::max(2.0 * mum - mus, 0.0);
  const double fg = std::exp(q.ln_fg);
  bool attached = false, fresh = false;
  double ax = 0.0, ay = 0.0;
  for (std::size_t i = 0; i < n; ++i) {
    out.slip[i] = 0;
    out.ux[i] = out.uy[i] = 0.0;
    if (!ns.contact[i]) {
      out.tx[i] = out.ty[i] = 0.0;
      attached = false;
      continue;
    }
    if (!attached) {
      ax = d.x[i];
      ay = d.y[i];
      attached = true;
      fresh = true;
    }
    const double g = 1.0 + d.w[i] * (fg - 1.0);
    double sx = d.x[i] - ax, sy = d.y[i] - ay;
    // sqrt, not hypot: millimetres cannot overflow, and hypot took a quarter of the fit.
    const double stretch = std::sqrt(sx * sx + sy * sy);
    const double yield = (exact || fresh ? mus : mum) * g * ns.force[i];
    if (kt * stretch > yield) {
      fresh = false;
      out.ux[i] = sx / stretch;
      out.uy[i] = sy / stretch;
      const double keep = (exact ? muk : mum) * g * ns.force[i] / (kt * stretch);
      sx *= keep;
      sy *= keep;
      ax = d.x[i] - sx;
      ay = d.y[i] - sy;
      out.slip[i] = 1;
    }
    out.tx[i] = -kt * sx - q.b * d.vx[i] + ns.rim_x[i];
    out.ty[i] = -kt * sy - q.b * d.vy[i] + ns.rim_y[i];
  }
}

/// Levenberg–Marquardt on a residual function r(θ) with Jacobian J(θ) (rows: points).
/// `eval(theta, r, J)` fills r (and J when not null); `clamp(theta)` applies the bounds.
/// Returns the final θ; `cov` gets σ²(JᵀJ)⁻¹, `rss` the residual sum of squares.
template <class Eval, class Clamp>
Eigen::VectorXd levenbergMarquardt(Eigen::VectorXd theta, Eval&& eval, Clamp&& clamp,
                                   int max_iterations, Eigen::MatrixXd* cov, double* rss,
                                   int* iterations) {
  const auto p = theta.size();
  Eigen::VectorXd r;
  Eigen::MatrixXd J;
  eval(theta, r, &J);
  double cost = r.squaredNorm();
  double mu = 1e-3;
  int it = 0;
  bool settled = false;
  for (; it < max_iterations && !settled; ++it) {
    const Eigen::MatrixXd A = J.transpose() * J;
    const Eigen::VectorXd g = J.transpose() * r;
    bool improved = false;
    for (int tries = 0; tries < 12; ++tries) {
      Eigen::MatrixXd Ad = A;
      for (Eigen::Index j = 0; j < p; ++j) Ad(j, j) += mu * std::max(A(j, j), 1e-12);
      Eigen::VectorXd step = -Ad.ldlt().solve(g);
      if (!step.allFinite()) {
        mu *= 10.0;
        continue;
      }
      Eigen::VectorXd next = theta + step;
      clamp(next);
      Eigen::VectorXd rn;
      eval(next, rn, nullptr);
      const double c = rn.squaredNorm();
      if (std::isfinite(c) && c < cost) {
        const double gain = cost - c;
        theta = next;
        eval(theta, r, &J);
        cost = r.squaredNorm();
        mu = std::max(mu / 3.0, 1e-9);
        improved = true;
        settled = gain < 1e-10 * cost;
        break;
      }
      mu *= 8.0;
    }
    if (!improved) break;
  }
  if (iterations) *iterations += it;
  if (rss) *rss = cost;
  if (cov) {
    const auto n = r.size();
    const double s2 = n > p ? cost / static_cast<double>(n - p) : kNaN;
    const Eigen::MatrixXd A = J.transpose() * J;
    Eigen::FullPivLU<Eigen::MatrixXd> lu(A);
    *cov = lu.isInvertible() ? Eigen::MatrixXd(s2 * lu.inverse())
                             : Eigen::MatrixXd::Constant(p, p, kNaN);
  }
  return theta;
}

/// Which parameters a block estimates (the others held).
/// The stiffness is estimated as the force at a reference depth inside the captured range,
/// ln f_ref = ln k + n·ln δ_ref (δ_ref: the contact depths' geometric mean), which the data
/// pin down apart from n; k (the force at a depth of 1 m, what the model takes) moves with n
/// by ln δ_ref·Δn and is computed from the two.
struct NormalLayout {
  bool offsets = true, patch = false, mass = false;
  double ln_ref = std::log(0.005);  ///< ln δ_ref
  Eigen::Index size() const { return 3 + (offsets ? 2 : 0) + (patch ? 1 : 0) + (mass ? 1 : 0); }
};

Eigen::VectorXd packNormal(const NormalParams& q, const NormalLayout& l) {
  Eigen::VectorXd t(l.size());
  Eigen::Index j = 0;
  t(j++) = q.ln_k + q.n * l.ln_ref;
  t(j++) = q.n;
  t(j++) = q.lambda;
  if (l.offsets) {
    t(j++) = q.offset[0];
    t(j++) = q.offset[1];
  }
  if (l.patch) t(j++) = q.ln_fk;
  if (l.mass) t(j++) = q.mass;
  return t;
}

NormalParams unpackNormal(const Eigen::VectorXd& t, const NormalLayout& l, NormalParams q) {
  Eigen::Index j = 0;
  q.n = t(1);
  q.ln_k = t(j++) - q.n * l.ln_ref;
  j++;
  q.lambda = t(j++);
  if (l.offsets) {
    q.offset[0] = t(j++);
    q.offset[1] = t(j++);
  }
  if (l.patch) q.ln_fk = t(j++);
  if (l.mass) q.mass = t(j++);
  return q;
}

struct FrictionLayout {
  bool patch = false;
  Eigen::Index size() const { return 2 + (patch ? 1 : 0); }
};

/// The simplex's coordinates: ln kt, ln mu_mid, [ln patch factor]; mu_static − mu_kinetic
/// comes from the sawtooth the averaged model leaves (FrictionBlock::sawtooth): in the
/// residual it shows only where the skin first yields after a touch, too few events to say
/// it (on some captures the residual is flat from mu_static = mu_mid to the truth's).
Eigen::VectorXd frictionTheta(const FrictionParams& q, const FrictionLayout& l) {
  Eigen::VectorXd t(l.size());
  t(0) = q.ln_kt;
  t(1) = q.ln_mum;
  if (l.patch) t(2) = q.ln_fg;
  return t;
}

FrictionParams frictionFrom(const Eigen::VectorXd& t, const FrictionLayout& l, FrictionParams q) {
  const double ratio = q.ln_mus - q.ln_mum;
  q.ln_kt = std::clamp(t(0), 0.0, std::log(TissueParams::kMaxLateral));
  q.ln_mum = std::clamp(t(1), std::log(1e-3), std::log(TissueParams::kMaxMu));
  q.ln_mus = q.ln_mum + ratio;
  if (l.patch) q.ln_fg = std::clamp(t(2), std::log(0.1), std::log(TissueParams::kMaxPatchFactor));
  return q;
}

/// Nelder–Mead simplex minimisation of f from x0 (initial edges `step`).
template <class F>
Eigen::VectorXd nelderMead(F&& f, const Eigen::VectorXd& x0, const Eigen::VectorXd& step,
                           int max_evals, double ftol, int* evals) {
  const auto n = x0.size();
  std::vector<Eigen::VectorXd> x(static_cast<std::size_t>(n + 1), x0);
  std::vector<double> fx(static_cast<std::size_t>(n + 1));
  for (Eigen::Index i = 0; i < n; ++i) x[static_cast<std::size_t>(i + 1)](i) += step(i);
  for (std::size_t i = 0; i < x.size(); ++i) fx[i] = f(x[i]);
  int count = static_cast<int>(x.size());
  std::vector<std::size_t> order(x.size());
  while (count < max_evals) {
    std::iota(order.begin(), order.end(), std::size_t{0});
    std::sort(order.begin(), order.end(),
              [&](std::size_t a, std::size_t b) { return fx[a] < fx[b]; });
    const std::size_t best = order.front(), worst = order.back(), second = order[order.size() - 2];
    if (std::abs(fx[worst] - fx[best]) <= ftol * (std::abs(fx[best]) + 1e-300)) break;
    Eigen::VectorXd centre = Eigen::VectorXd::Zero(n);
    for (std::size_t i = 0; i < x.size(); ++i)
      if (i != worst) centre += x[i];
    centre /= static_cast<double>(n);
    const Eigen::VectorXd xr = centre + (centre - x[worst]);
    const double fr = f(xr);
    ++count;
    if (fr < fx[best]) {
      const Eigen::VectorXd xe = centre + 2.0 * (centre - x[worst]);
      const double fe = f(xe);
      ++count;
      if (fe < fr) {
        x[worst] = xe;
        fx[worst] = fe;
      } else {
        x[worst] = xr;
        fx[worst] = fr;
      }
    } else if (fr < fx[second]) {
      x[worst] = xr;
      fx[worst] = fr;
    } else {
      const bool outside = fr < fx[worst];
      const Eigen::VectorXd xc = outside ? Eigen::VectorXd(centre + 0.5 * (xr - centre))
                                         : Eigen::VectorXd(centre + 0.5 * (x[worst] - centre));
      const double fc = f(xc);
      ++count;
      if (fc < (outside ? fr : fx[worst])) {
        x[worst] = xc;
        fx[worst] = fc;
      } else {
        for (std::size_t i = 0; i < x.size(); ++i) {
          if (i == best) continue;
          x[i] = x[best] + 0.5 * (x[i] - x[best]);
          fx[i] = f(x[i]);
          ++count;
        }
      }
    }
  }
  if (evals) *evals += count;
  return x[static_cast<std::size_t>(std::min_element(fx.begin(), fx.end()) - fx.begin())];
}

/// The normal block: the rows are the points near contact of both fingers.
class NormalBlock {
 public:
  NormalBlock(const PerFinger<Prepared>& d, const TissueFitOptions& o) : d_(d), o_(o) {
    for (int k = 0; k < 2; ++k) {
      for (std::size_t i = 0; i < d[k].x.size(); ++i) {
        if (d[k].over[i] && d[k].d_nom[i] > -o.max_surface_offset_m - 0.001)
          rows_.push_back({k, i});
      }
    }
    tau_[0].assign(d[0].x.size(), 0.0);
    tau_[1].assign(d[1].x.size(), 0.0);
  }
  std::size_t rows() const { return rows_.size(); }
  /// The friction's share in eq. 2 (from the friction block).
  void setFriction(int finger, const FrictionState& f) {
    const Prepared& d = d_[finger];
    for (std::size_t i = 0; i < d.x.size(); ++i)
      tau_[finger][i] = -(f.tx[i] * d.pad_x[i] + f.ty[i] * d.pad_y[i]);
  }

  /// Residuals (measured − predicted eq. 2) and their Jacobian.
  void eval(const NormalParams& q, const NormalLayout& l, Eigen::VectorXd& r,
            Eigen::MatrixXd* J) const {
    const auto n = static_cast<Eigen::Index>(rows_.size());
    r.resize(n);
    if (J) J->setZero(n, l.size());
    const double k = std::exp(q.ln_k), fk = std::exp(q.ln_fk);
    const double sigma = o_.normal_cut_at_zero ? o_.noise_n : 0.0;
    for (Eigen::Index row = 0; row < n; ++row) {
      const auto [f, i] = rows_[static_cast<std::size_t>(row)];
      const Prepared& d = d_[f];
      const double depth = d.d_nom[i] + q.offset[f];
      double force = 0.0, el = 0.0, kk = 0.0;
      if (depth > 0.0) {
        kk = k * (1.0 + d.w[i] * (fk - 1.0));
        el = kk * std::pow(depth, q.n);
        force = std::max(el * (1.0 + q.lambda * d.rate[i]), 0.0);
      }
      const double mu = force * d.a_n[i] + tau_[f][i] + q.mass * d.acc_n[i];
      const double raw = std::max(mu, 0.0);
      r(row) = d.meas_n[i] - (o_.normal_cut_at_zero ? cutMean(raw, sigma) : raw);
      if (!J || !(mu > 0.0)) continue;
      const double cs = o_.normal_cut_at_zero ? cutSlope(raw, sigma) : 1.0;
      const double c = cs * d.a_n[i];
      if (l.mass) (*J)(row, l.size() - 1) = -cs * d.acc_n[i];
      if (!(force > 0.0)) continue;
      Eigen::Index j = 0;
      (*J)(row, j++) = -c * force;                                 // ln f_ref
      (*J)(row, j++) = -c * force * (std::log(depth) - l.ln_ref);  // n
      (*J)(row, j++) = -c * el * d.rate[i];                        // λ
      if (l.offsets) {
        const double ds = force * q.n / depth;
        (*J)(row, j + f) = -c * ds;
        j += 2;
      }
      if (l.patch) {
        (*J)(row, j++) = -c * force * d.w[i] * fk / (1.0 + d.w[i] * (fk - 1.0));
      }
    }
  }

 private:
  const PerFinger<Prepared>& d_;
  const TissueFitOptions& o_;
  std::vector<std::pair<int, std::size_t>> rows_;
  PerFinger<std::vector<double>> tau_;
};

/// The friction block: the rows are the points in contact of both fingers (eq. 1). A group
/// of contacts can be left out (their rows count zero) for the jackknife.
class FrictionBlock {
 public:
  FrictionBlock(const PerFinger<Prepared>& d, const PerFinger<NormalState>& ns, int groups)
      : d_(d), ns_(ns) {
    // Contacts (runs of points in contact, cut every 2 s: a capture may stay on the skin
    // from its strokes through its circles) go to the groups in turn.
    int run = -1;
    for (int k = 0; k < 2; ++k) {
      bool in = false;
      std::size_t length = 0;
      for (std::size_t i = 0; i < d[k].x.size(); ++i) {
        if (!ns[k].contact[i]) {
          in = false;
          continue;
        }
        if (!in || ++length >= 2000) {
          ++run;
          length = 0;
        }
        in = true;
        group_.push_back(groups > 0 ? run % groups : 0);
      }
    }
    column_.resize(static_cast<Eigen::Index>(group_.size()));
    Eigen::Index row = 0;
    for (int k = 0; k < 2; ++k) {
      const Prepared& p = d[k];
      for (std::size_t i = 0; i < p.x.size(); ++i) {
        if (ns[k].contact[i]) column_(row++) = p.vx[i] * p.side_x[i] + p.vy[i] * p.side_y[i];
      }
    }
  }
  Eigen::Index rows() const { return static_cast<Eigen::Index>(group_.size()); }
  /// Leave group `g` out (−1: none).
  void leaveOut(int g) {
    left_out_ = g;
    masked_ = column_;
    for (Eigen::Index row = 0; row < rows(); ++row)
      if (group_[static_cast<std::size_t>(row)] == g) masked_(row) = 0.0;
  }
  /// Residuals (measured − predicted eq. 1), the states through `keep`.
  void eval(const FrictionParams& q, Eigen::VectorXd& r, bool exact = false,
            PerFinger<FrictionState>* keep = nullptr) const {
    r.resize(rows());
    Eigen::Index row = 0;
    PerFinger<FrictionState>& st = keep ? *keep : scratch_;
    for (int k = 0; k < 2; ++k) {
      const Prepared& d = d_[k];
      simulateFriction(d, ns_[k], q, st[k], exact);
      for (std::size_t i = 0; i < d.x.size(); ++i) {
        if (!ns_[k].contact[i]) continue;
        const double pred = ns_[k].force[i] * d.a_t[i] + ns_[k].inertia_t[i] -
                            (st[k].tx[i] * d.side_x[i] + st[k].ty[i] * d.side_y[i]);
        r(row) = group_[static_cast<std::size_t>(row)] == left_out_ ? 0.0 : d.meas_t[i] - pred;
        ++row;
      }
    }
  }
  /// The sawtooth's height, mu_static − mu_kinetic, from what the averaged model leaves where
  /// it slides. There the skin's force runs up from the kinetic limit to the static one and
  /// drops back, tooth after tooth, out of step with the model: the residual is the noise plus
  /// that departure from the teeth's mean, a sawtooth of height Δ = Δmu·g·F along the stretch
  /// that rises by u = kt·(v·ŝ)·dt per sample. Its covariance one sample apart is, seen along
  /// the side axis, (ŝ·side)²·(Δ²/12 − Δ·u/2) (a sawtooth's autocovariance at a lag of u/Δ of
  /// a tooth); the noise's own (white: none) is measured in the air and taken off. Unlike the
  /// variance, this needs no figure for the noise, and it reads every sliding sample, not only
  /// the first yield after each touch.
  /// Returns Δmu (its standard error through `se`), over the rows not left out.
  double sawtooth(const FrictionParams& q, double noise_lag1, double* se = nullptr) const {
    const double kt = std::exp(q.ln_kt), fg = std::exp(q.ln_fg), mum = std::exp(q.ln_mum);
    double saa = 0.0, sab = 0.0, sbb = 0.0, spa = 0.0, spb = 0.0, spp = 0.0;
    std::size_t n = 0, row = 0;
    for (int k = 0; k < 2; ++k) {
      const Prepared& p = d_[k];
      FrictionState& st = scratch_[k];
      simulateFriction(p, ns_[k], q, st);
      for (std::size_t i = 0; i < p.x.size(); ++i) {
        if (!ns_[k].contact[i]) continue;
        const std::size_t this_row = row++;
        if (i + 1 >= p.x.size() || !st.slip[i] || !st.slip[i + 1] || !(p.dt[i] > 0.0) ||
            group_[this_row] == left_out_)
          continue;
        auto residual = [&](std::size_t j) {
          return p.meas_t[j] - (ns_[k].force[j] * p.a_t[j] + ns_[k].inertia_t[j] -
                                (st.tx[j] * p.side_x[j] + st.ty[j] * p.side_y[j]));
        };
        const double proj = st.ux[i] * p.side_x[i] + st.uy[i] * p.side_y[i];
        const double gf = (1.0 + p.w[i] * (fg - 1.0)) * ns_[k].force[i];
        const double u = kt * std::abs(p.vx[i] * st.ux[i] + p.vy[i] * st.uy[i]) * p.dt[i];
        const double a = proj * proj * gf * gf / 12.0, b = proj * proj * gf * u / 2.0;
        const double y = residual(i) * residual(i + 1) - noise_lag1;
        saa += a * a;
        sab += a * b;
        sbb += b * b;
        spa += y * a;
        spb += y * b;
        spp += y * y;
        ++n;
      }
    }
    if (se) *se = kNaN;
    if (n < 100 || !(saa > 0.0)) return 0.0;
    // Σ(y − Δ²a + Δb)² over Δ in [0, 2·mu_mid]: the best of a fine grid.
    auto cost = [&](double x) {
      return spp - 2.0 * x * x * spa + 2.0 * x * spb + x * x * x * x * saa - 2.0 * x * x * x * sab +
             x * x * sbb;
    };
    double best = 0.0;
    for (double x = 0.0; x <= 2.0 * mum; x += 5e-4)
      if (cost(x) < cost(best)) best = x;
    // Its error from the sum's curvature, σ² the mean square left.
    const double s2 = cost(best) / static_cast<double>(n);
    const double curv = 4.0 * best * best * saa - 4.0 * best * sab + sbb;
    if (se && curv > 0.0) *se = std::sqrt(s2 / curv);
    return best;
  }

  /// The residual sum of squares with b at its best for the rest of `q` (b ≥ 0; set in q):
  /// b does not move the anchor, so the residual is linear in it (its slope: the velocity
  /// along each thimble's side axis).
  double costProjected(FrictionParams& q, bool exact = false) const {
    q.b = 0.0;
    eval(q, r_, exact);
    const Eigen::VectorXd& c = left_out_ < 0 ? column_ : masked_;
    const double rc = r_.dot(c), cc = c.squaredNorm();
    q.b = cc > 0.0 ? std::clamp(rc / cc, 0.0, TissueParams::kMaxViscous) : 0.0;
    return r_.squaredNorm() - 2.0 * q.b * rc + q.b * q.b * cc;
  }

  /// b from the exact sawtooth at `q`, jointly with a small change of the friction level
  /// (ln mu_mid and ln mu_static together, the averaged model's slope in it as the column):
  /// b·v and mu·F both oppose the motion, so b projected alone takes up whatever per cent
  /// the friction level is off (each per cent of it is 0.3-0.4 N·s/m of b on the healthy
  /// web); strokes at different speeds and presses tell the two apart. Sets q.b.
  static constexpr double kWeightShare = 0.5;  ///< of the static friction force, per N
  void projectViscousWithLevel(FrictionParams& q) const {
    FrictionParams z = q;
    z.b = 0.0;
    eval(z, r_, true);
    const Eigen::VectorXd r0 = r_;
    constexpr double kH = 0.01;
    // Columns: b's (the velocity along the side axis), then the averaged model's slope in
    // the friction level, the lateral stiffness and the teeth's height.
    const Eigen::VectorXd& c = left_out_ < 0 ? column_ : masked_;
    Eigen::MatrixXd X(rows(), 4);
    X.col(0) = c;
    for (int j = 1; j < 4; ++j) {
      FrictionParams lo = z, hi = z;
      if (j == 1) {
        lo.ln_mum -= kH;
        lo.ln_mus -= kH;
        hi.ln_mum += kH;
        hi.ln_mus += kH;
      } else if (j == 2) {
        lo.ln_kt -= kH;
        hi.ln_kt += kH;
      } else {
        lo.ln_mus -= kH;
        hi.ln_mus += kH;
      }
      Eigen::VectorXd rl, rh;
      eval(lo, rl);
      eval(hi, rh);
      X.col(j) = (rl - rh) / (2.0 * kH);  // the residual falls by the prediction's rise
    }
    // Rows weighted by how well the stick–slip model can follow them: its teeth out of step
    // with the data leave an error that grows with the friction force, which a light press
    // keeps small; b shows best there.
    Eigen::VectorXd wt(rows());
    {
      const double mus = std::exp(q.ln_mus), fg = std::exp(q.ln_fg);
      Eigen::Index row = 0;
      for (int k = 0; k < 2; ++k) {
        const Prepared& p = d_[k];
        for (std::size_t i = 0; i < p.x.size(); ++i) {
          if (!ns_[k].contact[i]) continue;
          const double f = mus * (1.0 + p.w[i] * (fg - 1.0)) * ns_[k].force[i];
          wt(row++) = 1.0 / std::sqrt(1.0 + kWeightShare * kWeightShare * f * f);
        }
      }
    }
    X = wt.asDiagonal() * X;
    const Eigen::MatrixXd A = X.transpose() * X;
    const Eigen::VectorXd x = A.ldlt().solve(X.transpose() * (wt.asDiagonal() * r0));
    q.b = x.allFinite() ? std::clamp(x(0), 0.0, TissueParams::kMaxViscous) : 0.0;
  }

 private:
  const PerFinger<Prepared>& d_;
  const PerFinger<NormalState>& ns_;
  std::vector<int> group_;
  int left_out_ = -1;
  Eigen::VectorXd column_, masked_;
  mutable Eigen::VectorXd r_;
  mutable PerFinger<FrictionState> scratch_;
};

/// Nelder–Mead over the averaged friction model from `q` (b projected out), then the
/// sawtooth's height from what it leaves (FrictionBlock::sawtooth) sets mu_static and
/// mu_kinetic about mu_mid, then the simplex again from there.
FrictionParams refineFriction(const FrictionBlock& fb, const FrictionParams& q,
                              const FrictionLayout& l, double step, int max_evals,
                              double noise_lag1, int* evals) {
  FrictionParams out = q;
  for (int round = 0; round < 2; ++round) {
    auto cost = [&](const Eigen::VectorXd& t) {
      FrictionParams c = frictionFrom(t, l, out);
      return fb.costProjected(c);
    };
    const Eigen::VectorXd t0 = frictionTheta(out, l);
    const Eigen::VectorXd t = nelderMead(cost, t0, Eigen::VectorXd::Constant(t0.size(), step),
                                         max_evals / 2, 1e-9, evals);
    out = frictionFrom(t, l, out);
    const double dmu = fb.sawtooth(out, noise_lag1);
    out.ln_mus = std::log(std::exp(out.ln_mum) + 0.5 * dmu);
    step = std::min(step, 0.03);
  }
  fb.costProjected(out);
  return out;
}

/// The tangential channel's noise one sample apart, from the points clearly off the skin
/// (half a millimetre from the fitted surfaces): 0 unless it differs from 0 by more than
/// three of its standard errors (white noise, as the synthetic thimbles have).
double noiseLag1(const PerFinger<Prepared>& d, const PerFinger<double>& offset) {
  auto air = [&](int f, std::size_t i) {
    return d[f].over[i] && d[f].d_nom[i] + offset[f] < -0.0005;
  };
  double mean = 0.0, var = 0.0, c = 0.0;
  std::size_t n = 0, pairs = 0;
  for (int f = 0; f < 2; ++f) {
    for (std::size_t i = 0; i < d[f].x.size(); ++i) {
      if (!air(f, i)) continue;
      mean += d[f].meas_t[i];
      ++n;
    }
  }
  if (n < 1000) return 0.0;
  mean /= static_cast<double>(n);
  for (int f = 0; f < 2; ++f) {
    for (std::size_t i = 0; i < d[f].x.size(); ++i) {
      if (!air(f, i)) continue;
      const double e = d[f].meas_t[i] - mean;
      var += e * e;
      if (i + 1 < d[f].x.size() && d[f].dt[i] > 0.0 && air(f, i + 1)) {
        c += e * (d[f].meas_t[i + 1] - mean);
        ++pairs;
      }
    }
  }
  if (pairs < 1000) return 0.0;
  var /= static_cast<double>(n);
  c /= static_cast<double>(pairs);
  return std::abs(c) > 3.0 * var / std::sqrt(static_cast<double>(pairs)) ? c : 0.0;
}

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  const auto k = static_cast<std::size_t>(q * static_cast<double>(v.size() - 1));
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  return v[k];
}

/// Start of the normal block: per finger the offset (grid) and for both the exponent (grid)
/// with the stiffness in closed form, over the points near contact (every 4th).
NormalParams startNormal(const PerFinger<Prepared>& d, const TissueFitOptions& o, bool offsets) {
  NormalParams q;
  const double step = 0.00025;
  const int half = offsets ? static_cast<int>(std::round(o.max_surface_offset_m / step)) : 0;
  auto sse = [&](int f, double s, double n, double* k_out) {
    // k = Σ m·δ^n / Σ δ^2n over points in contact; points out of contact predict 0.
    const Prepared& p = d[f];
    double smd = 0.0, sdd = 0.0, smm = 0.0;
    for (std::size_t i = 0; i < p.x.size(); i += 4) {
      if (!p.over[i] || p.d_nom[i] < -o.max_surface_offset_m - 0.001) continue;
      const double m = p.meas_n[i];
      smm += m * m;
      const double depth = p.d_nom[i] + s;
      if (!(depth > 0.0)) continue;
      const double dn = std::pow(depth, n) * p.a_n[i];
      smd += m * dn;
      sdd += dn * dn;
    }
    const double k = sdd > 0.0 ? smd / sdd : 0.0;
    if (k_out) *k_out = k;
    return smm - 2.0 * k * smd + k * k * sdd;
  };
  const std::array<double, 5> exps = {1.2, 1.5, 1.8, 2.2, 2.7};
  for (int f = 0; f < 2; ++f) {
    double best = std::numeric_limits<double>::infinity();
    for (const double n : exps) {
      for (int j = -half; j <= half; ++j) {
        const double c = sse(f, j * step, n, nullptr);
        if (c < best) {
          best = c;
          q.offset[f] = j * step;
        }
      }
    }
  }
  double best = std::numeric_limits<double>::infinity();
  for (double n = 1.0; n <= 3.0 + 1e-9; n += 0.05) {
    double k0 = 0.0, k1 = 0.0;
    const double c = sse(0, q.offset[0], n, &k0) + sse(1, q.offset[1], n, &k1);
    if (c < best && k0 + k1 > 0.0) {
      best = c;
      q.n = n;
      q.ln_k = std::log(0.5 * (k0 + k1));
    }
  }
  return q;
}

}  // namespace

TissueFitter::TissueFitter(const TissueParams& nominal, const TissueFitOptions& options)
    : nominal_(nominal), options_(options) {}

bool TissueFitter::add(const Sample& s, bool valid) {
  if (!valid) {
    ++counts_.invalid;
    return false;
  }
  if ((s.flags >> sample_flags::kFsrFaultShift) & 0xFFu) {
    ++counts_.fsr_fault;
    return false;
  }
  if (!(s.flags & sample_flags::kCapture)) {
    ++counts_.not_capture;
    return false;
  }
  for (const auto& f : s.fingers) {
    if (!std::isfinite(f.tangential_n) || !std::isfinite(f.normal_n)) {
      ++counts_.invalid;
      return false;
    }
  }
  ++counts_.used;
  seq_.push_back(s.seq);
  samples_.push_back(s);
  return true;
}

PerFinger<std::vector<TissuePoint>> TissueFitter::points() const {
  // In sequence order, duplicates (a retried chunk) once.
  std::vector<std::size_t> order(samples_.size());
  std::iota(order.begin(), order.end(), std::size_t{0});
  std::stable_sort(order.begin(), order.end(),
                   [&](std::size_t a, std::size_t b) { return seq_[a] < seq_[b]; });
  order.erase(std::unique(order.begin(), order.end(),
                          [&](std::size_t a, std::size_t b) { return seq_[a] == seq_[b]; }),
              order.end());
  const TissueModel m(nominal_);
  const Quat to_web = nominal_.orientation.conjugate();
  PerFinger<std::vector<TissuePoint>> out;
  for (int k = 0; k < 2; ++k) {
    auto& pts = out[k];
    pts.reserve(order.size());
    for (const std::size_t idx : order) {
      const Sample& s = samples_[idx];
      const SampleFinger& f = s.fingers[k];
      TissuePoint p;
      p.seq = s.seq;
      p.t_ns = s.source_time_ns;
      p.p_device = Vec3(f.position_m[0], f.position_m[1], f.position_m[2]);
      p.p_web = m.toWeb(p.p_device);
      const Quat q = sampleOrientation(f);
      p.side_device = q * Vec3::UnitY();
      p.pad_device = q * Vec3::UnitZ();
      p.side_web = to_web * p.side_device;
      p.pad_web = to_web * p.pad_device;
      p.tangential_n = f.tangential_n;
      p.normal_n = f.normal_n;
      pts.push_back(p);
    }
    const std::size_t n = pts.size();
    const auto h = static_cast<std::size_t>(std::max(options_.rate_half_window, 1));
    for (std::size_t i = 0; i < n; ++i) {
      const std::size_t lo = i >= h ? i - h : 0;
      const std::size_t hi = std::min(i + h, n - 1);
      if (hi == lo) continue;
      const double dt = static_cast<double>(pts[hi].t_ns - pts[lo].t_ns) * 1e-9;
      // Across a gap (samples left out) the difference would not be a velocity.
      if (!(dt > 0.0) || pts[hi].seq - pts[lo].seq != hi - lo ||
          dt > 3e-3 * static_cast<double>(hi - lo))
        continue;
      pts[i].v_device = (pts[hi].p_device - pts[lo].p_device) / dt;
      pts[i].v_web = to_web * pts[i].v_device;
    }
    // Accelerations: second differences over twice the window, where it is complete.
    const std::size_t ha = 2 * h;
    for (std::size_t i = ha; i + ha < n; ++i) {
      const double dt1 = static_cast<double>(pts[i].t_ns - pts[i - ha].t_ns) * 1e-9;
      const double dt2 = static_cast<double>(pts[i + ha].t_ns - pts[i].t_ns) * 1e-9;
      if (pts[i + ha].seq - pts[i - ha].seq != 2 * ha || !(dt1 > 0.0) || !(dt2 > 0.0) ||
          dt1 + dt2 > 3e-3 * static_cast<double>(2 * ha))
        continue;
      pts[i].a_device = ((pts[i + ha].p_device - pts[i].p_device) / dt2 -
                         (pts[i].p_device - pts[i - ha].p_device) / dt1) /
                        (0.5 * (dt1 + dt2));
      pts[i].a_web = to_web * pts[i].a_device;
    }
  }
  return out;
}

TissuePrediction predictTissue(const TissueParams& model, int finger,
                               const std::vector<TissuePoint>& points) {
  const TissueModel m(model);
  TissuePrediction out;
  const std::size_t n = points.size();
  for (auto* v :
       {&out.normal_n, &out.tangential_n, &out.depth_m, &out.depth_rate_m_s, &out.normal_force_n})
    v->assign(n, 0.0);
  out.contact.assign(n, 0);
  out.slipping.assign(n, 0);
  TissueAnchor anchor;
  for (std::size_t i = 0; i < n; ++i) {
    const TissuePoint& p = points[i];
    const TissueContact c = tissueContact(m, finger, p.p_device, p.v_device, anchor);
    const Vec3 pressed = -c.force();
    out.normal_n[i] = std::max(pressed.dot(p.pad_device), 0.0);
    out.tangential_n[i] = pressed.dot(p.side_device);
    out.depth_m[i] = c.depth_m;
    out.depth_rate_m_s[i] = c.depth_rate_m_s;
    out.normal_force_n[i] = c.normal_n.norm();
    out.contact[i] = c.depth_m > 0.0;
    out.slipping[i] = c.depth_m > 0.0 && !c.sticking;
  }
  return out;
}

TissueFit TissueFitter::fit() const {
  TissueFit out;
  out.counts = counts_;
  out.params = nominal_;
  const auto pts = points();
  PerFinger<Prepared> d{prepare(nominal_, kThumb, pts[0]), prepare(nominal_, kIndex, pts[1])};
  out.samples = pts[0].size() + pts[1].size();

  const bool patch_geometry = nominal_.patch_radius_m > 0.0;
  NormalLayout nl;
  nl.offsets = options_.fit_surface;
  nl.mass = options_.fit_mass;
  FrictionLayout fl;

  // Normal block start.
  NormalParams nq = startNormal(d, options_, nl.offsets);
  nq.ln_fk = std::log(std::max(nominal_.patch_stiffness_factor, 0.1));
  NormalBlock nb(d, options_);
  PerFinger<NormalState> ns{normalState(d[0], nq), normalState(d[1], nq)};
  std::size_t contact = 0, in_patch = 0;
  double depth_lo = 1e300, depth_hi = -1e300, sum_ln_depth = 0.0;
  for (int k = 0; k < 2; ++k) {
    for (std::size_t i = 0; i < d[k].x.size(); ++i) {
      if (!ns[k].contact[i]) continue;
      ++contact;
      sum_ln_depth += std::log(ns[k].depth[i]);
      if (d[k].w[i] > 0.5) ++in_patch;
      depth_lo = std::min(depth_lo, ns[k].depth[i]);
      depth_hi = std::max(depth_hi, ns[k].depth[i]);
    }
  }
  if (contact < options_.min_contact_samples) {
    out.why = "too few samples in contact with the web (" + std::to_string(contact) + ", need " +
              std::to_string(options_.min_contact_samples) + ")";
    return out;
  }
  if (depth_hi - depth_lo < options_.min_depth_span_m) {
    out.why = "the capture pressed over too small a depth range";
    return out;
  }
  const bool patch = patch_geometry && options_.fit_patch && in_patch >= options_.min_patch_samples;
  nl.patch = patch;
  nl.ln_ref = sum_ln_depth / static_cast<double>(contact);
  fl.patch = patch;
  out.patch_fitted = patch;

  FrictionParams fq;
  fq.ln_fg = std::log(std::max(nominal_.patch_friction_factor, 0.1));
  double noise_lag1 = 0.0;
  PerFinger<FrictionState> fs;
  Eigen::MatrixXd ncov;
  double nrss = 0.0;
  auto clampNormal = [&](Eigen::VectorXd& t) {
    t(1) = std::clamp(t(1), TissueParams::kMinExponent, TissueParams::kMaxExponent);
    t(0) = std::clamp(t(0), std::log(1.0) + t(1) * nl.ln_ref,
                      std::log(TissueParams::kMaxStiffness) + t(1) * nl.ln_ref);
    t(2) = std::clamp(t(2), 0.0, TissueParams::kMaxDamping);
    Eigen::Index j = 3;
    if (nl.offsets) {
      for (int f = 0; f < 2; ++f, ++j)
        t(j) = std::clamp(t(j), -options_.max_surface_offset_m, options_.max_surface_offset_m);
    }
    if (nl.patch) {
      t(j) = std::clamp(t(j), std::log(0.1), std::log(TissueParams::kMaxPatchFactor));
      ++j;
    }
    if (nl.mass) t(j) = std::clamp(t(j), 0.0, 0.5);
  };

  for (int pass = 0; pass < std::max(options_.passes, 1); ++pass) {
    // Normal block.
    {
      auto eval = [&](const Eigen::VectorXd& t, Eigen::VectorXd& r, Eigen::MatrixXd* J) {
        nb.eval(unpackNormal(t, nl, nq), nl, r, J);
      };
      const Eigen::VectorXd t =
          levenbergMarquardt(packNormal(nq, nl), eval, clampNormal, options_.max_iterations, &ncov,
                             &nrss, &out.iterations);
      nq = unpackNormal(t, nl, nq);
      ns = {normalState(d[0], nq), normalState(d[1], nq)};
    }
    // Friction block (with the averaged model, simulateFriction).
    FrictionBlock fb(d, ns, 0);
    if (pass == 0) {
      // A grid over the lateral stiffness and the mu, b solved for each. The skin may stick
      // over most of a small circle (the anchor then sits inside it and the force points at
      // it, not against the motion), so the level of friction is searched, not read off
      // the sliding force.
      double best = std::numeric_limits<double>::infinity();
      for (double kt = 150.0; kt <= 5000.0; kt *= 1.5) {
        for (const double mus : {0.15, 0.25, 0.4, 0.6, 0.9, 1.3}) {
          for (const double ratio : {0.6, 0.8, 0.95}) {
            FrictionParams t = fq;
            t.ln_kt = std::log(kt);
            t.ln_mus = std::log(mus);
            t.ln_mum = std::log(mus * (1.0 + ratio) / 2.0);
            const double cost = fb.costProjected(t);
            if (cost < best) {
              best = cost;
              fq = t;
            }
          }
        }
      }
    }
    // Nelder–Mead on (ln kt, ln mu_mid, ln patch factor), b projected out, and a scan of
    // mu_static / mu_mid: the averaged model's residual is continuous in them but has kinks
    // (where the finger grazes the yield circle), which a simplex steps over better than
    // differences.
    if (pass == 0) noise_lag1 = noiseLag1(d, nq.offset);
    fq = refineFriction(fb, fq, fl, pass == 0 ? 0.15 : 0.03, pass == 0 ? 300 : 150, noise_lag1,
                        &out.iterations);
    Eigen::VectorXd r;
    fb.eval(fq, r, false, &fs);
    for (int k = 0; k < 2; ++k) nb.setFriction(k, fs[k]);
  }
  // The normal block once more with the final friction's share in eq. 2.
  {
    auto eval = [&](const Eigen::VectorXd& t, Eigen::VectorXd& r, Eigen::MatrixXd* J) {
      nb.eval(unpackNormal(t, nl, nq), nl, r, J);
    };
    const Eigen::VectorXd t =
        levenbergMarquardt(packNormal(nq, nl), eval, clampNormal, options_.max_iterations, &ncov,
                           &nrss, &out.iterations);
    nq = unpackNormal(t, nl, nq);
    ns = {normalState(d[0], nq), normalState(d[1], nq)};
  }
  // The viscous b. At massage speeds (a few cm/s) b·v is a tenth of a newton, what a change
  // of 1-2 % in the friction level makes: b and mu_mid trade (each per cent of mu_mid moves b
  // by 0.3-0.4 N·s/m on the healthy web), so b is only as good as the model's mean friction.
  // The averaged model's teeth on a curved path (each tooth's stretch grows along the
  // motion, not along the anchor's direction) leave a drag that grows with the speed, which
  // its b takes up; the exact sawtooth at the fitted kt and mu holds the teeth's mean force,
  // and out of step with the data it only adds scatter: b is the projection there (+0.1
  // N·s/m on average on the healthy web against +0.4 with the averaged model, spread
  // ±0.5; docs/capture.md).
  FrictionParams fit_q = fq;
  {
    FrictionBlock fb(d, ns, 0);
    fb.projectViscousWithLevel(fit_q);
    const double rss = fb.costProjected(fq);
    out.tangential_rms_n = fb.rows() > 0 ? std::sqrt(rss / static_cast<double>(fb.rows())) : 0.0;
  }
  // Standard errors: a delete-a-group jackknife over the contacts. The residual's curvature
  // would say far less (0.1 % on kt): the averaged model's misfit, not the noise, sets how
  // far the estimates move from one capture to another.
  const int groups = options_.jackknife_groups;
  std::array<std::vector<double>, 6> jack;  // kt, mu_s, mu_k, b, patch factor
  if (groups >= 2) {
    FrictionBlock fb(d, ns, groups);
    for (int g = 0; g < groups; ++g) {
      fb.leaveOut(g);
      FrictionParams q =
          refineFriction(fb, fq, fl, 0.03, options_.jackknife_evals, noise_lag1, &out.iterations);
      fb.projectViscousWithLevel(q);
      const double mus = std::exp(q.ln_mus), mum = std::exp(q.ln_mum);
      jack[0].push_back(std::exp(q.ln_kt));
      jack[1].push_back(mus);
      jack[2].push_back(std::max(2.0 * mum - mus, 0.0));
      jack[3].push_back(q.b);
      jack[4].push_back(std::exp(q.ln_fg));
    }
  }
  auto jackSe = [&](std::size_t j) {
    const auto& v = jack[j];
    if (v.size() < 2) return kNaN;
    const double n = static_cast<double>(v.size());
    const double mean = std::accumulate(v.begin(), v.end(), 0.0) / n;
    double ss = 0.0;
    for (const double x : v) ss += (x - mean) * (x - mean);
    return std::sqrt((n - 1.0) / n * ss);
  };

  // The fitted parameters and their standard errors.
  auto se = [](const Eigen::MatrixXd& cov, Eigen::Index j) {
    return j < cov.rows() ? std::sqrt(std::max(cov(j, j), 0.0)) : kNaN;
  };
  TissueParams& p = out.params;
  const double k = std::exp(nq.ln_k);
  // ln k = ln f_ref − n·ln δ_ref: its variance from the two's covariance.
  const double ln_k_var = ncov.rows() > 1 ? ncov(0, 0) + nl.ln_ref * nl.ln_ref * ncov(1, 1) -
                                                2.0 * nl.ln_ref * ncov(0, 1)
                                          : kNaN;
  out.stiffness = {k, k * std::sqrt(std::max(ln_k_var, 0.0))};
  out.ref_depth_m = std::exp(nl.ln_ref);
  const double f_ref = std::exp(nq.ln_k + nq.n * nl.ln_ref);
  out.force_at_ref = {f_ref, f_ref * se(ncov, 0)};
  out.thimble_mass_kg =
      nl.mass ? FittedValue{nq.mass, se(ncov, nl.size() - 1)} : FittedValue{0.0, kNaN};
  out.exponent = {nq.n, se(ncov, 1)};
  out.damping = {nq.lambda, se(ncov, 2)};
  if (nl.offsets) {
    out.surface_offset_m[0] = {nq.offset[0], se(ncov, 3)};
    out.surface_offset_m[1] = {nq.offset[1], se(ncov, 4)};
  }
  // mu_static is where the skin first yields after a touch, mu_mid the sliding level:
  // mu_kinetic = 2·mu_mid − mu_static.
  const double kt = std::exp(fq.ln_kt), mus = std::exp(fq.ln_mus), mum = std::exp(fq.ln_mum);
  const double muk = std::max(2.0 * mum - mus, 0.0);
  out.lateral_stiffness = {kt, jackSe(0)};
  out.mu_static = {mus, jackSe(1)};
  out.mu_kinetic = {muk, jackSe(2)};
  out.viscous = {fit_q.b, jackSe(3)};
  if (patch) {
    const double fk = std::exp(nq.ln_fk), fg = std::exp(fq.ln_fg);
    out.patch_stiffness_factor = {fk, fk * se(ncov, nl.size() - 1 - (nl.mass ? 1 : 0))};
    out.patch_friction_factor = {fg, jackSe(4)};
  } else {
    out.patch_stiffness_factor = {nominal_.patch_stiffness_factor, kNaN};
    out.patch_friction_factor = {nominal_.patch_friction_factor, kNaN};
  }
  p.stiffness_n_per_m_pow = k;
  p.exponent = nq.n;
  p.damping_s_per_m = nq.lambda;
  p.lateral_stiffness_n_per_m = kt;
  p.mu_static = mus;
  p.mu_kinetic = std::min(muk, mus);
  p.viscous_n_s_per_m = fit_q.b;
  p.patch_stiffness_factor = out.patch_stiffness_factor.value;
  p.patch_friction_factor = out.patch_friction_factor.value;
  // The surfaces: the thumb's side `offset[0]` and the index's `offset[1]` deeper than
  // nominal (depth = nominal + offset) is a web thicker by their sum and moved along its
  // normal by half their difference.
  p.thickness_m = nominal_.thickness_m + nq.offset[0] + nq.offset[1];
  p.origin_m = nominal_.origin_m +
               nominal_.orientation * Vec3(0.0, 0.0, 0.5 * (nq.offset[0] - nq.offset[1]));

  // Figures over the capture, from the fitted model as the proxy renders it.
  std::vector<double> rates, speeds;
  double sn = 0.0;
  std::size_t nn = 0, nt = 0, slips = 0;
  out.depth_min_m = 1e300;
  out.depth_max_m = 0.0;
  for (int f = 0; f < 2; ++f) {
    const TissuePrediction pr = predictTissue(p, f, pts[f]);
    FrictionState sliding;  // the averaged model's: where the skin slides, not its teeth
    simulateFriction(d[f], ns[f], fq, sliding);
    for (std::size_t i = 0; i < pts[f].size(); ++i) {
      if (!d[f].over[i] || d[f].d_nom[i] < -options_.max_surface_offset_m - 0.001) continue;
      const double with_mass = std::max(pr.normal_n[i] + nq.mass * d[f].acc_n[i], 0.0);
      const double pred_n =
          options_.normal_cut_at_zero ? cutMean(with_mass, options_.noise_n) : with_mass;
      sn += (pts[f][i].normal_n - pred_n) * (pts[f][i].normal_n - pred_n);
      ++nn;
      if (!pr.contact[i]) continue;
      ++nt;
      slips += sliding.slip[i];
      out.depth_min_m = std::min(out.depth_min_m, pr.depth_m[i]);
      out.depth_max_m = std::max(out.depth_max_m, pr.depth_m[i]);
      out.force_max_n = std::max(out.force_max_n, pr.normal_force_n[i]);
      rates.push_back(pr.depth_rate_m_s[i]);
      speeds.push_back(std::hypot(pts[f][i].v_web.x(), pts[f][i].v_web.y()));
      if (d[f].w[i] > 0.5) ++out.patch_samples;
    }
  }
  out.contact_samples = nt;
  out.normal_rms_n = nn ? std::sqrt(sn / static_cast<double>(nn)) : 0.0;
  out.slip_fraction = nt ? static_cast<double>(slips) / static_cast<double>(nt) : 0.0;
  out.depth_rate_p5_m_s = percentile(rates, 0.05);
  out.depth_rate_p95_m_s = percentile(rates, 0.95);
  out.speed_p95_m_s = percentile(speeds, 0.95);
  if (nt == 0) out.depth_min_m = 0.0;
  if (const char* bad = invalidTissueParam(p)) {
    out.why = std::string("the fitted web is not a valid model (") + bad + ")";
    return out;
  }
  out.ok = true;
  return out;
}

TissuePlotData tissuePlotData(const TissueFitter& fitter, const TissueFit& fit) {
  TissuePlotData out;
  const TissueParams& nominal = fitter.nominal();
  const auto pts = fitter.points();
  PerFinger<Prepared> d{prepare(nominal, kThumb, pts[0]), prepare(nominal, kIndex, pts[1])};
  NormalParams nq;
  nq.ln_k = std::log(std::max(fit.stiffness.value, 1e-300));
  nq.n = fit.exponent.value;
  nq.lambda = fit.damping.value;
  nq.offset = {fit.surface_offset_m[0].value, fit.surface_offset_m[1].value};
  nq.ln_fk = std::log(std::max(fit.params.patch_stiffness_factor, 1e-300));
  FrictionParams fq;
  fq.ln_kt = std::log(std::max(fit.lateral_stiffness.value, 1e-300));
  fq.ln_mus = std::log(std::max(fit.mu_static.value, 1e-300));
  fq.ln_mum = std::log(std::max(0.5 * (fit.mu_static.value + fit.mu_kinetic.value), 1e-300));
  fq.b = fit.viscous.value;
  fq.ln_fg = std::log(std::max(fit.params.patch_friction_factor, 1e-300));
  const double k = fit.stiffness.value, fk = fit.params.patch_stiffness_factor;
  const double fg = fit.params.patch_friction_factor;
  for (int f = 0; f < 2; ++f) {
    const Prepared& p = d[f];
    const NormalState ns = normalState(p, nq);
    FrictionState averaged, exact;
    simulateFriction(p, ns, fq, averaged);
    FrictionParams no_b = fq;
    no_b.b = 0.0;
    simulateFriction(p, ns, no_b, exact, true);
    bool attached = false, stuck = false;
    double x0 = 0.0, y0 = 0.0;
    for (std::size_t i = 0; i < p.x.size(); ++i) {
      if (!p.over[i] || p.d_nom[i] + nq.offset[f] < -0.002) continue;
      const double depth = p.d_nom[i] + nq.offset[f];
      const double share = p.a_n[i] > 0.5 ? p.a_n[i] : 1.0;
      // The normal channel less friction's share in it.
      const double tau = -(averaged.tx[i] * p.pad_x[i] + averaged.ty[i] * p.pad_y[i]);
      const double measured = (p.meas_n[i] - tau) / share;
      out.depth_m.push_back(depth);
      out.normal_n.push_back(measured);
      out.patch_weight.push_back(p.w[i]);
      if (!ns.contact[i]) {
        attached = false;
        continue;
      }
      const double el = k * (1.0 + p.w[i] * (fk - 1.0)) * std::pow(depth, nq.n);
      out.elastic_rate.push_back(el * p.rate[i]);
      out.normal_excess_n.push_back(measured - el);
      // Eq. 1 less the normal's share: the friction the pad presses along the side axis.
      const double friction = p.meas_t[i] - ns.force[i] * p.a_t[i];
      if (!attached) {
        attached = true;
        stuck = true;
        x0 = p.x[i];
        y0 = p.y[i];
      }
      if (averaged.slip[i]) stuck = false;
      const double vs = p.vx[i] * p.side_x[i] + p.vy[i] * p.side_y[i];
      if (stuck) {
        out.stick_disp_m.push_back((p.x[i] - x0) * p.side_x[i] + (p.y[i] - y0) * p.side_y[i]);
        out.stick_force_n.push_back(friction - fq.b * vs +
                                    (ns.rim_x[i] * p.side_x[i] + ns.rim_y[i] * p.side_y[i]));
      } else if (averaged.slip[i]) {
        // The model's stretch direction: its force less the viscous and rim parts.
        const double sx = -(averaged.tx[i] + fq.b * p.vx[i] - ns.rim_x[i]);
        const double sy = -(averaged.ty[i] + fq.b * p.vy[i] - ns.rim_y[i]);
        const double norm = std::hypot(sx, sy);
        const double c = norm > 0.0 ? (sx * p.side_x[i] + sy * p.side_y[i]) / norm : 0.0;
        if (std::abs(c) > std::cos(degToRad(35.0))) {
          const double g = 1.0 + p.w[i] * (fg - 1.0);
          out.slide_normal_n.push_back(g * ns.force[i]);
          out.slide_friction_n.push_back(
              (friction - fq.b * vs + (ns.rim_x[i] * p.side_x[i] + ns.rim_y[i] * p.side_y[i])) / c);
        }
      }
      const double pred_no_b =
          ns.force[i] * p.a_t[i] - (exact.tx[i] * p.side_x[i] + exact.ty[i] * p.side_y[i]);
      out.side_speed_m_s.push_back(vs);
      out.viscous_force_n.push_back(p.meas_t[i] - pred_no_b);
    }
  }
  return out;
}

namespace {

/// The shortest text that reads back as exactly `v`, as a TOML float.
std::string num(double v) {
  char buf[64];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  std::string out(buf, r.ptr);
  if (out.find_first_of(".eEn") == std::string::npos) out += ".0";
  return out;
}

}  // namespace

std::string tissueSectionToml(const TissueParams& p, const TissueFit* fit) {
  std::ostringstream o;
  char buf[256];
  auto fig = [&](const FittedValue& v, const char* unit) -> std::string {
    if (!fit) return "";
    if (std::isnan(v.se)) return "   # not fitted";
    std::snprintf(buf, sizeof buf, "   # ± %.3g%s (1 SE)", v.se, unit);
    return buf;
  };
  o << "[tissue]";
  if (fit) {
    std::snprintf(buf, sizeof buf,
                  "   # RMS residual eq. 2 %.3f N, eq. 1 %.3f N over %zu samples in contact; "
                  "depths %.1f..%.1f mm",
                  fit->normal_rms_n, fit->tangential_rms_n, fit->contact_samples,
                  fit->depth_min_m * 1e3, fit->depth_max_m * 1e3);
    o << buf;
    std::snprintf(buf, sizeof buf,
                  "\n# force at the reference depth %.2f mm: %.3g ± %.2g N (1 SE); moving mass "
                  "at the thimble %.3g kg",
                  fit->ref_depth_m * 1e3, fit->force_at_ref.value, fit->force_at_ref.se,
                  fit->thimble_mass_kg.value);
    o << buf;
  }
  o << "\n";
  o << "origin_m = [" << num(p.origin_m.x()) << ", " << num(p.origin_m.y()) << ", "
    << num(p.origin_m.z()) << "]\n";
  o << "orientation = [" << num(p.orientation.w()) << ", " << num(p.orientation.x()) << ", "
    << num(p.orientation.y()) << ", " << num(p.orientation.z()) << "]   # w, x, y, z\n";
  o << "thickness_m = " << num(p.thickness_m);
  if (fit && !std::isnan(fit->surface_offset_m[0].se)) {
    std::snprintf(buf, sizeof buf,
                  "   # surfaces moved %+.2f (thumb) / %+.2f (index) mm from the nominal",
                  fit->surface_offset_m[0].value * 1e3, fit->surface_offset_m[1].value * 1e3);
    o << buf;
  }
  o << "\npad_radius_m = " << num(p.pad_radius_m) << "\n";
  o << "half_extent_m = " << num(p.half_extent_m) << "\n";
  o << "stiffness_n_per_m_pow = " << num(p.stiffness_n_per_m_pow)
    << (fit ? fig(fit->stiffness, "") : "") << "\n";
  o << "exponent = " << num(p.exponent) << (fit ? fig(fit->exponent, "") : "") << "\n";
  o << "damping_s_per_m = " << num(p.damping_s_per_m) << (fit ? fig(fit->damping, "") : "") << "\n";
  o << "lateral_stiffness_n_per_m = " << num(p.lateral_stiffness_n_per_m)
    << (fit ? fig(fit->lateral_stiffness, "") : "") << "\n";
  o << "mu_static = " << num(p.mu_static) << (fit ? fig(fit->mu_static, "") : "") << "\n";
  o << "mu_kinetic = " << num(p.mu_kinetic) << (fit ? fig(fit->mu_kinetic, "") : "") << "\n";
  o << "viscous_n_s_per_m = " << num(p.viscous_n_s_per_m) << (fit ? fig(fit->viscous, "") : "")
    << "\n";
  o << "patch_x_m = " << num(p.patch_x_m) << "\n";
  o << "patch_y_m = " << num(p.patch_y_m) << "\n";
  o << "patch_radius_m = " << num(p.patch_radius_m) << "\n";
  o << "patch_stiffness_factor = " << num(p.patch_stiffness_factor)
    << (fit ? fig(fit->patch_stiffness_factor, "") : "") << "\n";
  o << "patch_friction_factor = " << num(p.patch_friction_factor)
    << (fit ? fig(fit->patch_friction_factor, "") : "") << "\n";
  o << "patch_rim_m = " << num(p.patch_rim_m) << "\n";
  return o.str();
}

std::string massageCaseToml(const TissueFit& fit, const JointModelParams& joint,
                            const std::string& name, const std::string& description,
                            const std::string& source) {
  std::ostringstream o;
  char buf[256];
  o << "# Fitted from a massage capture (telehand-records fit): the web's tissue model\n"
       "# (Hunt–Crossley normal force, stick–slip friction on an elastic skin anchor, viscous\n"
       "# skin) by least squares on what the thimbles measured (eqs. 1-2). The joint sections\n"
       "# are the base joint's: a massage capture does not move the MCP.\n";
  o << "[case]\n";
  o << "name = \"" << name << "\"\n";
  o << "description = \"" << description << "\"\n";
  o << "source = \"" << source << "\"\n";
  std::snprintf(buf, sizeof buf, "damping_nms_per_rad = %.9g\n", joint.damping_nms_per_rad);
  o << buf;
  std::snprintf(buf, sizeof buf, "speed_gain_s_per_rad = %.9g\n", joint.speed_gain_s_per_rad);
  o << buf;
  for (std::size_t i = 0; i < kAxes; ++i) {
    const CubicCurve& c = joint.axes[i];
    o << "\n[" << kAxisNames[i] << "]\n";
    std::snprintf(buf, sizeof buf,
                  "coeffs = [%.9g, %.9g, %.9g, %.9g]\nmin_deg = %.9g\nmax_deg = %.9g\n"
                  "neutral_zone_deg = %.9g\n",
                  c.coeffs[0], c.coeffs[1], c.coeffs[2], c.coeffs[3], c.min_deg, c.max_deg,
                  joint.neutral_zone_deg[i]);
    o << buf;
  }
  o << "\n" << tissueSectionToml(fit.params, &fit) << "\n";
  return o.str();
}

TissueParams tissueGeometry(const TissueParams& p) noexcept {
  TissueParams n;
  n.origin_m = p.origin_m;
  n.orientation = p.orientation;
  n.thickness_m = p.thickness_m;
  n.pad_radius_m = p.pad_radius_m;
  n.half_extent_m = p.half_extent_m;
  n.patch_x_m = p.patch_x_m;
  n.patch_y_m = p.patch_y_m;
  n.patch_radius_m = p.patch_radius_m;
  n.patch_rim_m = p.patch_rim_m;
  return n;
}

}  // namespace telehand::server::estimate
