// Capture and fitting figures (README "Performance"):
//  1. the k-nearest-neighbour (FLANN) model's cost per 1 kHz tick: the query alone, back to
//     back and paced at 1 kHz (caches go cold between ticks, as in the loop), and the whole
//     JointProxy::render with it;
//  2. live refit latency in the server: from the arrival of a capture's newest sample to
//     the JointModel fitted from it being published, with the capture streamed in real
//     time as the client's 100-sample record chunks; and the refit's compute time.
//  3. (--fit-table) fitted holding force against the truth: the shipped cases at the default
//     capture length (10 s per axis), 0.5, 3 and 6 Hz, the paper's 1.43 N thimble noise,
//     three seeds each; the largest error over the reachable range off the zone edges and
//     walls, and including them (the walls to 2 deg beyond each end reached).
// Usage: telehand_bench_capture [--quick | --fit-table [CASES_DIR, default deploy/cases]]
#include <spdlog/spdlog.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <vector>

#include "telehand/config/config.h"
#include "telehand/core/clock.h"
#include "telehand/core/knn_model.h"
#include "telehand/protocol/wire.h"
#include "telehand/server/estimate/synthetic_capture.h"
#include "telehand/server/session/session_manager.h"
#include "telehand/server/store/sqlite_store.h"

using namespace telehand;

namespace {

int64_t now() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec * kNsPerS + ts.tv_nsec;
}

void sleepUntil(int64_t t) {
  timespec ts{t / kNsPerS, t % kNsPerS};
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
  }
}

void report(const char* what, std::vector<int64_t> ns, double unit = 1e3, const char* u = "us") {
  std::sort(ns.begin(), ns.end());
  auto q = [&](double p) {
    return static_cast<double>(ns[std::min(
               ns.size() - 1, static_cast<std::size_t>(p * static_cast<double>(ns.size())))]) /
           unit;
  };
  std::printf("%-52s n=%-7zu p50 %8.2f  p90 %8.2f  p99 %8.2f  p99.9 %8.2f  max %8.2f %s\n", what,
              ns.size(), q(0.5), q(0.9), q(0.99), q(0.999), static_cast<double>(ns.back()) / unit,
              u);
}

class Recorder final : public server::session::Outbox {
 public:
  void publish(const telehand_msg_SessionStatus&) override {}
  void publish(const telehand_msg_JointModel& m) override {
    if (m.session_id == 1) ++capture_models;
  }
  void publish(const telehand_msg_HandState&) override {}
  void publish(const telehand_msg_SessionEvent&) override {}
  int capture_models = 0;
};

}  // namespace

/// The fitted and true holding force, worst over the reachable range (inner: off the zone
/// edges and 1 deg from the walls; edges: including them and 2 deg into each wall reached).
std::pair<double, double> fitErrors(const JointModelParams& truth_p, const JointModelParams& fit_p,
                                    int i, double max_force_n) {
  const JointModel truth(truth_p), fitted(fit_p);
  const CubicCurve& c = truth_p.axes[static_cast<std::size_t>(i)];
  const double rest = radToDeg(truth.restAngleRad(i));
  auto f = [&](double d) { return truth.holdingForceN(i, degToRad(d)); };
  double lo = rest, hi = rest;
  while (lo - 0.05 >= c.min_deg && std::abs(f(lo - 0.05)) <= max_force_n) lo -= 0.05;
  while (hi + 0.05 <= c.max_deg && std::abs(f(hi + 0.05)) <= max_force_n) hi += 0.05;
  const bool wlo = lo <= c.min_deg + 0.05, whi = hi >= c.max_deg - 0.05;
  const double zone = truth_p.neutral_zone_deg[static_cast<std::size_t>(i)];
  double inner = 0.0, edges = 0.0;
  for (double d = wlo ? c.min_deg - 2.0 : lo; d <= (whi ? c.max_deg + 2.0 : hi); d += 0.05) {
    const double e = std::abs(fitted.holdingForceN(i, degToRad(d)) - f(d));
    edges = std::max(edges, e);
    const bool near =
        (wlo && d < c.min_deg + 1.0) || (whi && d > c.max_deg - 1.0) ||
        (zone > 0.0 && (std::abs(d - rest + zone) < 1.5 || std::abs(d - rest - zone) < 1.5));
    if (d >= lo && d <= hi && !near) inner = std::max(inner, e);
  }
  return {inner, edges};
}

