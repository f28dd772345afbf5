#pragma once
/// A session's record: every sample stored once, what the store refused kept and retried,
/// and the live samples that were not finite counted and reported.
#include <algorithm>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "telehand/core/sample.h"
#include "telehand/server/session/session_context.h"

namespace telehand::server::session {

class Recorder {
 public:
  explicit Recorder(uint64_t session_id) noexcept : session_id_(session_id) {}

  /// Append to the record, after whatever is still pending (kept on a store error).
  void store(SessionContext& ctx, std::vector<Sample>&& samples, std::vector<uint8_t>&& valid);
  /// Queue for the record without storing yet: the chunks a round of the serve loop takes
  /// go to the store together at flush(), one batch per session (one COPY, one transaction)
  /// rather than one per chunk, so that a loop that fell behind catches up in a few writes.
  void add(std::vector<Sample>&& samples, std::vector<uint8_t>&& valid);
  /// Store what was queued, and retry what the store refused before; where a writer thread
  /// stores the samples (ctx.samples_on_writer), nothing: it takes them at the next round.
  void flush(SessionContext& ctx) {
    if (!ctx.samples_on_writer) flushNow(ctx);
  }
  /// Store what is queued now, on the caller's connection (a server stopping), unless a
  /// write of this session's is under way on the writer thread.
  void flushNow(SessionContext& ctx) {
    if (!pending_.empty() && !writing_) store(ctx, {}, {});
  }
  /// What flush() would store, for a write of several sessions' together (valid until the
  /// next add or store); its outcome goes to stored().
  store::SessionStore::SampleBatch batch() const noexcept {
    return {session_id_, pending_, pending_valid_};
  }
  /// The outcome of writing batch(): counted and acknowledged, or kept for the next try.
  void stored(SessionContext& ctx, const store::SessionStore::BatchResult& result);
  /// Hands what is queued to a write on another thread (store::BatchWriter): swapped into
  /// `samples` and `valid`, which come back to written() with the write's outcome. Until
  /// then this session has a write under way and nothing else of it is written.
  void handOver(std::vector<Sample>& samples, std::vector<uint8_t>& valid) noexcept;
  /// The outcome of a handOver's write: counted and acknowledged, or queued again in front
  /// of what came meanwhile, for the next try. `samples`/`valid` are left for reuse.
  void written(SessionContext& ctx, std::vector<Sample>& samples, std::vector<uint8_t>& valid,
               const store::SessionStore::BatchResult& result);
  bool writing() const noexcept { return writing_; }
  bool queued() const noexcept { return !pending_.empty(); }
  /// Nothing queued and no write under way.
  bool drained() const noexcept { return pending_.empty() && !writing_; }
  uint64_t recorded() const noexcept { return recorded_; }
  /// Every sample with seq < this is in the record (what the client may forget,
  /// SessionStatus.stored_below): the stored prefix of the sequence.
  uint64_t storedBelow() const noexcept { return below_; }
  /// A session taken on from the record (docs/recovery.md): what it already holds.
  void resumeFrom(uint64_t recorded, uint64_t stored_below) noexcept {
    recorded_ = recorded;
    below_ = stored_below;
    above_.clear();
  }
  /// What the record holds, counted there: in a pool another server may have stored some
  /// of this session's samples (before it let go of the session), which this recorder did
  /// not count as new.
  void recountFrom(uint64_t in_record) noexcept { recorded_ = std::max(recorded_, in_record); }
  /// Runs of stored sequence numbers beyond the prefix kept at most (a client's stream has a
  /// few; past this the furthest are forgotten, which only delays the acknowledgement).
  static constexpr std::size_t kMaxRuns = 1024;

  /// A live sample no device could have sent (`why`: firstInvalid's description): counted,
  /// reported at most once per 5 s.
  void invalidSample(SessionContext& ctx, uint64_t client_id, const Sample& d,
                     const std::string& why, int64_t now_ns);
  uint64_t nonfinite() const noexcept { return nonfinite_; }

 private:
  uint64_t session_id_;
  uint64_t recorded_ = 0;
  void markStored(const std::vector<Sample>& samples);
  /// `samples` stored, `added` of them new: counted, and acknowledged from now on.
  void landed(SessionContext& ctx, const std::vector<Sample>& samples, uint64_t added);
  void refused(SessionContext& ctx, const std::string& why, std::size_t kept) const;
  /// Appends a chunk to a queue, its validity flags kept one per sample (a chunk without
  /// flags is all valid).
  static void append(std::vector<Sample>& to, std::vector<uint8_t>& to_valid,
                     std::vector<Sample>&& samples, std::vector<uint8_t>&& valid);
  /// True when the record already holds `seq` (stored by this recorder or before it took on).
  bool holds(uint64_t seq) const noexcept;
  /// Leave out what the record already holds: a client sends again what was not acknowledged
  /// in time, and a write that repeats a stored row costs the store far more than a new one
  /// (PostgreSQL's COPY fails on the key, and the rows go again one INSERT at a time).
  void dropHeld(std::vector<Sample>& samples, std::vector<uint8_t>& valid) const;
  uint64_t below_ = 0;                  // every seq < below_ is stored
  std::map<uint64_t, uint64_t> above_;  // stored runs beyond it: first seq -> one past the last
  std::vector<Sample> pending_;         // not yet stored (store error): retried
  std::vector<uint8_t> pending_valid_;
  bool writing_ = false;  // handed over to the writer thread, not yet written()
  uint64_t nonfinite_ = 0;
  int64_t nonfinite_reported_ns_ = INT64_MIN / 2;
};

}  // namespace telehand::server::session
