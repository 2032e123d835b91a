#include "server/worker_pool.h"

#include <algorithm>
#include <thread>

#include "core/util/thread_pool.h"

namespace surfacer::server {

WorkerPool::WorkerPool(int threads) : threads_(std::max(1, threads)) {
  reserve_pool_threads(std::max(threads_, static_cast<int>(std::thread::hardware_concurrency())));
}

WorkerPool::~WorkerPool() { stop(); }

void WorkerPool::post(std::function<void()> task) {
  {
    std::lock_guard lock(mutex_);
    if (stopping_) return;
    queue_.push_back(std::move(task));
    if (draining_ == threads_) return;  // a running drain() takes it
    ++draining_;
  }
  surfacer::post([this] { drain(); });
}

void WorkerPool::drain() {
  for (;;) {
    std::function<void()> task;
    {
      std::lock_guard lock(mutex_);
      if (queue_.empty()) {
        if (--draining_ == 0) idle_.notify_all();
        return;
      }
      task = std::move(queue_.front());
      queue_.pop_front();
    }
    task();
  }
}

void WorkerPool::stop() {
  std::unique_lock lock(mutex_);
  stopping_ = true;
  idle_.wait(lock, [this] { return draining_ == 0; });
}

}  // namespace surfacer::server
