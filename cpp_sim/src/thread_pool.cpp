#include "thread_pool.h"

#include <unistd.h>

namespace softrom {

ThreadPool& ThreadPool::instance() {
  static ThreadPool* pool = nullptr;
  static pid_t owner = 0;
  static std::mutex guard;
  std::lock_guard<std::mutex> lock(guard);
  const pid_t pid = getpid();
  if (pool == nullptr || owner != pid) {
    // After fork() the parent's workers do not exist in the child: abandon (leak) that copy
    // rather than join threads that are not there.
    pool = new ThreadPool();
    owner = pid;
  }
  return *pool;
}

ThreadPool::~ThreadPool() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  wake_.notify_all();
  for (auto& t : workers_)
    if (t.joinable()) t.join();
}

void ThreadPool::grow(int workers) {
  while (static_cast<int>(workers_.size()) < workers) {
    const int id = static_cast<int>(workers_.size());
    workers_.emplace_back([this, id] {
      long seen = 0;
      for (;;) {
        const std::function<void(int)>* job;
        {
          std::unique_lock<std::mutex> lock(mutex_);
          wake_.wait(lock, [&] { return stop_ || (generation_ != seen && id < job_workers_); });
          if (stop_) return;
          seen = generation_;
          job = job_;
        }
        work(*job);
        {
          std::lock_guard<std::mutex> lock(mutex_);
          if (--running_ == 0) done_.notify_all();
        }
      }
    });
  }
}

void ThreadPool::work(const std::function<void(int)>& fn) {
  for (int i = next_.fetch_add(1); i < n_; i = next_.fetch_add(1)) {
    try {
      fn(i);
    } catch (...) {
      std::lock_guard<std::mutex> lock(mutex_);
      if (!error_) error_ = std::current_exception();
      next_.store(n_);  // the others stop at their next task
    }
  }
}

namespace {
// True on a thread while it runs a batch: a Python signal handler run by the batch's poll
// (Ctrl-C's check) may start another rollout on the same thread, which would lock
// call_mutex_ a second time and hang for good.
thread_local bool t_in_batch = false;
}  // namespace

void ThreadPool::run(int threads, int n, const std::function<void(int)>& fn,
                     const std::function<void()>* poll) {
  if (t_in_batch) {  // re-entered from this thread's poll: run the nested batch here, serially
    for (int i = 0; i < n; ++i) fn(i);
    return;
  }
  struct InBatch {
    InBatch() { t_in_batch = true; }
    ~InBatch() { t_in_batch = false; }
  } in_batch;
  std::lock_guard<std::mutex> call(call_mutex_);
  const int helpers = std::max(0, std::min(threads, n) - 1);
  int started = helpers;
  try {
    grow(helpers);
  } catch (...) {
    // Fewer threads than asked: those that exist share the batch.
    started = static_cast<int>(workers_.size());
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    job_ = &fn;
    n_ = n;
    next_.store(0);
    error_ = nullptr;
    job_workers_ = started;
    running_ = started;
    ++generation_;
  }
  if (started > 0) wake_.notify_all();
  work(fn);
  {
    std::unique_lock<std::mutex> lock(mutex_);
    const auto finished = [&] { return running_ == 0; };
    if (poll == nullptr) {
      done_.wait(lock, finished);
    } else {
      while (!done_.wait_for(lock, kPollInterval, finished)) {
        // Not under the pool's lock: the poll may wait for the GIL, and workers finishing
        // meanwhile need the lock to say so.
        lock.unlock();
        try {
          (*poll)();
        } catch (...) {
          // As a task's exception: the others stop at their next task and it is rethrown
          // below, once none of them still runs fn (which lives in the caller's frame).
          std::lock_guard<std::mutex> error_lock(mutex_);
          if (!error_) error_ = std::current_exception();
          next_.store(n_);
        }
        lock.lock();
      }
    }
    job_ = nullptr;
  }
  if (error_) std::rethrow_exception(error_);
}

}  // namespace softrom
