#include "telehand/server/session/lesson_run.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numeric>

#include "telehand/core/error.h"
#include "telehand/server/lesson/lesson.h"

namespace telehand::server::session {

void LessonRun::begin(const std::string& phase, double authority, uint64_t first_seq) {
  in_trial_ = true;
  current_ = Trial{};
  current_.index = ++begun_;
  current_.phase = phase;
  current_.authority = authority;
  current_.first_seq = first_seq;
}

void LessonRun::end(uint64_t last_seq, int64_t now_ns) {
  if (!in_trial_) return;
  in_trial_ = false;
  if (last_seq < current_.first_seq) {
    // Ended before a sample of it was sent: it took one of the plan's trials, so it is said.
    current_.empty = true;
    current_.last_seq = current_.first_seq;
    current_.deadline_ns = now_ns;
    waiting_.push_back(current_);
    return;
  }
  // A trial is scored over its planned length and a margin at most: a client that never
  // ends one cannot make the server read (and hold) minutes of record at once.
  // Samples are the client loop's ticks: up to LoopConfig::kMaxRateHz (4 kHz) a second.
  const auto span = static_cast<uint64_t>((plan.trial_s + kTrialMarginS) * 4000.0);
  current_.last_seq = std::min(last_seq, current_.first_seq + span - 1);
  current_.cut = current_.last_seq < last_seq;
  current_.deadline_ns = now_ns + kScoreWaitNs;
  waiting_.push_back(current_);
}

void LessonRun::scoreDue(SessionContext& ctx, uint64_t session_id, uint64_t client_id,
                         double force_scale, int64_t now_ns, bool final) {
  for (auto it = waiting_.begin(); it != waiting_.end();) {
    bool due = final || it->empty || now_ns >= it->deadline_ns;
    if (!due && now_ns < it->next_check_ns) {
      ++it;
      continue;
    }
    if (!due) {
      it->next_check_ns = now_ns + kCheckEveryNs;
      // Complete when the record holds every sample of the trial.
      uint64_t n = 0;
      try {
        n = ctx.store.countSamples(session_id, it->first_seq, it->last_seq);
      } catch (const StoreError& e) {
        ++ctx.stats.store_errors;
        spdlog::error("session {}: {}", session_id, e.what());
      }
      due = n == it->last_seq - it->first_seq + 1;
    }
    if (!due) {
      ++it;
      continue;
    }
    score(ctx, session_id, client_id, force_scale, *it, now_ns);
    it = waiting_.erase(it);
  }
}

void LessonRun::score(SessionContext& ctx, uint64_t session_id, uint64_t client_id,
                      double force_scale, const Trial& t, int64_t now_ns) {
  if (t.empty) {
    ctx.event(session_id, client_id, telehand_msg_EVENT_ERROR,
              lesson::trialLabel(t.index, t.phase, t.authority) +
                  " not scored: it ended before a sample of it was sent",
              now_ns);
    return;
  }
  std::vector<Sample> samples;
  samples.reserve(t.last_seq - t.first_seq + 1);
  try {
    ctx.store.forEachSampleIn(session_id, t.first_seq, t.last_seq, [&](const Sample& s, bool ok) {
      if (ok) samples.push_back(s);
    });
  } catch (const StoreError& e) {
    ++ctx.stats.store_errors;
    ctx.event(session_id, client_id, telehand_msg_EVENT_ERROR,
              "trial " + std::to_string(t.index) + " not scored: " + e.what(), now_ns);
    return;
  }
  const uint64_t expected = t.last_seq - t.first_seq + 1;
  const uint64_t missing = expected - std::min<uint64_t>(expected, samples.size());
  const std::string label = lesson::trialLabel(t.index, t.phase, t.authority);
  // The trial's length on its samples' clock (samples are loop ticks, up to 4 kHz).
  const double span_s =
      samples.empty()
          ? 0.0
          : static_cast<double>(samples.back().source_time_ns - samples.front().source_time_ns) *
                1e-9;
  if (samples.size() < 2000) {
    ctx.event(session_id, client_id, telehand_msg_EVENT_ERROR,
              label + " not scored: " + std::to_string(samples.size()) + " of " +
                  std::to_string(expected) + " samples in the record (2 s needed)",
              now_ns);
    return;
  }
  store::TrialRecord rec;
  rec.session_id = session_id;
  rec.index = t.index;
  rec.phase = t.phase;
  rec.authority = t.authority;
  rec.first_seq = t.first_seq;
  rec.last_seq = t.last_seq;
  std::vector<std::string> lines;  // score events: the oscillations first, then the trial
  std::string summary;
  // What the record holds is too short to judge (shorter than the settling and one of the
  // demonstration's periods, or its gaps leave no stretch that long; the scorer's rule,
  // whyNotJudged): not scored, since a 0 would say the student failed a trial the record
  // cannot show.
  auto notJudged = [&](const std::string& why) {
    ctx.event(session_id, client_id, telehand_msg_EVENT_ERROR,
              label + " not scored: " + why + " (" + std::to_string(samples.size()) + " of " +
                  std::to_string(expected) + " samples in the record)",
              now_ns);
  };
  if (massage) {
    const technique::MassageSeries series =
        technique::massageSeriesFromSamples(samples, force_scale);
    const technique::MassageScore sc =
        technique::scoreMassage(series, *massage, web, lesson::kMassageSettleS);
    if (!sc.not_scored.empty()) {
      notJudged(sc.not_scored);
      return;
    }
    rec.overall = sc.overall;
    rec.figures = lesson::encodeMassageScore(sc);
    summary = technique::massageSummaryLine(sc);
  } else {
    const technique::Series series = technique::seriesFromSamples(samples, force_scale);
    const technique::TrialScore sc = technique::score(series, targets, lesson::kSettleS);
    if (!sc.not_scored.empty()) {
      notJudged(sc.not_scored);
      return;
    }
    rec.overall = sc.overall;
    rec.figures = lesson::encodeScore(sc);
    summary = technique::summaryLine(sc);
    int n = 0;
    for (const auto& o : sc.figures.oscillations) {
      if (++n > kMaxOscillationEvents) break;
      lines.push_back(label + " oscillation " + std::to_string(n) + ": " +
                      technique::oscillationLine(o, targets));
    }
  }
  rec.figures += "missing=" + std::to_string(missing) + ";";
  try {
    ctx.store.appendTrial(rec);
  } catch (const StoreError& e) {
    ++ctx.stats.store_errors;
    spdlog::error("session {}: {}", session_id, e.what());
  }
  // Every oscillation, then the trial: scores in the record and on the event topic.
  for (const auto& line : lines) {
    ctx.event(session_id, client_id, telehand_msg_EVENT_SCORE, line, now_ns);
  }
  ctx.event(session_id, client_id, telehand_msg_EVENT_SCORE,
            label + ": " + summary +
                (missing ? " (" + std::to_string(missing) + " samples missing)" : std::string()) +
                (t.cut ? " (its first " + std::to_string(static_cast<long long>(span_s)) + " s)"
                       : std::string()),
            now_ns);
  overall_.push_back(rec.overall);
}

std::string LessonRun::summary() const {
  if (overall_.empty()) return "lesson " + std::to_string(info.id) + ": no trial scored";
  const double mean =
      std::accumulate(overall_.begin(), overall_.end(), 0.0) / static_cast<double>(overall_.size());
  const double best = *std::max_element(overall_.begin(), overall_.end());
  char text[160];
  std::snprintf(text, sizeof text, "lesson %llu: %zu trials scored, overall mean %.0f, best %.0f",
                static_cast<unsigned long long>(info.id), overall_.size(), mean, best);
  return text;
}

}  // namespace telehand::server::session
