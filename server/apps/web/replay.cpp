#include "replay.h"

#include <spdlog/fmt/fmt.h>

#include <algorithm>
#include <iterator>
#include <vector>

#include "frames.h"
#include "telehand/core/joint_model.h"
#include "telehand/core/thimble.h"
#include "telehand/server/store/open_store.h"

namespace telehand::web {

using server::store::openStore;
using server::store::SessionStore;

namespace {

std::string sessionJson(const server::store::SessionInfo& s) {
  return fmt::format(R"({{"id":{},"user":{},"case":{},"mode":{},"state":{},"started_ms":{:.3f},)"
                     R"("ended_ms":{:.3f},"samples":{}}})",
                     s.id, jsonString(s.user), jsonString(s.case_name), jsonString(s.mode),
                     jsonString(s.state), static_cast<double>(s.started_ns) * 1e-6,
                     static_cast<double>(s.ended_ns) * 1e-6, s.samples);
}

void column(std::string& out, const char* name, const std::vector<double>& v) {
  fmt::format_to(std::back_inserter(out), R"(,"{}":[)", name);
  for (std::size_t i = 0; i < v.size(); ++i) {
    if (i) out += ',';
    out += jsonNumber(v[i]);
  }
  out += ']';
}

/// A column of whole numbers written exactly (sample numbers pass 6 significant digits after
/// 17 minutes at 1 kHz).
void column(std::string& out, const char* name, const std::vector<uint64_t>& v) {
  fmt::format_to(std::back_inserter(out), R"(,"{}":[)", name);
  for (std::size_t i = 0; i < v.size(); ++i) {
    if (i) out += ',';
    fmt::format_to(std::back_inserter(out), "{}", v[i]);
  }
  out += ']';
}

}  // namespace

std::optional<std::string> replayFrame(const std::string& db, uint64_t session,
                                       std::size_t max_points) {
  const auto opened = openStore(db, SessionStore::Mode::kReadOnly);
  SessionStore& store = *opened;
  const auto info = store.session(session);
  if (!info) return std::nullopt;
  const uint64_t stride = std::max<uint64_t>(1, (info->samples + max_points - 1) / max_points);
  // The force against the band is the applied force in reference scale, as the server's hand
  // computes it (HandState.applied_force_ref_n); a capture renders at 1:1.
  const double force_scale = info->mode == "capture" ? 1.0 : JointModelParams{}.force_scale;
  std::vector<double> t, a, b, g, force, thumb, index;
  std::vector<uint64_t> seq;
  int64_t t0 = 0;
  uint64_t n = 0;
  store.forEachSample(session, [&](const Sample& s, bool valid) {
    if (n++ % stride != 0 || !valid) return;
    if (t.empty()) t0 = s.source_time_ns;
    Vec3 applied = Vec3::Zero();
    double per[2];
    for (std::size_t k = 0; k < 2; ++k) {
      const auto& f = s.fingers[k];
      const Quat q(f.orientation_q[0], f.orientation_q[1], f.orientation_q[2], f.orientation_q[3]);
      const Vec3 fv = thimbleForceVector({f.tangential_n, f.normal_n}, q);
      applied += fv;
      per[k] = fv.norm();
    }
    t.push_back(static_cast<double>(s.source_time_ns - t0) * 1e-9);
    seq.push_back(s.seq);
    a.push_back(s.mcp_angles_rad[0]);
    b.push_back(s.mcp_angles_rad[1]);
    g.push_back(s.mcp_angles_rad[2]);
    force.push_back(applied.norm() / force_scale);
    thumb.push_back(per[0]);
    index.push_back(per[1]);
  });
  std::string out =
      fmt::format(R"({{"type":"replay","session":{},"info":{},"t0_ms":{:.3f},)"
                  R"("stride":{},"points":{})",
                  session, sessionJson(*info), static_cast<double>(t0) * 1e-6, stride, t.size());
  column(out, "t", t);
  column(out, "seq", seq);
  column(out, "alpha", a);
  column(out, "beta", b);
  column(out, "gamma", g);
  column(out, "force", force);
  column(out, "thumb_n", thumb);
  column(out, "index_n", index);
  out += R"(,"events":[)";
  bool first = true;
  for (const auto& e : store.events(session)) {
    if (!first) out += ',';
    first = false;
    fmt::format_to(std::back_inserter(out), R"({{"t_ms":{:.3f},"kind":{},"text":{}}})",
                   static_cast<double>(e.time_ns) * 1e-6, jsonString(e.kind), jsonString(e.text));
  }
  out += "]}";
  return out;
}

std::string recordsFrame(const std::string& db) {
  const auto store = openStore(db, SessionStore::Mode::kReadOnly);
  const auto all = store->listSessions();
  // The newest only: a record of years would make a reply over a browser's queue bound, and
  // the browser would be dropped at every connection.
  const std::size_t from = all.size() > kMaxRecordsListed ? all.size() - kMaxRecordsListed : 0;
  std::string out = R"({"type":"records","sessions":[)";
  for (std::size_t i = from; i < all.size(); ++i) {
    if (i != from) out += ',';
    out += sessionJson(all[i]);
  }
  fmt::format_to(std::back_inserter(out), R"(],"total":{}}})", all.size());
  return out;
}

}  // namespace telehand::web
