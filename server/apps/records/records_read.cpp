#include "records_read.h"

#include <algorithm>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <sstream>
#include <vector>

namespace telehand::records {

using namespace server::store;

namespace {

std::string formatTime(int64_t ns) {
  if (ns <= 0) return "-";
  const std::time_t t = static_cast<std::time_t>(ns / 1'000'000'000);
  std::tm tm{};
  localtime_r(&t, &tm);
  std::ostringstream o;
  o << std::put_time(&tm, "%Y-%m-%d %H:%M:%S");
  return o.str();
}

/// Samples the client said it sent that the record does not hold.
/// Samples the client said it sent and the record lacks; "?" when the client never said
/// (a session still open, or one whose server stopped before the CLOSE): then nobody knows
/// how many are missing, and 0 would claim the record complete.
std::string missingSamples(const SessionInfo& s) {
  if (s.samples_expected == 0) return s.samples == 0 && s.state == "closed" ? "0" : "?";
  return std::to_string(s.missing());
}

}  // namespace

int runList(SessionStore& store) {
  const auto sessions = store.listSessions();
  if (sessions.empty()) {
    std::cout << "no sessions in " << store.location() << "\n";
    return 0;
  }
  std::cout << std::left << std::setw(6) << "id" << std::setw(14) << "user" << std::setw(14)
            << "mode" << std::setw(10) << "case" << std::setw(12) << "state" << std::setw(21)
            << "started" << std::right << std::setw(10) << "duration" << std::setw(10) << "samples"
            << std::setw(10) << "missing"
            << "\n";
  for (const auto& s : sessions) {
    const double dur =
        s.ended_ns > s.started_ns ? static_cast<double>(s.ended_ns - s.started_ns) * 1e-9 : 0.0;
    const std::string missing = missingSamples(s);
    std::ostringstream d;
    d << std::fixed << std::setprecision(1) << dur << " s";
    std::cout << std::left << std::setw(6) << s.id << std::setw(14) << s.user << std::setw(14)
              << s.mode << std::setw(10) << s.case_name << std::setw(12) << s.state << std::setw(21)
              << formatTime(s.started_ns) << std::right << std::setw(10) << d.str() << std::setw(10)
              << s.samples << std::setw(10) << missing << "\n";
  }
  return 0;
}

int runShow(SessionStore& store, const SessionInfo& info, bool digest) {
  const uint64_t session_id = info.id;
  const std::string missing = missingSamples(info);
  std::cout << "session " << info.id << ": " << info.mode << " on case '" << info.case_name
            << "' for " << info.user << ", " << info.state << ", started "
            << formatTime(info.started_ns) << "\n  samples " << info.samples << " (missing "
            << missing << ", flagged invalid " << info.rejected << ")\n";
  if (!info.owner.empty()) std::cout << "  opened by participant " << info.owner << "\n";
  if (const std::string server = store.poolOwner(session_id); !server.empty()) {
    std::cout << "  served by " << server << " (pool)\n";
  }
  if (digest) {
    SampleDigest d;
    store.forEachSample(session_id, [&](const Sample& s, bool) { d.add(s); });
    std::cout << "  record holds " << d.text() << "\n";
  }
  const auto events = store.events(session_id);
  std::cout << "events (" << events.size() << "):\n";
  for (const auto& e : events) {
    std::cout << "  " << formatTime(e.time_ns) << "  " << std::left << std::setw(9) << e.kind
              << e.text << "\n";
  }
  const auto reaches = store.reaches(session_id);
  if (!reaches.empty()) {
    // Each phase in the order recorded, its six directions in the order exploration names
    // them (server/session exploration.h): a direction the phase never took the joint into
    // has no row and shows as not reached, never as a 0 deg reach.
    static constexpr const char* kDirections[] = {"flexion",   "extension",  "abduction",
                                                  "adduction", "supination", "pronation"};
    std::vector<std::string> phases;
    for (const auto& r : reaches) {
      if (std::find(phases.begin(), phases.end(), r.phase) == phases.end()) {
        phases.push_back(r.phase);
      }
    }
    std::cout << "exploration:\n  " << std::left << std::setw(14) << "phase" << std::setw(12)
              << "direction" << std::right << std::setw(10) << "angle" << std::setw(12)
              << "force\n";
    auto row = [](const SessionStore::Reach& r) {
      std::cout << "  " << std::left << std::setw(14) << r.phase << std::setw(12) << r.direction
                << std::right << std::setw(8) << std::fixed << std::setprecision(1) << r.angle_deg
                << " deg" << std::setw(8) << r.force_n << " N\n";
    };
    for (const auto& phase : phases) {
      for (const char* dir : kDirections) {
        const auto it = std::find_if(reaches.begin(), reaches.end(), [&](const auto& r) {
          return r.phase == phase && r.direction == dir;
        });
        if (it != reaches.end()) {
          row(*it);
        } else {
          std::cout << "  " << std::left << std::setw(14) << phase << std::setw(12) << dir
                    << std::right << std::setw(14) << "not reached"
                    << "\n";
        }
      }
      for (const auto& r : reaches) {  // a direction this version does not know
        if (r.phase == phase && std::find_if(std::begin(kDirections), std::end(kDirections),
                                             [&](const char* d) { return r.direction == d; }) ==
                                    std::end(kDirections)) {
          row(r);
        }
      }
    }
  }
  // A lesson run: its lesson and its scored trials (docs/lessons.md).
  if (const uint64_t lesson = store.sessionLesson(session_id)) {
    const auto trials = store.trials(session_id);
    std::cout << "lesson " << lesson << ": " << trials.size() << " trials scored"
              << (trials.empty() ? "\n" : ":\n");
    for (const auto& t : trials) {
      std::cout << "  trial " << t.index << "  " << std::left << std::setw(8) << t.phase
                << std::right << std::fixed << std::setprecision(2) << " authority " << t.authority
                << "  samples " << t.first_seq << ".." << t.last_seq << "  overall "
                << std::setprecision(1) << t.overall << "\n";
    }
  }
  return 0;
}

int runExport(SessionStore& store, uint64_t session_id, const std::string& out_path) {
  // A file is written beside its destination and renamed over it only when complete: an
  // error half way (a full disk, a read error in the record) leaves no partial CSV behind.
  // Something that is not a regular file (a pipe, a terminal, a device) is written directly.
  std::error_code kind_ec;
  const bool special = !out_path.empty() && std::filesystem::exists(out_path, kind_ec) &&
                       !std::filesystem::is_regular_file(out_path, kind_ec);
  const std::string tmp_path = out_path.empty() || special ? "" : out_path + ".partial";
  std::ofstream file;
  if (!out_path.empty()) {
    const std::string& open_path = special ? out_path : tmp_path;
    file.open(open_path, std::ios::trunc);
    if (!file) {
      std::cerr << "telehand-records: cannot write '" << open_path << "'\n";
      return 2;
    }
  }
  std::ostream& out = out_path.empty() ? std::cout : file;
  const auto fail = [&](const std::string& why) {
    std::cerr << "telehand-records: " << why << "\n";
    if (!tmp_path.empty()) {
      file.close();
      std::error_code ec;
      std::filesystem::remove(tmp_path, ec);
    }
    return 2;
  };
  const auto& cols = sampleColumns();
  for (std::size_t i = 0; i < cols.size(); ++i) out << (i ? "," : "") << cols[i];
  out << "\n";
  uint64_t rows = 0;
  try {
    store.forEachSample(session_id, [&](const telehand::Sample& s, bool valid) {
      out << sampleCsvRow(s, valid) << "\n";
      ++rows;
    });
  } catch (const std::exception& e) {
    return fail(
        std::string(e.what()) + " (after " + std::to_string(rows) + " rows" +
        (tmp_path.empty() ? std::string(")") : "; nothing was written to '" + out_path + "')"));
  }
  out.flush();
  if (!out) {
    return fail("write failed after " + std::to_string(rows) + " rows" +
                (tmp_path.empty() ? "" : "; nothing was written to '" + out_path + "'"));
  }
  if (!tmp_path.empty()) {
    // The last buffered bytes reach the file only now: a close that fails (a full disk, a
    // quota) leaves it short.
    file.close();
    if (file.fail()) {
      return fail("closing '" + tmp_path + "' failed after " + std::to_string(rows) +
                  " rows; nothing was written to '" + out_path + "'");
    }
    std::error_code ec;
    std::filesystem::rename(tmp_path, out_path, ec);
    if (ec) return fail("cannot rename '" + tmp_path + "' to '" + out_path + "': " + ec.message());
  }
  if (!out_path.empty()) {
    std::cerr << "exported session " << session_id << ": " << rows << " samples to " << out_path
              << "\n";
  }
  return 0;
}

}  // namespace telehand::records
