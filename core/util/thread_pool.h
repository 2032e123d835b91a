// The process-wide pool of threads behind parallel_for (core/util/parallel.h) and the server's jobs
// (server/worker_pool.h posts their tasks here): one set of threads, started on first use and kept for the life of
// the process, so a parallel loop costs a wake-up of idle threads instead of the creation and join of new ones, and a
// loop inside a job is helped by the threads no job holds (docs/ALGORITHMS.md "Threads").
// CHOICE: our own pool, not TBB (libtbb-dev 2021.8). Measured on 2 hardware threads, shared machine, wall seconds,
// two runs each, the same hand-out loop on: threads started per call / this pool / tbb::task_group:
//   20000 calls of 8 items of ~1 us (threads = 2):            2.09-2.11 / 0.24-0.29 / 0.37-0.57
//   200 calls of 8 items, each a nested call of 64 items:     0.89-0.98 / 0.79-0.80 / 0.88-0.91
//   50 calls of 64 chunks of 16k items:                      0.29-0.31 / 0.29-0.30 / 0.28-0.29
// TBB's partitioners do not hand items out in increasing order, so it would only have supplied the threads.
// CHOICE: the server's jobs on this pool, not on a worker pool of their own beside it. Its size is max(--workers,
// hardware threads): --workers tasks run at once, and when fewer run their loops find a helper for every core; the
// separate pools let workers + hardware threads - 1 threads compute. Measured against the separate pools on 2
// hardware threads (--workers 2), shared machine (load average 5-7), new/old:
//   load_bench, 8 clients, 8-10 s against a surfacer-server, 7 pairs: jobs/s 0.82-1.56 (median 0.92: the machine's
//     noise), server CPU per finished job 31.8-32.9 ms against 31.0-33.3 ms; the server's own threads under load 5
//     against 6 (gRPC's threads unchanged);
//   service_bench --section 5 (8 frames at 96 cells, three codecs), 4 pairs: CPU 1.04 (0.88-1.17), wall 1.04
//     (1.02-1.19), peak memory 94 against 107 MiB;
//   service_bench --section 1 (single-frame jobs at 160 cells, four codecs), three calls of 3-4 pairs: CPU 1.00,
//     0.99, 1.05 (0.93-1.14), wall 1.16, 0.91, 0.96 (0.71-1.18), peak memory 630-647 against 756-789 MiB.
#pragma once

#include <functional>
#include <type_traits>

namespace surfacer {

// A callable borrowed for the duration of one call (no allocation, no ownership).
class WorkRef {
 public:
  template <class F>
    requires(!std::is_same_v<std::remove_cv_t<F>, WorkRef>)
  explicit WorkRef(F& f) noexcept : object_(&f), call_([](void* o) noexcept { (*static_cast<F*>(o))(); }) {}
  void operator()() const noexcept { call_(object_); }

 private:
  void* object_;
  void (*call_)(void*) noexcept;
};

// Threads of the pool: hardware threads - 1 (the caller of a loop is the other one; 0 on a single-core machine) until
// reserve_pool_threads or post asks for more.
int pool_threads();

// Grows the pool to at least `threads` threads (it never shrinks); returns pool_threads(). A process that runs its own
// work on the pool (the server's jobs, through post) reserves a thread for each task it runs at once plus the helpers
// their loops should find.
int reserve_pool_threads(int threads);

// Runs work() on the calling thread and, at the same time, on up to `helpers` pool threads that are free now or
// become free while the caller's own work() runs; returns once every work() that started has returned. A helper that
// would start after the caller's work() returned is not started, so the caller never waits for a thread that is busy
// elsewhere, and calls may nest (a work() that calls run_with_helpers again) without deadlock: when no pool thread is
// free, the caller does the work alone. work() must not throw and must return soon once nothing is left to do (every
// call after the first to return finds nothing). Newer calls are served first, so nested loops finish before their
// parents hand out more work. Concurrent threads of the process: at most pool_threads() + the threads that call.
void run_with_helpers(int helpers, WorkRef work);

// Queues task() to run once on a pool thread, in posting order (first in, first out), for long work such as a job's
// task: a free pool thread takes the oldest queued task before it helps a loop, so a task starts as soon as a thread
// is free, and the loops a task runs find the threads that no task holds (run_with_helpers). Nothing waits for a task
// here: the poster keeps its own count if it must. Grows an empty pool to one thread. task() must not throw.
void post(std::function<void()> task);

}  // namespace surfacer
