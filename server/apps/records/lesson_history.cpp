#include "lesson_history.h"

namespace telehand::records {

using namespace server::store;

std::vector<SessionInfo> runsOf(SessionStore& store, uint64_t lesson_id) {
  std::vector<SessionInfo> out;
  for (const auto& s : store.listSessions()) {
    if (s.mode == "lesson" && store.sessionLesson(s.id) == lesson_id) out.push_back(s);
  }
  return out;
}

double meanOverall(const std::vector<TrialRecord>& trials) {
  if (trials.empty()) return 0.0;
  double sum = 0.0;
  for (const auto& t : trials) sum += t.overall;
  return sum / static_cast<double>(trials.size());
}

std::vector<std::pair<std::string, double>> learningHistory(SessionStore& store,
                                                            const std::string& user,
                                                            uint64_t session) {
  std::vector<std::pair<std::string, double>> out;
  for (const auto& s : store.listSessions()) {  // by id: oldest first
    if (s.mode != "lesson" || s.user != user || s.id >= session) continue;
    const auto trials = store.trials(s.id);
    if (trials.empty()) continue;
    out.emplace_back("session " + std::to_string(s.id), meanOverall(trials));
  }
  return out;
}

}  // namespace telehand::records
