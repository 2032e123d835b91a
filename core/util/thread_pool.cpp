#include "core/util/thread_pool.h"

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

namespace surfacer {
namespace {

// One run_with_helpers call, shared by the caller and the helpers that joined it. A helper holds it by shared_ptr,
// so its last touch (the notify after leaving) is safe after the caller has returned.
struct Call {
  Call(WorkRef work, int wanted) : work(work), wanted(wanted) {}
  const WorkRef work;        // called only by helpers that joined while the call was open
  int wanted;                // helpers still wanted; guarded by Pool::mutex_
  std::atomic<int> active{0};  // helpers that joined and have not left
};

class Pool {
 public:
  explicit Pool(int threads) { reserve(threads); }
  int threads() const { return thread_count_.load(std::memory_order_relaxed); }

  int reserve(int threads) {
    std::lock_guard lock(mutex_);
    while (static_cast<int>(threads_.size()) < threads) threads_.emplace_back([this] { serve(); });
    thread_count_.store(static_cast<int>(threads_.size()), std::memory_order_relaxed);
    return static_cast<int>(threads_.size());
  }

  void post(std::function<void()> task) {
    if (threads() == 0) reserve(1);
    {
      std::lock_guard lock(mutex_);
      tasks_.push_back(std::move(task));
    }
    cv_.notify_one();
  }

  void run(int helpers, WorkRef work) {
    helpers = std::min(helpers, threads());
    if (helpers <= 0) {
      work();
      return;
    }
    auto call = std::make_shared<Call>(work, helpers);
    int wake;
    {
      std::lock_guard lock(mutex_);
      open_.push_back(call);
      wake = std::min(helpers, idle_);
    }
    for (int w = 0; w < wake; ++w) cv_.notify_one();
    work();
    {
      std::lock_guard lock(mutex_);  // closes the call: no helper joins after this
      if (call->wanted > 0) std::erase(open_, call);
    }
    for (int n = call->active.load(std::memory_order_acquire); n != 0;
         n = call->active.load(std::memory_order_acquire)) {
      call->active.wait(n, std::memory_order_acquire);
    }
  }

 private:
  void serve() {
    for (;;) {
      std::shared_ptr<Call> call;
      std::function<void()> task;
      {
        std::unique_lock lock(mutex_);
        ++idle_;
        cv_.wait(lock, [this] { return !tasks_.empty() || !open_.empty(); });
        --idle_;
        if (!tasks_.empty()) {  // the oldest task first: it may start a job's loops, which the others then help
          task = std::move(tasks_.front());
          tasks_.pop_front();
        } else {
          call = open_.back();  // the newest call: an inner loop before the outer loop's next items
          call->active.fetch_add(1, std::memory_order_relaxed);
          if (--call->wanted == 0) open_.pop_back();
        }
      }
      if (task) {
        task();
        continue;
      }
      call->work();
      if (call->active.fetch_sub(1, std::memory_order_acq_rel) == 1) call->active.notify_all();
    }
  }

  std::mutex mutex_;
  std::condition_variable cv_;
  std::vector<std::shared_ptr<Call>> open_;  // calls that still want helpers, oldest first
  std::deque<std::function<void()>> tasks_;  // posted tasks not yet started, oldest first
  int idle_ = 0;                             // pool threads waiting for a call or a task
  std::vector<std::thread> threads_;         // grows only, under mutex_
  std::atomic<int> thread_count_{0};         // threads_.size(), read without the lock
};

// Never destroyed: its threads wait for work until the process exits, and a loop running on a detached thread at
// exit still finds the pool.
Pool& pool() {
  static Pool* const instance =
      new Pool(std::max(0, static_cast<int>(std::thread::hardware_concurrency()) - 1));
  return *instance;
}

}  // namespace

int pool_threads() { return pool().threads(); }

int reserve_pool_threads(int threads) { return pool().reserve(threads); }

void run_with_helpers(int helpers, WorkRef work) { pool().run(helpers, work); }

void post(std::function<void()> task) { pool().post(std::move(task)); }

}  // namespace surfacer
