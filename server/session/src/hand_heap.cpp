#include "telehand/server/session/hand_heap.h"

#include <pthread.h>

#include <condition_variable>
#include <exception>
#include <mutex>
#include <thread>
#include <utility>

namespace telehand::server::session {

namespace {
/// One thread, one job at a time; the caller waits for it.
class HandHeap {
 public:
  HandHeap() : thread_([this] { run(); }) {}
  ~HandHeap() {
    {
      const std::lock_guard lock(m_);
      stop_ = true;
    }
    cv_.notify_all();
    thread_.join();
  }

  void call(const std::function<void()>& job) {
    const std::lock_guard serial(callers_);
    std::unique_lock lock(m_);
    job_ = &job;
    done_ = false;
    cv_.notify_all();
    cv_.wait(lock, [&] { return done_; });
    job_ = nullptr;
    if (error_) std::rethrow_exception(std::exchange(error_, nullptr));
  }

 private:
  void run() {
    pthread_setname_np(pthread_self(), "telehand-hands");
    std::unique_lock lock(m_);
    for (;;) {
      cv_.wait(lock, [&] { return stop_ || (job_ != nullptr && !done_); });
      if (stop_) return;
      try {
        (*job_)();
      } catch (...) {
        error_ = std::current_exception();
      }
      done_ = true;
      cv_.notify_all();
    }
  }

  std::mutex callers_;  // one call at a time
  std::mutex m_;
  std::condition_variable cv_;
  const std::function<void()>* job_ = nullptr;
  bool done_ = false;
  bool stop_ = false;
  std::exception_ptr error_;
  std::thread thread_;  // last: starts once the members above exist
};
}  // namespace

void onHandHeap(const std::function<void()>& job) {
  static HandHeap heap;
  heap.call(job);
}

}  // namespace telehand::server::session
