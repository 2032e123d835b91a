#include "core/active/sparse_grid.h"

#include <algorithm>

namespace surfacer::sparse {

int SparseBlockGrid::insert(const BlockCoord& c, float fill) {
  const int b = block_count();
  coords_.push_back(c);
  index_.emplace(pack_coord(c[0], c[1], c[2]), b);
  for (auto& d : data_) d.resize(d.size() + kBlockNodes, fill);
  neighbors_.clear();
  return b;
}

void SparseBlockGrid::remove_blocks(const std::vector<char>& remove) {
  int out = 0;
  for (int b = 0; b < block_count(); ++b) {
    if (remove[b]) {
      index_.erase(pack_coord(coords_[b][0], coords_[b][1], coords_[b][2]));
      continue;
    }
    if (out != b) {
      coords_[out] = coords_[b];
      index_[pack_coord(coords_[b][0], coords_[b][1], coords_[b][2])] = out;
      for (auto& d : data_) {
        std::copy_n(d.begin() + static_cast<std::ptrdiff_t>(b) * kBlockNodes, kBlockNodes,
                    d.begin() + static_cast<std::ptrdiff_t>(out) * kBlockNodes);
      }
    }
    ++out;
  }
  coords_.resize(out);
  for (auto& d : data_) d.resize(static_cast<std::size_t>(out) * kBlockNodes);
  neighbors_.clear();
}

void SparseBlockGrid::rebuild_neighbors() {
  neighbors_.assign(coords_.size() * 27, -1);
  for (int b = 0; b < block_count(); ++b) {
    const BlockCoord& c = coords_[b];
    for (int dz = -1; dz <= 1; ++dz) {
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          neighbors_[static_cast<std::size_t>(b) * 27 + neighbor_slot(dx, dy, dz)] =
              find(c[0] + dx, c[1] + dy, c[2] + dz);
        }
      }
    }
  }
}

}  // namespace surfacer::sparse