int fitTable(const std::string& cases_dir) {
  std::printf(
      "case      Hz   | flexion inner/edges | abduction inner/edges | axial inner/edges "
      "(N, worst of 3 seeds)\n");
  for (const char* name : {"healthy", "stiff", "lax", "recovery", "spasm"}) {
    const JointModelParams truth = loadPatientCase(cases_dir + "/" + name + ".toml").model;
    for (const double hz : {0.5, 3.0, 6.0}) {
      std::array<std::pair<double, double>, kAxes> worst{};
      bool all_ok = true;
      for (uint64_t seed = 1; seed <= 3; ++seed) {
        server::estimate::SyntheticCaptureOptions o;
        o.truth = truth;
        o.frequency_hz = hz;
        o.seed = seed;
        const auto cap = server::estimate::synthesizeCapture(o);
        server::estimate::CaptureFitter fitter(cap.geometry);
        for (const auto& smp : cap.samples) fitter.add(smp, true);
        const auto fit = fitter.fit();
        all_ok = all_ok && fit.ok();
        JointModelParams static_truth = truth;
        static_truth.speed_gain_s_per_rad = 0.0;
        for (int i = 0; i < kAxes; ++i) {
          const auto e = fitErrors(static_truth, fit.model(truth), i, o.max_force_n);
          auto& w = worst[static_cast<std::size_t>(i)];
          w = {std::max(w.first, e.first), std::max(w.second, e.second)};
        }
      }
      std::printf("%-9s %-4.1f | %6.2f / %-6.2f     | %6.2f / %-6.2f       | %6.2f / %-6.2f %s\n",
                  name, hz, worst[0].first, worst[0].second, worst[1].first, worst[1].second,
                  worst[2].first, worst[2].second, all_ok ? "" : "(an axis not fitted)");
    }
  }
  return 0;
}

