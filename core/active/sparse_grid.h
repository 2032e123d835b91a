// A sparse grid of 8^3-node blocks addressed through a hash of block coordinates (docs/ALGORITHMS.md §4, "Narrow
// band": a hash of fixed-size blocks, allocated only near the surface, so memory grows with surface area and an
// unbounded domain costs nothing where there is no surface).
//
// Each block holds `channels` float arrays of 512 nodes (x fastest). Blocks are kept in a flat array in insertion
// order; removal compacts the array keeping the relative order, so the block order — and everything computed by
// iterating blocks in order — is deterministic as long as insertions and removals are.
//
// Node (i, j, k) (global integer coordinates) lies in block (i >> 3, j >> 3, k >> 3) at local index
// (i & 7) + 8 (j & 7) + 64 (k & 7). Block coordinates are limited to [-2^20, 2^20).
//
// `gather<G>` copies a block and a G-node apron around it (from the 26 neighbour blocks) into a dense
// (8 + 2G)^3 array, so stencils run on plain strides. Where a neighbour block is missing, its nodes take the sign
// (+1 or -1) of the block's own nearest node: a block is missing only where the potential is saturated.
#pragma once

#include <array>
#include <cstdint>
#include <unordered_map>
#include <vector>

namespace surfacer::sparse {

inline constexpr int kBlockLog2 = 3;
inline constexpr int kBlockSize = 1 << kBlockLog2;          // nodes along each edge of a block
inline constexpr int kBlockMask = kBlockSize - 1;           // g & kBlockMask: a node's local coordinate in its block
inline constexpr int kBlockRows = kBlockSize * kBlockSize;  // rows of kBlockSize nodes along x
inline constexpr int kBlockNodes = kBlockRows * kBlockSize;
inline constexpr int kCoordLimit = 1 << 20;  // block coordinates lie in [-kCoordLimit, kCoordLimit)

using BlockCoord = std::array<int, 3>;

inline constexpr int local_index(int x, int y, int z) { return x + kBlockSize * (y + kBlockSize * z); }
// The local x, y, z of local_index i.
inline constexpr int local_x(int i) { return i & kBlockMask; }
inline constexpr int local_y(int i) { return (i >> kBlockLog2) & kBlockMask; }
inline constexpr int local_z(int i) { return i >> (2 * kBlockLog2); }
// The block holding global node coordinate g (floor division by kBlockSize).
inline constexpr int block_of(std::int64_t g) {
  return static_cast<int>(g >= 0 ? g / kBlockSize : -((-g + kBlockMask) / kBlockSize));
}

inline std::uint64_t pack_coord(int x, int y, int z) {
  const auto u = [](int v) { return static_cast<std::uint64_t>(v + kCoordLimit) & 0x1fffffu; };
  return u(x) | (u(y) << 21) | (u(z) << 42);
}

// Index of the neighbour offset (dx, dy, dz) in {-1, 0, 1}^3 within a 27-entry table; 13 is the block itself.
inline constexpr int neighbor_slot(int dx, int dy, int dz) { return (dx + 1) + 3 * (dy + 1) + 9 * (dz + 1); }

// The side S = kBlockSize + 2G of an apron gathered with G ghost nodes (SparseBlockGrid::gather), and the index in it
// of a block's local node (x, y, z) (x, y, z in [-G, kBlockSize + G)).
template <int G>
constexpr int apron_side() {
  return kBlockSize + 2 * G;
}
template <int G>
constexpr int apron_at(int x, int y, int z) {
  return (x + G) + apron_side<G>() * ((y + G) + apron_side<G>() * (z + G));
}

class SparseBlockGrid {
 public:
  explicit SparseBlockGrid(int channels) : data_(channels) {}

  int channels() const { return static_cast<int>(data_.size()); }
  int block_count() const { return static_cast<int>(coords_.size()); }
  const BlockCoord& coord(int block) const { return coords_[block]; }

  float* data(int block, int channel) { return data_[channel].data() + static_cast<std::size_t>(block) * kBlockNodes; }
  const float* data(int block, int channel) const {
    return data_[channel].data() + static_cast<std::size_t>(block) * kBlockNodes;
  }
  // Appends n channels to every block, filled with `fill` (later insertions fill them like the others).
  void add_channels(int n, float fill) {
    for (int k = 0; k < n; ++k) data_.emplace_back(coords_.size() * kBlockNodes, fill);
  }
  // Swaps two channels of every block in O(1).
  void swap_channels(int a, int b) { data_[a].swap(data_[b]); }

