// The server's job queue: tasks posted here run in FIFO order, at most threads() at once, on the process-wide pool
// of core/util/thread_pool.h, which also runs the loops of the engines (parallel_for): one set of threads for jobs
// and their loops. Jobs and their frames run there, never on gRPC threads.
#pragma once

#include <condition_variable>
#include <deque>
#include <functional>
#include <mutex>

namespace surfacer::server {

class WorkerPool {
 public:
  // threads >= 1 (less is taken as 1): tasks that run at once. Grows the process-wide pool to max(threads, hardware
  // threads), so that threads() tasks run at once and, when fewer run, their loops find helpers for every core.
  explicit WorkerPool(int threads);
  ~WorkerPool();  // runs the queue dry, then returns

  WorkerPool(const WorkerPool&) = delete;
  WorkerPool& operator=(const WorkerPool&) = delete;

  // Tasks must not throw (wrap them); a task posted after stop() is dropped.
  void post(std::function<void()> task);
  int threads() const { return threads_; }
  // Lets the queued tasks finish, then returns once none runs. Must not be called from a task.
  void stop();

 private:
  // Runs queued tasks on a pool thread until the queue is empty.
  void drain();

  const int threads_;
  std::mutex mutex_;
  std::condition_variable idle_;  // signalled when the last drain returns
  std::deque<std::function<void()>> queue_;
  int draining_ = 0;  // drain() calls posted to the pool and not returned, at most threads_
  bool stopping_ = false;
};

}  // namespace surfacer::server
