#include "server/worker_pool.h"

#include <algorithm>
#include <exception>
#include <memory>

namespace surfacer::server {

WorkerPool::WorkerPool(int threads) {
  if (threads < 1) threads = 1;
  threads_.reserve(threads);
  for (int i = 0; i < threads; ++i) threads_.emplace_back([this] { run(); });
}

WorkerPool::~WorkerPool() { stop(); }

void WorkerPool::post(std::function<void()> task) {
  {
    std::lock_guard lock(mutex_);
    if (stopping_) return;
    queue_.push_back(std::move(task));
  }
  cv_.notify_one();
}

void WorkerPool::post_front(std::function<void()> task) {
  {
    std::lock_guard lock(mutex_);
    if (stopping_) return;
    queue_.push_front(std::move(task));
  }
  cv_.notify_one();
}

void WorkerPool::stop() {
  {
    std::lock_guard lock(mutex_);
    if (stopping_ && threads_.empty()) return;
    stopping_ = true;
  }
  cv_.notify_all();
  for (auto& t : threads_) {
    if (t.joinable()) t.join();
  }
  threads_.clear();
}

void WorkerPool::run() {
  for (;;) {
    std::function<void()> task;
    {
      std::unique_lock lock(mutex_);
      cv_.wait(lock, [this] { return stopping_ || !queue_.empty(); });
      if (queue_.empty()) return;  // stopping and drained
      task = std::move(queue_.front());
      queue_.pop_front();
    }
    task();
  }
}

namespace {

// One for_each call, shared by the caller and its helpers (which may outlive the call: they then find no item).
struct ForEach {
  ForEach(int items, const std::function<void(int)>& body) : items(items), body(body) {}
  const int items;
  const std::function<void(int)> body;
  std::mutex mutex;
  std::condition_variable idle;
  int next = 0;
  int running = 0;
  std::exception_ptr error;

  // Runs items until none is left (or one failed).
  void work() {
    for (;;) {
      int item;
      {
        std::lock_guard lock(mutex);
        if (next >= items || error) return;
        item = next++;
        ++running;
      }
      std::exception_ptr failure;
      try {
        body(item);
      } catch (...) {
        failure = std::current_exception();
      }
      std::lock_guard lock(mutex);
      if (failure && !error) error = failure;
      if (--running == 0) idle.notify_all();
    }
  }
};

}  // namespace

void PoolExecutor::for_each(int items, const std::function<void(int)>& body) const {
  if (items <= 0) return;
  const int helpers = std::min(items, pool_.threads()) - 1;
  if (helpers <= 0) {
    for (int i = 0; i < items; ++i) body(i);
    return;
  }
  auto state = std::make_shared<ForEach>(items, body);
  for (int h = 0; h < helpers; ++h) pool_.post_front([state] { state->work(); });
  state->work();
  std::unique_lock lock(state->mutex);
  state->idle.wait(lock, [&] { return state->running == 0; });
  if (state->error) std::rethrow_exception(state->error);
}

}  // namespace surfacer::server
