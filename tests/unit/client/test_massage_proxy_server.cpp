// The client's tissue proxy and the server's web agree: the client's HapticLoop renders the
// web on the simulated MF-2 (the virtual clinician circling with 10 ± 2 N) in simulated time,
// and the samples it records, fed in order to the server's WebSim as its session feeds the
// live stream at zero delay, give the server the same per-finger web force the client
// recorded (Sample::fingers[k].tissue_force_n) on every sample. With samples lost on the way
// the server's web takes its state back from those recorded forces (WebSim::resync).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "telehand/client/loop/haptic_loop.h"
#include "telehand/core/clock.h"
#include "telehand/core/joint_model.h"
#include "telehand/core/safety.h"
#include "telehand/core/sample.h"
#include "telehand/core/tissue_model.h"
#include "telehand/devices/simulated_massage_mf2.h"
#include "telehand/server/sim/web_sim.h"

namespace telehand {
namespace {

struct Agreement {
  std::size_t samples = 0;
  std::size_t in_contact = 0;  ///< samples on which both pads pressed the web
  double max_rel_error = 0.0;  ///< max |F_server − F_client| / max(|F_client|, 1 N)
  std::size_t worst_seq = 0;
  double max_force_n = 0.0;  ///< largest client web force (reference N)
  double in_band = 0.0;      ///< share of massage ticks with both pads in 10 ± 2 N
  client::loop::LoopFault fault = client::loop::LoopFault::kNone;
};

/// `seconds` of the clinician's massage on case `tissue_case` through the client's loop, then
/// the recorded samples through the server's web.
Agreement runAgreement(const std::string& tissue_case, uint64_t seed, double seconds) {
  JointModelParams model = healthyIndexMcp();
  model.technique = Technique::kMassage;
  model.tissue = tissueCase(tissue_case.c_str());
  ManualClock clock(kNsPerS);
  OperatorConfig op;
  op.seed = seed;
  devices::SimulatedMassageMf2 dev(model.tissue, op, clock, model.force_scale);
  client::loop::HapticLoop loop(dev, clock, model, SafetyLimits{});
  const auto ticks = static_cast<std::size_t>(std::lround(seconds * 1000.0));
  std::vector<Sample> samples;
  samples.reserve(ticks);
  Sample s;
  for (std::size_t i = 0; i < ticks; ++i) {
    clock.advance(kNsPerMs);
    loop.step();
    while (loop.samples().tryPop(s)) samples.push_back(s);
  }
  Agreement a;
  a.samples = samples.size();
  a.fault = loop.fault();
  const auto& h = loop.health();
  a.in_band = h.massage_ticks.load() > 0 ? static_cast<double>(h.massage_in_band.load()) /
                                               static_cast<double>(h.massage_ticks.load())
                                         : 0.0;
  // The server's stepping path (HandRunner::advance): one WebSim step per live sample, at the
  // sample's time, with the thimble positions the sample carries.
  server::sim::WebSim web(model.tissue, model.force_scale);
  for (const Sample& rec : samples) {
    web.step(thimblePositions(rec), rec.source_time_ns);
    const TissueOutput& out = web.last();
    bool both = true;
    for (int k = 0; k < 2; ++k) {
      const Vec3 client(rec.fingers[k].tissue_force_n[0], rec.fingers[k].tissue_force_n[1],
                        rec.fingers[k].tissue_force_n[2]);
      const Vec3 server = out.contact[k].force();
      const double rel = (server - client).norm() / std::max(client.norm(), 1.0);
      if (!(rel <= a.max_rel_error)) {
        a.max_rel_error = std::isfinite(rel) ? rel : 1e9;
        a.worst_seq = rec.seq;
      }
      a.max_force_n = std::max(a.max_force_n, client.norm());
      both = both && rec.fingers[k].contact_depth_m > 0.0;
    }
    if (both) ++a.in_contact;
  }
  return a;
}

void expectAgreement(const std::string& tissue_case, uint64_t seed) {
  constexpr double kSeconds = 6.0;
  const Agreement a = runAgreement(tissue_case, seed, kSeconds);
  ASSERT_EQ(a.samples, 6000u) << "every tick recorded";
  EXPECT_EQ(a.fault, client::loop::LoopFault::kNone);
  // The run is a massage, not two pads in the air: both press for most of it, near 10 N.
  EXPECT_GT(a.in_contact, a.samples * 8 / 10) << tissue_case;
  EXPECT_GT(a.max_force_n, 8.0) << tissue_case;
  EXPECT_GT(a.in_band, 0.5) << tissue_case;
  EXPECT_LE(a.max_rel_error, 0.02)
      << tissue_case << " seed " << seed << ": worst at seq " << a.worst_seq;
  std::printf(
      "%-10s seed %llu: %zu samples, %zu with both pads in, largest force %.2f N, "
      "%.1f %% in 10 ± 2 N, largest proxy/server difference %.3g %%\n",
      tissue_case.c_str(), static_cast<unsigned long long>(seed), a.samples, a.in_contact,
      a.max_force_n, 100.0 * a.in_band, 100.0 * a.max_rel_error);
}

/// The client's samples with bursts lost on the way, stepped as HandRunner::advance steps a
/// gap (the straight line between the samples either side) with or without taking the skin
/// back from the client's recorded force: the largest difference, normal and tangential.
struct LossyAgreement {
  double normal = 0.0, tangential = 0.0;
};
LossyAgreement runLossy(const std::string& tissue_case, uint64_t seed, bool resync) {
  JointModelParams model = healthyIndexMcp();
  model.technique = Technique::kMassage;
  model.tissue = tissueCase(tissue_case.c_str());
  ManualClock clock(kNsPerS);
  OperatorConfig op;
  op.seed = seed;
  devices::SimulatedMassageMf2 dev(model.tissue, op, clock, model.force_scale);
  client::loop::HapticLoop loop(dev, clock, model, SafetyLimits{});
  std::vector<Sample> samples;
  Sample s;
  for (int i = 0; i < 6000; ++i) {
    clock.advance(kNsPerMs);
    loop.step();
    while (loop.samples().tryPop(s)) samples.push_back(s);
  }
  server::sim::WebSim web(model.tissue, model.force_scale);
  const Vec3 axis = web.model().normalAxis();
  LossyAgreement a;
  const Sample* last = nullptr;
  for (std::size_t i = 0; i < samples.size(); ++i) {
    if (i % 97 >= 89) continue;  // 8 in a burst lost
    const Sample& rec = samples[i];
    const PerFinger<Vec3> to = thimblePositions(rec);
    if (last != nullptr && rec.seq - last->seq > 1) {
      const PerFinger<Vec3> from = thimblePositions(*last);
      const auto steps = static_cast<double>(rec.seq - last->seq);
      for (uint64_t j = 1; j < rec.seq - last->seq; ++j) {
        const double w = static_cast<double>(j) / steps;
        web.step({from[0] + w * (to[0] - from[0]), from[1] + w * (to[1] - from[1])},
                 last->source_time_ns +
                     static_cast<int64_t>(
                         static_cast<double>(rec.source_time_ns - last->source_time_ns) * w));
      }
    }
    web.step(to, rec.source_time_ns);
    PerFinger<Vec3> force;
    PerFinger<double> depth;
    for (std::size_t k = 0; k < 2; ++k) {
      const auto& f = rec.fingers[k];
      force[k] = Vec3(f.tissue_force_n[0], f.tissue_force_n[1], f.tissue_force_n[2]);
      depth[k] = f.contact_depth_m;
    }
    if (resync) web.resync(force, depth);
    last = &rec;
    if (i < 1000) continue;
    for (std::size_t k = 0; k < 2; ++k) {
      const Vec3 d = web.last().contact[k].force() - force[k];
      a.normal = std::max(a.normal, std::abs(d.dot(axis)));
      a.tangential = std::max(a.tangential, (d - d.dot(axis) * axis).norm());
    }
  }
  return a;
}

TEST(MassageProxyServer, OnALossyLinkTheServerTakesTheWebBackFromTheClientsForce) {
  for (const char* c : {"healthy", "hypertonic", "oedema", "scar"}) {
    const LossyAgreement off = runLossy(c, 1, false), on = runLossy(c, 1, true);
    std::printf(
        "%-10s 8 of 97 lost: largest difference normal %.3g N, tangential %.3g N; "
        "stepped alone %.3g N, %.3g N\n",
        c, on.normal, on.tangential, off.normal, off.tangential);
    // Differences under 1 nN are left alone (WebSim::resync).
    EXPECT_LT(on.normal, 1e-8) << c;
    EXPECT_LT(on.tangential, 1e-8) << c;
    EXPECT_GT(std::max(off.normal, off.tangential), 1e-3) << c << ": the gaps part the webs";
  }
  // The skin sticks and slips out of step after the first gap.
  EXPECT_GT(runLossy("healthy", 1, false).tangential, 0.5);
}

TEST(MassageProxyServer, ServerWebMatchesTheClientsRecordedForceHealthy) {
  expectAgreement("healthy", 1);
}

TEST(MassageProxyServer, ServerWebMatchesTheClientsRecordedForceAnotherSeed) {
  expectAgreement("healthy", 7);
}

TEST(MassageProxyServer, ServerWebMatchesTheClientsRecordedForceHypertonic) {
  expectAgreement("hypertonic", 3);
}

TEST(MassageProxyServer, ServerWebMatchesTheClientsRecordedForceScar) {
  // The stiff, sticky patch sits where the clinician circles (docs/massage.md "Cases").
  expectAgreement("scar", 5);
}

}  // namespace
}  // namespace telehand