  // Block index or -1.
  int find(int x, int y, int z) const {
    const auto it = index_.find(pack_coord(x, y, z));
    return it == index_.end() ? -1 : it->second;
  }
  // Appends a block with every channel set to `fill`; returns its index. The block must not exist.
  int insert(const BlockCoord& c, float fill);
  // Removes the blocks with remove[b] != 0, keeping the others in order. Invalidates neighbour tables.
  void remove_blocks(const std::vector<char>& remove);
  // Recomputes the 27-entry neighbour tables (call after insertions or removals).
  void rebuild_neighbors();
  // Neighbour block at offset slot (see neighbor_slot), or -1. Valid after rebuild_neighbors().
  int neighbor(int block, int slot) const { return neighbors_[static_cast<std::size_t>(block) * 27 + slot]; }
  bool neighbors_valid() const { return neighbors_.size() == coords_.size() * 27; }

  // Copies channel `channel` of `block` with a G-node apron into out[(x+G) + S ((y+G) + S (z+G))], S = 8 + 2G,
  // for x, y, z in [-G, 8 + G). 1 <= G <= 8. Nodes of missing neighbours get *missing when given, else the sign
  // (+1 / -1) of the block's own nearest node.
  template <int G>
  void gather(int block, int channel, float* out, const float* missing = nullptr) const;

  std::size_t memory_bytes() const {
    std::size_t bytes = coords_.capacity() * sizeof(BlockCoord) + neighbors_.capacity() * sizeof(int);
    for (const auto& d : data_) bytes += d.capacity() * sizeof(float);
    return bytes + index_.size() * (sizeof(std::uint64_t) + sizeof(int) + 2 * sizeof(void*));
  }

 private:
  std::vector<std::vector<float>> data_;  // per channel, block-major
  std::vector<BlockCoord> coords_;
  std::unordered_map<std::uint64_t, int> index_;
  std::vector<int> neighbors_;  // 27 per block
};

template <int G>
void SparseBlockGrid::gather(int block, int channel, float* out, const float* missing) const {
  static_assert(G >= 1 && G <= kBlockSize);
  constexpr int S = kBlockSize + 2 * G;
  const float* self = data(block, channel);
  // Per axis the apron splits into three ranges: [-G, 0) from the -1 neighbour, [0, kBlockSize) own, [kBlockSize,
  // kBlockSize + G) from +1.
  constexpr int lo[3] = {-G, 0, kBlockSize};
  constexpr int len[3] = {G, kBlockSize, G};
  for (int dz = -1; dz <= 1; ++dz) {
    for (int dy = -1; dy <= 1; ++dy) {
      for (int dx = -1; dx <= 1; ++dx) {
        const int nb = neighbor(block, neighbor_slot(dx, dy, dz));
        const float* src = nb >= 0 ? data(nb, channel) : nullptr;
        for (int z = lo[dz + 1]; z < lo[dz + 1] + len[dz + 1]; ++z) {
          for (int y = lo[dy + 1]; y < lo[dy + 1] + len[dy + 1]; ++y) {
            float* row = out + (G + S * ((y + G) + S * (z + G)));
            const int x0 = lo[dx + 1], x1 = x0 + len[dx + 1];
            if (src != nullptr) {
              // Local coordinates inside the neighbour: wrap by the block size.
              const float* srow = src + local_index((x0 + kBlockSize) & kBlockMask, (y + kBlockSize) & kBlockMask,
                                                    (z + kBlockSize) & kBlockMask);
              for (int k = 0; k < x1 - x0; ++k) row[x0 + k] = srow[k];
            } else if (missing != nullptr) {
              for (int x = x0; x < x1; ++x) row[x] = *missing;
            } else {
              const int cy = y < 0 ? 0 : (y > kBlockMask ? kBlockMask : y),
                        cz = z < 0 ? 0 : (z > kBlockMask ? kBlockMask : z);
              const float* own = self + local_index(0, cy, cz);
              for (int x = x0; x < x1; ++x) {
                const int cx = x < 0 ? 0 : (x > kBlockMask ? kBlockMask : x);
                row[x] = own[cx] > 0.0f ? 1.0f : -1.0f;
              }
            }
          }
        }
      }
    }
  }
}

}  // namespace surfacer::sparse
