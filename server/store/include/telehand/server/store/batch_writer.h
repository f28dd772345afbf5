#pragma once
/// Sample batches written on a thread and a store connection of their own: a serve loop hands
/// over what a round took and goes on, so that a slow record (PostgreSQL shared by a pool on a
/// busy machine) delays the acknowledgements, not the loop's claims, resumes and leases.
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "telehand/core/sample.h"
#include "telehand/server/store/store.h"

namespace telehand::server::store {

class BatchWriter {
 public:
  /// One session's samples, owned by the write while it is under way, and its outcome.
  struct Job {
    uint64_t session_id = 0;
    std::vector<Sample> samples;
    std::vector<uint8_t> valid;
    SessionStore::BatchResult result;
  };

  /// `connection`: a store used by this writer's thread alone (SessionStore::openWriter).
  explicit BatchWriter(std::unique_ptr<SessionStore> connection);
  /// Finishes the write under way; its results are dropped (what is stored stays stored).
  ~BatchWriter();
  BatchWriter(const BatchWriter&) = delete;
  BatchWriter& operator=(const BatchWriter&) = delete;

  /// True while a write is under way: submit() must wait for it, collect() gives nothing.
  bool busy() const noexcept { return busy_.load(std::memory_order_acquire); }
  /// Starts writing `jobs` (all in one appendSampleBatches). Swapped: `jobs` comes back with
  /// the emptied vectors of an earlier write, for reuse. Not while busy().
  void submit(std::vector<Job>& jobs);
  /// When not busy: the last write's jobs with their results, swapped into `out` (true when
  /// there were any). Each write's jobs are collected once.
  bool collect(std::vector<Job>& out);
  /// Blocks until no write is under way.
  void wait();
  /// When not busy and no results wait to be collected: frees the jobs' sample buffers kept
  /// for reuse (sized by the busiest write) and the connection's cache
  /// (SessionStore::releaseMemory). For a server with no session left.
  void releaseMemory();
  /// Wall time the writes took since the last call, ns.
  int64_t takeWriteNs() noexcept { return write_ns_.exchange(0, std::memory_order_relaxed); }

 private:
  void run(std::stop_token stop);

  std::unique_ptr<SessionStore> store_;
  std::mutex mutex_;
  std::condition_variable_any cv_;
  std::vector<Job> jobs_;                           // the write under way, then its results
  std::vector<SessionStore::SampleBatch> batches_;  // views of jobs_ (the writer thread's)
  bool work_ = false;     // jobs_ submitted, not yet written (under mutex_)
  bool results_ = false;  // jobs_ written, not yet collected (under mutex_)
  std::atomic<bool> busy_{false};
  std::atomic<int64_t> write_ns_{0};
  std::jthread thread_;  // last: started once the members above are
};

}  // namespace telehand::server::store
