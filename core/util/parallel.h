// Fork-join helpers for core's data-parallel loops, on one process-wide pool of threads (core/util/thread_pool.h).
#pragma once

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <exception>
#include <memory>
#include <mutex>
#include <numeric>
#include <thread>
#include <type_traits>
#include <utility>
#include <vector>

#include "core/util/thread_pool.h"

namespace surfacer {

// The number of worker threads to use for `requested` (0: std::thread::hardware_concurrency(), at least 1).
inline int resolve_threads(int requested) {
  if (requested > 0) return requested;
  return std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
}

// Runs body(item) for every item in [0, items) on up to min(threads, items) threads: the caller's thread and free
// threads of the process-wide pool (core/util/thread_pool.h); when none is free the caller runs every item itself,
// so calls may nest. Items are handed out in increasing order from a shared counter, so results must be stored per
// item (not appended) for the outcome to be independent of scheduling. The first exception thrown stops the hand-out
// of further items (items already running finish) and is rethrown once every started item has returned.
template <class Body>
void parallel_for(int items, int threads, Body&& body) {
  if (items <= 0) return;
  const int workers = std::clamp(threads, 1, items);
  if (workers == 1) {
    for (int i = 0; i < items; ++i) body(i);
    return;
  }
  std::atomic<int> next{0};
  std::atomic<bool> failed{false};
  std::exception_ptr error;
  std::mutex error_mutex;
  auto work = [&]() noexcept {
    while (!failed.load(std::memory_order_relaxed)) {
      const int i = next.fetch_add(1, std::memory_order_relaxed);
      if (i >= items) return;
      try {
        body(i);
      } catch (...) {
        std::lock_guard lock(error_mutex);
        if (!error) error = std::current_exception();
        failed.store(true, std::memory_order_relaxed);
      }
    }
  };
  run_with_helpers(workers - 1, WorkRef(work));
  if (error) std::rethrow_exception(error);
}

// Items [begin, end) of chunk c when n items are cut into `chunks` contiguous chunks of near-equal size.
inline std::pair<std::size_t, std::size_t> chunk_range(std::size_t n, int chunks, int c) {
  return {n * static_cast<std::size_t>(c) / static_cast<std::size_t>(chunks),
          n * static_cast<std::size_t>(c + 1) / static_cast<std::size_t>(chunks)};
}

// body(begin, end) over [0, n) cut into contiguous chunks (about four per thread, at least ~1024 items each), run by
// parallel_for: the chunks depend on n and threads only.
template <class Body>
void for_chunks(std::size_t n, int threads, Body&& body) {
  const int chunks = static_cast<int>(std::min<std::size_t>(std::max(1, 4 * threads), n / 1024 + 1));
  parallel_for(chunks, threads, [&](int c) {
    const auto [begin, end] = chunk_range(n, chunks, c);
    body(begin, end);
  });
}

// The allocator of Buffer: resize() and the size constructor default-initialize, which leaves trivial elements
// unwritten.
template <class T>
class DefaultInitAllocator : public std::allocator<T> {
 public:
  template <class U>
  struct rebind {
    using other = DefaultInitAllocator<U>;
  };
  DefaultInitAllocator() = default;
  template <class U>
  DefaultInitAllocator(const DefaultInitAllocator<U>&) noexcept {}
  template <class U>
  void construct(U* p) noexcept(std::is_nothrow_default_constructible_v<U>) {
    ::new (static_cast<void*>(p)) U;
  }
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
};

// A vector for large arrays that a parallel loop fills: resizing it does not zero the elements, so their pages are
// first touched (and faulted in) by the threads that write them instead of by one thread's memset, and are written
// once instead of twice. Every element must be written before it is read.
template <class T>
using Buffer = std::vector<T, DefaultInitAllocator<T>>;

// Entries bucketed by row in parallel without atomics (a counting sort). The input is cut into `parts` contiguous
// shares; each share counts its entries per row in an array of its own, place() turns the counts into the rows'
// offsets and each share's write cursors, and each share then writes its entries at its cursors. Within a row, share
// 0's entries come first, then share 1's and so on: input order, whatever the threads. 4 bytes per row and share.
// The caller spreads the steps over its own threads:
//   1. clear() every range of rows;   2. each share: ++count(share)[row] per entry;
//   3. place(offsets, for_blocks);   4. each share: values[cursor(share)[row]++] = value per entry, in the order it
//      counted them.
class RowBuckets {
 public:
  RowBuckets(std::size_t rows, int parts)
      : rows_(rows), parts_(std::max(1, parts)), counts_(rows * static_cast<std::size_t>(std::max(1, parts))) {}
  int parts() const { return parts_; }
  void clear(std::size_t begin, std::size_t end) {
    for (int p = 0; p < parts_; ++p) std::fill(count(p) + begin, count(p) + end, 0u);
  }
  std::uint32_t* count(int part) { return counts_.data() + static_cast<std::size_t>(part) * rows_; }
  // offsets[row] for every row and offsets[rows] (rows + 1 of them), which is returned: the number of entries. The
  // counts become the cursors. for_blocks(n, body) must call body(b) once for every b in [0, n), in any order and on
  // any threads; each b is a block of kBlockRows rows, summed, then (after a prefix sum over the blocks) placed.
  template <class ForBlocks>
  std::uint32_t place(std::uint32_t* offsets, ForBlocks&& for_blocks) {
    const int blocks = static_cast<int>((rows_ + kBlockRows - 1) / kBlockRows);
    auto range = [&](int b) { return std::pair{b * kBlockRows, std::min(rows_, (b + 1) * kBlockRows)}; };
    std::vector<std::uint32_t> first(blocks + 1, 0);  // the entries before each block of rows
    for_blocks(blocks, [&](int b) {
      const auto [begin, end] = range(b);
      std::uint32_t sum = 0;
      for (int p = 0; p < parts_; ++p) sum = std::accumulate(count(p) + begin, count(p) + end, sum);
      first[b + 1] = sum;
    });
    std::partial_sum(first.begin(), first.end(), first.begin());
    for_blocks(blocks, [&](int b) {
      const auto [begin, end] = range(b);
      std::uint32_t next = first[b];
      for (std::size_t row = begin; row < end; ++row) {
        offsets[row] = next;
        for (int p = 0; p < parts_; ++p) next += std::exchange(count(p)[row], next);
      }
    });
    offsets[rows_] = first[blocks];
    return first[blocks];
  }
  std::uint32_t* cursor(int part) { return count(part); }

 private:
  static constexpr std::size_t kBlockRows = 32768;
  std::size_t rows_;
  int parts_;
  Buffer<std::uint32_t> counts_;
};

}  // namespace surfacer
