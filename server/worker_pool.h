// A fixed pool of worker threads running posted tasks in FIFO order. Jobs and their frames run here, never on
// gRPC threads.
#pragma once

#include <condition_variable>
#include <deque>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace surfacer::server {

class WorkerPool {
 public:
  explicit WorkerPool(int threads);  // threads >= 1
  ~WorkerPool();                     // runs the queue dry, then joins

  WorkerPool(const WorkerPool&) = delete;
  WorkerPool& operator=(const WorkerPool&) = delete;

  // Tasks must not throw (wrap them); a task posted after stop() is dropped.
  void post(std::function<void()> task);
  int threads() const { return static_cast<int>(threads_.size()); }
  // Lets the queued tasks finish, then joins the threads.
  void stop();

 private:
  void run();

  std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<std::function<void()>> queue_;
  bool stopping_ = false;
  std::vector<std::thread> threads_;
};

}  // namespace surfacer::server
