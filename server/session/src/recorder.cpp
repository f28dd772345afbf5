#include "telehand/server/session/recorder.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <iterator>
#include <span>

#include "telehand/core/clock.h"
#include "telehand/core/error.h"

namespace telehand::server::session {

bool Recorder::holds(uint64_t seq) const noexcept {
  if (seq < below_) return true;
  auto it = above_.upper_bound(seq);
  return it != above_.begin() && std::prev(it)->second > seq;
}

void Recorder::dropHeld(std::vector<Sample>& samples, std::vector<uint8_t>& valid) const {
  if (below_ == 0 && above_.empty()) return;
  const bool flags = valid.size() == samples.size();
  std::size_t out = 0;
  for (std::size_t i = 0; i < samples.size(); ++i) {
    if (holds(samples[i].seq)) continue;
    if (out != i) {
      samples[out] = samples[i];
      if (flags) valid[out] = valid[i];
    }
    ++out;
  }
  samples.resize(out);
  if (flags) valid.resize(out);
}

void Recorder::append(std::vector<Sample>& to, std::vector<uint8_t>& to_valid,
                      std::vector<Sample>&& samples, std::vector<uint8_t>&& valid) {
  if (samples.empty()) return;
  if (to.empty()) {
    to = std::move(samples);
    to_valid = std::move(valid);
    return;
  }
  if (to_valid.size() != to.size() || valid.size() != samples.size()) {
    // One queue, one flag per sample: a chunk sent without flags counts as all valid.
    if (to_valid.empty() && valid.empty()) {
      // Neither has flags: none needed.
    } else {
      to_valid.resize(to.size(), 1);
      valid.resize(samples.size(), 1);
    }
  }
  to.insert(to.end(), samples.begin(), samples.end());
  to_valid.insert(to_valid.end(), valid.begin(), valid.end());
}

void Recorder::store(SessionContext& ctx, std::vector<Sample>&& samples,
                     std::vector<uint8_t>&& valid) {
  dropHeld(samples, valid);
  append(pending_, pending_valid_, std::move(samples), std::move(valid));
  if (pending_.empty()) return;
  const store::SessionStore::SampleBatch one = batch();
  stored(ctx, ctx.store.appendSampleBatches(std::span(&one, 1)).front());
}

void Recorder::stored(SessionContext& ctx, const store::SessionStore::BatchResult& result) {
  if (!result.stored) {
    refused(ctx, result.error, pending_.size());
    return;
  }
  landed(ctx, pending_, result.added);
  pending_.clear();
  pending_valid_.clear();
}

void Recorder::handOver(std::vector<Sample>& samples, std::vector<uint8_t>& valid) noexcept {
  samples.clear();
  valid.clear();
  samples.swap(pending_);
  valid.swap(pending_valid_);
  writing_ = true;
}

void Recorder::written(SessionContext& ctx, std::vector<Sample>& samples,
                       std::vector<uint8_t>& valid,
                       const store::SessionStore::BatchResult& result) {
  writing_ = false;
  if (result.stored) {
    landed(ctx, samples, result.added);
    return;
  }
  refused(ctx, result.error, samples.size() + pending_.size());
  // Back in front of what came meanwhile (a chunk is a run of sequence numbers; the order
  // only matters to how the acknowledgement grows).
  append(samples, valid, std::move(pending_), std::move(pending_valid_));
  samples.swap(pending_);
  valid.swap(pending_valid_);
  dropHeld(pending_, pending_valid_);
}

void Recorder::landed(SessionContext& ctx, const std::vector<Sample>& samples, uint64_t added) {
  recorded_ += added;
  ctx.stats.recorded_samples += added;
  markStored(samples);
}

void Recorder::refused(SessionContext& ctx, const std::string& why, std::size_t kept) const {
  ++ctx.stats.store_errors;
  spdlog::error("session {}: {} ({} samples kept in memory, retrying)", session_id_, why, kept);
}

void Recorder::add(std::vector<Sample>&& samples, std::vector<uint8_t>&& valid) {
  dropHeld(samples, valid);
  append(pending_, pending_valid_, std::move(samples), std::move(valid));
}

void Recorder::markStored(const std::vector<Sample>& samples) {
  // A chunk is a run of consecutive sequence numbers: one interval per run.
  std::size_t i = 0;
  while (i < samples.size()) {
    uint64_t first = samples[i].seq, end = first + 1;
    while (++i < samples.size() && samples[i].seq == end) ++end;
    if (end <= below_) continue;
    first = std::max(first, below_);
    // Merge with the runs it touches.
    auto it = above_.upper_bound(first);
    if (it != above_.begin() && std::prev(it)->second >= first) --it;
    while (it != above_.end() && it->first <= end) {
      first = std::min(first, it->first);
      end = std::max(end, it->second);
      it = above_.erase(it);
    }
    above_.emplace(first, end);
  }
  while (!above_.empty() && above_.begin()->first <= below_) {
    below_ = std::max(below_, above_.begin()->second);
    above_.erase(above_.begin());
  }
  while (above_.size() > kMaxRuns) above_.erase(std::prev(above_.end()));
}

void Recorder::invalidSample(SessionContext& ctx, uint64_t client_id, const Sample& d,
                             const std::string& field, int64_t now_ns) {
  ++ctx.stats.nonfinite_samples;
  ++nonfinite_;
  if (now_ns - nonfinite_reported_ns_ <= 5 * kNsPerS) return;
  nonfinite_reported_ns_ = now_ns;
  ctx.event(session_id_, client_id, telehand_msg_EVENT_ERROR,
            "DeviceState seq " + std::to_string(d.seq) + " has a " + field +
                "; not used for the hand state (" + std::to_string(nonfinite_) + " so far)",
            now_ns);
}

}  // namespace telehand::server::session
