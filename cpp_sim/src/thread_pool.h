// A persistent thread pool for batched rollouts: workers are started once and reused, each
// task index is run start to finish by one worker, and the caller takes part as worker 0.
// (MuJoCo's rollout keeps its pool the same way, so that a replan does not pay for thread
// creation.) The pool is rebuilt in a child process after fork(), whose copy of the workers
// does not exist.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <exception>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace softrom {

class ThreadPool {
 public:
  // The process-wide pool (created on first use, and anew in a forked child).
  static ThreadPool& instance();

  // Runs fn(task) for every task in [0, n) on up to `threads` threads (the caller included)
  // and returns when all are done. The first exception a task throws is rethrown here after
  // the others have stopped taking tasks. Calls from several threads are serialised; a call
  // made from within `poll` on the calling thread (a signal handler) runs its tasks there.
  // `poll`, when given, is called on the calling thread about every kPollInterval while it
  // waits for the other workers to finish (it may tell the tasks to stop: Ctrl-C).
  void run(int threads, int n, const std::function<void(int)>& fn,
           const std::function<void()>* poll = nullptr);

  static constexpr std::chrono::milliseconds kPollInterval{100};

  ~ThreadPool();

 private:
  ThreadPool() = default;
  void grow(int workers);
  void work(const std::function<void(int)>& fn);

  std::mutex call_mutex_;  // one batch at a time
  std::mutex mutex_;
  std::condition_variable wake_, done_;
  std::vector<std::thread> workers_;
  const std::function<void(int)>* job_ = nullptr;
  int job_workers_ = 0;     // workers (besides the caller) taking part in the current job
  long generation_ = 0;
  int running_ = 0;
  bool stop_ = false;
  int n_ = 0;
  std::atomic<int> next_{0};
  std::exception_ptr error_;
};

}  // namespace softrom
