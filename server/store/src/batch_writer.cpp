#include "telehand/server/store/batch_writer.h"

#include <exception>
#include <utility>

#include "telehand/core/clock.h"

namespace telehand::server::store {

BatchWriter::BatchWriter(std::unique_ptr<SessionStore> connection)
    : store_(std::move(connection)), thread_([this](std::stop_token st) { run(st); }) {}

BatchWriter::~BatchWriter() {
  thread_.request_stop();
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void BatchWriter::submit(std::vector<Job>& jobs) {
  {
    std::lock_guard lock(mutex_);
    jobs_.swap(jobs);
    work_ = true;
    results_ = false;
    busy_.store(true, std::memory_order_release);
  }
  for (auto& j : jobs) {  // the earlier write's, back to the caller emptied
    j.samples.clear();
    j.valid.clear();
  }
  cv_.notify_all();
}

bool BatchWriter::collect(std::vector<Job>& out) {
  if (busy()) return false;
  std::lock_guard lock(mutex_);
  if (!results_) return false;
  results_ = false;
  out.swap(jobs_);
  return !out.empty();
}

void BatchWriter::wait() {
  std::unique_lock lock(mutex_);
  cv_.wait(lock, [this] { return !work_; });
}

void BatchWriter::releaseMemory() {
  const std::lock_guard lock(mutex_);
  if (work_ || results_) return;
  jobs_ = {};
  batches_ = {};
  store_->releaseMemory();  // not busy: the writer thread does not touch it
}

void BatchWriter::run(std::stop_token stop) {
  std::unique_lock lock(mutex_);
  for (;;) {
    cv_.wait(lock, stop, [this] { return work_; });
    if (!work_) return;  // stopped with nothing to write
    // The jobs are this thread's until work_ is cleared: the loop only looks at busy().
    lock.unlock();
    batches_.clear();
    for (const Job& j : jobs_) batches_.push_back({j.session_id, j.samples, j.valid});
    const int64_t t0 = SteadyClock{}.nowNs();
    std::vector<SessionStore::BatchResult> results;
    try {
      results = store_->appendSampleBatches(batches_);
    } catch (const std::exception& e) {
      results.assign(jobs_.size(), {false, 0, e.what()});
    }
    write_ns_.fetch_add(SteadyClock{}.nowNs() - t0, std::memory_order_relaxed);
    for (std::size_t i = 0; i < jobs_.size(); ++i) {
      jobs_[i].result = i < results.size()
                            ? std::move(results[i])
                            : SessionStore::BatchResult{false, 0, "no result from the store"};
    }
    lock.lock();
    work_ = false;
    results_ = true;
    busy_.store(false, std::memory_order_release);
    cv_.notify_all();
    if (stop.stop_requested()) return;
  }
}

}  // namespace telehand::server::store