int main(int argc, char** argv) {
  if (argc > 1 && std::strcmp(argv[1], "--fit-table") == 0)
    return fitTable(argc > 2 ? argv[2] : "deploy/cases");
  const bool quick = argc > 1 && std::strcmp(argv[1], "--quick") == 0;
  spdlog::set_level(spdlog::level::warn);
  // 1. k-nearest neighbours per tick.
  // Flexion and abduction swept together (the coupled-joint capture): samples fill the plane.
  server::estimate::SyntheticCaptureOptions o;
  o.seconds_per_axis = quick ? 4.0 : 20.0;
  o.combined_sweep = true;
  o.frequency_hz = 0.1;
  o.max_force_n = 8.0;
  const auto train = server::estimate::synthesizeCapture(o);
  o.seed = 2;
  const auto held = server::estimate::synthesizeCapture(o);
  server::estimate::CaptureFitter ft(train.geometry), fh(held.geometry);
  for (const auto& s : train.samples) ft.add(s, true);
  for (const auto& s : held.samples) fh.add(s, true);
  std::vector<KnnPoint> raw;
  for (const auto& p : ft.points())
    raw.push_back({p.angles_rad, -p.axis_force_n * train.geometry.lever_arm_m});
  const KnnTorqueModel cells(voxelAverage(raw, KnnOptions{}.cell_deg));
  const KnnTorqueModel all(raw);
  std::printf("kNN model: %zu cell-averaged samples (the live model), %zu raw samples; k = %d\n",
              cells.size(), all.size(), KnnOptions{}.k);
  const auto& q = fh.points();
  volatile double sink = 0.0;
  for (const KnnTorqueModel* m : {&cells, &all}) {
    std::vector<int64_t> t;
    t.reserve(q.size());
    for (const auto& p : q) {
      const int64_t t0 = now();
      sink = sink + m->torqueNm(p.angles_rad)[0];
      t.push_back(now() - t0);
    }
    report(
        m == &cells ? "query back to back, cell-averaged model" : "query back to back, raw samples",
        t);
  }
  {
    // Paced at 1 kHz: one query per millisecond along the held-out trajectory.
    const std::size_t ticks = quick ? 1000 : 10000;
    std::vector<int64_t> t;
    t.reserve(ticks);
    int64_t next = now() + kNsPerMs;
    for (std::size_t i = 0; i < ticks; ++i) {
      sleepUntil(next);
      next += kNsPerMs;
      const int64_t t0 = now();
      sink = sink + cells.torqueNm(q[i % q.size()].angles_rad)[0];
      t.push_back(now() - t0);
    }
    report("query paced at 1 kHz, cell-averaged model", t);
  }
  {
    JointModelParams p = healthyIndexMcp();
    p.knn = &cells;
    JointProxy knn_proxy(p), cubic_proxy(healthyIndexMcp());
    const JointModel geo(p);
    for (JointProxy* proxy : {&cubic_proxy, &knn_proxy}) {
      std::vector<int64_t> t;
      int64_t clock = kNsPerS;
      for (const auto& pt : q) {
        const auto grip = geo.gripFromAngles(pt.angles_rad, 0.008);
        clock += kNsPerMs;
        const int64_t t0 = now();
        sink = sink + proxy->render(grip, clock).torque_ref_nm[0];
        t.push_back(now() - t0);
      }
      report(
          proxy == &knn_proxy ? "JointProxy::render, kNN model" : "JointProxy::render, cubic model",
          t);
    }
  }

  // 2. Live refit latency, real time.
  namespace fs = std::filesystem;
  const fs::path dir =
      fs::temp_directory_path() / ("telehand-bench-capture-" + std::to_string(getpid()));
  fs::create_directories(dir);
  {
    server::store::SqliteStore store((dir / "r.db").string());
    Recorder out;
    server::session::SessionManager mgr(store, out, ServerConfig{});
    telehand_msg_SessionCommand open{};
    open.client_id = 1;
    open.kind = telehand_msg_CMD_OPEN;
    open.mode = telehand_msg_MODE_CAPTURE;
    std::strcpy(open.case_name, "healthy");
    mgr.onCommand(open, now());
    server::estimate::SyntheticCaptureOptions lo;
    lo.seconds_per_axis = quick ? 2.0 : 6.0;
    const auto cap = server::estimate::synthesizeCapture(lo);
    std::vector<int64_t> latency, compute, chunk_cost;
    std::vector<telehand_msg_DeviceState> chunk;
    int64_t next_chunk = now();
    int64_t last_latency_seen = 0;
    int published_before = 0;
    for (std::size_t i = 0; i < cap.samples.size(); i += 100) {
      // The server ticks every few ms between chunks (its waitset wakes on data or timeout).
      while (now() < next_chunk) {
        const int64_t t0 = now();
        mgr.tick(t0);
        const int64_t dt = now() - t0;
        if (out.capture_models != published_before) {
          published_before = out.capture_models;
          compute.push_back(dt);
          if (mgr.stats().last_refit_latency_ns != last_latency_seen) {
            last_latency_seen = mgr.stats().last_refit_latency_ns;
            latency.push_back(last_latency_seen + dt);
          }
        }
        sleepUntil(std::min(next_chunk, now() + 2 * kNsPerMs));
      }
      next_chunk += 100 * kNsPerMs;
      chunk.clear();
      for (std::size_t j = i; j < std::min(i + 100, cap.samples.size()); ++j)
        chunk.push_back(toWire(cap.samples[j]));
      for (auto& s : chunk) s.session_id = 1;
      telehand_msg_RecordChunk c{};
      c.session_id = 1;
      c.chunk_seq = i / 100;
      c.samples._buffer = chunk.data();
      c.samples._length = static_cast<uint32_t>(chunk.size());
      c.samples._maximum = c.samples._length;
      const int64_t t0 = now();
      mgr.onChunk(c, t0);
      chunk_cost.push_back(now() - t0);
    }
    std::printf(
        "live refit: %d models published from a %.0f s capture (%zu samples), refit at most every "
        "%.1f s;\n"
        "  a sample that arrives just after a refit waits for the next one (up to that interval)\n",
        out.capture_models, static_cast<double>(cap.samples.size()) / 1000.0, cap.samples.size(),
        static_cast<double>(server::estimate::LiveRefitOptions{}.min_interval_ns) / 1e9);
    if (!latency.empty()) {
      report("newest sample's arrival -> model published", latency, 1e6, "ms");
      report("refit compute (tick that published)", compute, 1e6, "ms");
    }
    report("storing + feeding one 100-sample chunk", chunk_cost, 1e6, "ms");
    std::printf(
        "  end to end add the client's chunking (a sample waits up to 100 ms for its chunk) "
        "and DDS (~0.1 ms on loopback)\n");
    mgr.closeAll(now());
  }
  fs::remove_all(dir);
  return sink == 12345.678 ? 1 : 0;
}
