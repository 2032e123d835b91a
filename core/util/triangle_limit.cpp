#include "core/util/triangle_limit.h"

#include <algorithm>
#include <limits>

#include "core/util/errors.h"
#include "core/util/run_control.h"

namespace surfacer {

TriangleCounter::TriangleCounter(const RunControl& control, const char* what, const char* fix)
    : limit_(control.triangles), what_(what), fix_(fix) {
  if (limit_ && limit_->reserve) {
    const std::int64_t first = std::min(kMinChunk, limit_->max_triangles);
    limit_->reserve(first);
    covered_.store(first, std::memory_order_relaxed);
  }
}

void TriangleCounter::over() const {
  throw ResourceLimit(limit_->name, std::string(what_) + " stopped at " + std::to_string(count()) +
                                        " triangles, over the limit of " + std::to_string(limit_->max_triangles) +
                                        " triangles per mesh (" + limit_->name + "); " + fix_ + ", or raise " +
                                        limit_->name);
}

void TriangleCounter::add(std::int64_t n) {
  if (limit_ == nullptr || n <= 0) return;
  const std::int64_t total = count_.fetch_add(n, std::memory_order_relaxed) + n;
  if (total > limit_->max_triangles) over();
  if (!limit_->reserve || total <= covered_.load(std::memory_order_acquire)) return;
  std::lock_guard lock(mutex_);
  const std::int64_t covered = covered_.load(std::memory_order_relaxed);
  if (total <= covered) return;
  const std::int64_t next = std::min(limit_->max_triangles, std::max(total, covered) + std::max(kMinChunk, total / 8));
  limit_->reserve(next);
  covered_.store(next, std::memory_order_release);
}

std::int64_t max_triangles(const RunControl& control) {
  return control.triangles ? control.triangles->max_triangles : std::numeric_limits<std::int64_t>::max();
}

void reserve_triangles(const RunControl& control, std::int64_t triangles, std::int64_t& covered) {
  if (control.triangles == nullptr || !control.triangles->reserve || triangles <= covered) return;
  control.triangles->reserve(triangles);
  covered = triangles;
}

}  // namespace surfacer
