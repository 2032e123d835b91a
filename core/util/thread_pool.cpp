#include "core/util/thread_pool.h"

#include <algorithm>
#include <atomic>
#include <condition_variable>
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
  explicit Pool(int threads) {
    threads_.reserve(threads);
    for (int t = 0; t < threads; ++t) threads_.emplace_back([this] { serve(); });
  }
  int threads() const { return static_cast<int>(threads_.size()); }

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
      {
        std::unique_lock lock(mutex_);
        ++idle_;
        cv_.wait(lock, [this] { return !open_.empty(); });
        --idle_;
        call = open_.back();  // the newest call: an inner loop before the outer loop's next items
        call->active.fetch_add(1, std::memory_order_relaxed);
        if (--call->wanted == 0) open_.pop_back();
      }
      call->work();
      if (call->active.fetch_sub(1, std::memory_order_acq_rel) == 1) call->active.notify_all();
    }
  }

  std::mutex mutex_;
  std::condition_variable cv_;
  std::vector<std::shared_ptr<Call>> open_;  // calls that still want helpers, oldest first
  int idle_ = 0;                              // pool threads waiting for a call
  std::vector<std::thread> threads_;
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

void run_with_helpers(int helpers, WorkRef work) { pool().run(helpers, work); }

}  // namespace surfacer
