// A bound on the triangles a mesh may reach while a stage builds it (a server's --max-triangles) and a hook that
// reserves the memory of those triangles before they are built (a server's --memory-budget). RunControl carries it
// (RunControl::triangles), so every stage that builds or grows a mesh obeys it as it goes: the polygonizers (and so
// the isosurface, particle and active surface jobs and the optimizer's start mesh) count triangles as they produce
// them, the optimizer's subdivision never builds a round past it; none first builds the whole mesh and then counts.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>

namespace surfacer {

struct RunControl;

struct TriangleLimit {
  // Most triangles one mesh may hold (> 0).
  std::int64_t max_triangles = std::int64_t{1} << 40;
  // What raises max_triangles, named in the error ("--max-triangles").
  std::string name = "max_triangles";
  // Called before a mesh grows past the triangles covered so far, with the count it must now cover (<=
  // max_triangles, larger than in any earlier call on the same counter); throws to refuse (the server: its memory
  // budget has no room), and the error leaves the stage unchanged. Calls are serialized. Empty: nothing to reserve.
  std::function<void(std::int64_t triangles)> reserve;
};

// The triangles of one mesh under construction, counted from any thread against control.triangles (no bound when
// that is null). Reservations grow in chunks (at least kMinChunk triangles, and 1/8 of the count so far), so the
// hook runs O(log n) times and adding is one atomic add in between.
class TriangleCounter {
 public:
  static constexpr std::int64_t kMinChunk = std::int64_t{1} << 12;

  // `what` names the stage in the error ("marching cubes"); `fix` says how to need fewer triangles ("use fewer
  // cells"). Both must outlive the counter.
  TriangleCounter(const RunControl& control, const char* what, const char* fix);

  // Adds n >= 0 triangles produced. Throws ResourceLimit(limit.name) once the count passes max_triangles, naming
  // the count reached, the limit and the fix (every later call throws too), and what the reserve hook throws.
  // Thread-safe.
  void add(std::int64_t n);
  std::int64_t count() const { return count_.load(std::memory_order_relaxed); }

 private:
  [[noreturn]] void over() const;
  const TriangleLimit* limit_;
  const char* what_;
  const char* fix_;
  std::atomic<std::int64_t> count_{0};
  std::atomic<std::int64_t> covered_{0};  // triangles the hook has reserved for
  std::mutex mutex_;                      // serializes the hook
};

// The most triangles a mesh built under `control` may hold (TriangleLimit::max_triangles; INT64_MAX without one).
std::int64_t max_triangles(const RunControl& control);

// For a stage that knows a mesh's next size before building it (the optimizer's refinement): has control's hook
// cover `triangles` (<= max_triangles(control)) when more than it covered before through this call; `covered` keeps
// what was covered (start at 0). Throws what the hook throws.
void reserve_triangles(const RunControl& control, std::int64_t triangles, std::int64_t& covered);

}  // namespace surfacer
