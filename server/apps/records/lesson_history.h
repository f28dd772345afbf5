#pragma once
// What telehand-records reads from the record about lesson runs: a lesson's runs, and a
// student's learning curve over their earlier runs (the report's history).
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "telehand/server/store/store.h"

namespace telehand::records {

/// Sessions that ran `lesson_id`, oldest first.
std::vector<server::store::SessionInfo> runsOf(server::store::SessionStore& store,
                                               uint64_t lesson_id);

/// The mean overall score of a run's trials (0 without any).
double meanOverall(const std::vector<server::store::TrialRecord>& trials);

/// The learning curve before `session`: `user`'s lesson runs (of any lesson) with scored
/// trials whose id is below it, oldest first, as ("session ID", mean overall score). The run
/// `session` itself is not in it (the report adds it as "this lesson", scored again).
std::vector<std::pair<std::string, double>> learningHistory(server::store::SessionStore& store,
                                                            const std::string& user,
                                                            uint64_t session);

}  // namespace telehand::records
