// Giving memory back between the stages of a long computation: a container's storage released (`v = {}` and clear()
// keep a vector's capacity), and the free pages the C allocator holds returned to the system.
#pragma once

namespace surfacer {

// Frees `container`'s storage: afterwards it is empty with no capacity.
template <class Container>
void release(Container& container) {
  Container().swap(container);
}

// Returns to the system the whole free pages the C allocator keeps in its heaps (glibc: malloc_trim), e.g. after a
// stage freed many small blocks that later large arrays, mapped on their own, would not reuse. A no-op where the
// allocator has no such call. Thread-safe; costs about one pass over the heaps' free lists.
void return_free_memory();

}  // namespace surfacer
