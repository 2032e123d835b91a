// Cancellation and progress for long loops (STYLE.md 5). Every long loop in core calls
// `control.check()` often enough that a cancel takes effect within ~50 ms.
#pragma once

#include <atomic>
#include <functional>
#include <string_view>

#include "core/util/errors.h"

namespace surfacer {

struct TriangleLimit;  // core/util/triangle_limit.h

class CancelToken {
 public:
  void cancel() { flag_.store(true, std::memory_order_relaxed); }
  bool cancelled() const { return flag_.load(std::memory_order_relaxed); }

 private:
  std::atomic<bool> flag_{false};
};

// stage: short name ("polygonize", "smooth"); fraction: 0..1 within that stage. Called from worker threads;
// must be cheap and thread-safe.
using ProgressFn = std::function<void(std::string_view stage, double fraction)>;

struct RunControl {
  const CancelToken* cancel = nullptr;
  ProgressFn progress;
  // The most triangles a mesh built under this control may hold, and the hook reserving their memory
  // (core/util/triangle_limit.h); null: no bound. Must outlive the calls it is passed to.
  const TriangleLimit* triangles = nullptr;

  bool cancelled() const { return cancel != nullptr && cancel->cancelled(); }
  // Throws Error(kCancelled) when the token fired.
  void check() const {
    if (cancelled()) throw Cancelled();
  }
  void report(std::string_view stage, double fraction) const {
    if (progress) progress(stage, fraction);
  }
};

}  // namespace surfacer
