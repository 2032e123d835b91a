// The cut is by triangle index alone, so the pieces, and every byte encoded from them, are the same whatever the
// number of threads. Local vertex numbers follow first use in the piece (a window over the vertex ids the piece
// touches, or a sort when the ids are scattered). A vertex is shared when two pieces claim it (a compare-and-swap on
// its owner); shared vertices on the same grid point are ranked by mesh index, which makes the tags deterministic.
#include "core/mesh/mesh_pieces.h"

#include <algorithm>
#include <atomic>
#include <limits>
#include <memory>
#include <numeric>
#include <string>

#include "core/util/errors.h"

namespace surfacer {
namespace {

constexpr std::uint32_t kUnset = std::numeric_limits<std::uint32_t>::max();

bool repeated(const Triangle& t) { return t[0] == t[1] || t[1] == t[2] || t[0] == t[2]; }

bool operator<(const std::array<std::uint32_t, 3>& a, const std::array<std::uint32_t, 3>& b) {
  return std::lexicographical_compare(a.begin(), a.end(), b.begin(), b.end());
}

}  // namespace

MeshPieces::MeshPieces(const Mesh& mesh, const QuantizationGrid& grid, std::size_t max_piece_triangles,
                       const Executor& executor, const RunControl& control)
    : mesh_(mesh), grid_(grid) {
  cut(std::max<std::size_t>(1, max_piece_triangles), executor, control);
}

void MeshPieces::cut(std::size_t max_piece_triangles, const Executor& executor, const RunControl& control) {
  const std::size_t nf = mesh_.triangles.size();
  const std::size_t nv = mesh_.vertices.size();
  const std::size_t n = std::max<std::size_t>(1, (nf + max_piece_triangles - 1) / max_piece_triangles);
  pieces_.assign(n, Piece{});
  tags_.clear();
  std::unique_ptr<std::atomic<std::uint32_t>[]> owner;
  std::vector<std::uint8_t> shared;
  if (n > 1) {
    owner.reset(new std::atomic<std::uint32_t>[nv]);
    for (std::size_t v = 0; v < nv; ++v) owner[v].store(kUnset, std::memory_order_relaxed);
    shared.assign(nv, 0);
  }
  std::vector<std::size_t> owned(n, 0);
  executor.for_each(static_cast<int>(n), [&](int p) {
    control.check();
    const std::size_t begin = nf * p / n, end = nf * (p + 1) / n;
    Piece& piece = pieces_[p];
    std::uint32_t lo = kUnset, hi = 0;
    std::size_t count = 0;
    for (std::size_t t = begin; t < end; ++t) {
      const Triangle& tri = mesh_.triangles[t];
      if (repeated(tri)) continue;
      ++count;
      for (std::uint32_t v : tri) {
        lo = std::min(lo, v);
        hi = std::max(hi, v);
      }
    }
    piece.triangles.reserve(count);
    if (count == 0) return;
    const std::size_t window = std::size_t{hi} - lo + 1;
    if (window <= 8 * 3 * count + 4096) {
      std::vector<std::uint32_t> local(window, kUnset);
      for (std::size_t t = begin; t < end; ++t) {
        const Triangle& tri = mesh_.triangles[t];
        if (repeated(tri)) continue;
        Triangle out;
        for (int c = 0; c < 3; ++c) {
          std::uint32_t& l = local[tri[c] - lo];
          if (l == kUnset) {
            l = static_cast<std::uint32_t>(piece.globals.size());
            piece.globals.push_back(tri[c]);
          }
          out[c] = l;
        }
        piece.triangles.push_back(out);
      }
    } else {
      // Vertex ids scattered over the mesh: number them by first use through a sort of (id, corner).
      std::vector<std::pair<std::uint32_t, std::uint32_t>> corners;  // (vertex, corner in the piece)
      corners.reserve(3 * count);
      for (std::size_t t = begin; t < end; ++t) {
        const Triangle& tri = mesh_.triangles[t];
        if (repeated(tri)) continue;
        for (int c = 0; c < 3; ++c) corners.emplace_back(tri[c], static_cast<std::uint32_t>(corners.size()));
      }
      std::sort(corners.begin(), corners.end());
      std::vector<std::size_t> run_start;  // runs of one vertex; each begins with its first corner
      for (std::size_t i = 0; i < corners.size(); ++i) {
        if (i == 0 || corners[i].first != corners[i - 1].first) run_start.push_back(i);
      }
      run_start.push_back(corners.size());
      const std::size_t runs = run_start.size() - 1;
      std::vector<std::pair<std::uint32_t, std::uint32_t>> order(runs);  // (first corner, run)
      for (std::size_t r = 0; r < runs; ++r) order[r] = {corners[run_start[r]].second, static_cast<std::uint32_t>(r)};
      std::sort(order.begin(), order.end());
      std::vector<std::uint32_t> local(corners.size());
      piece.globals.resize(runs);
      for (std::size_t l = 0; l < runs; ++l) {
        const std::size_t r = order[l].second;
        piece.globals[l] = corners[run_start[r]].first;
        for (std::size_t i = run_start[r]; i < run_start[r + 1]; ++i)
          local[corners[i].second] = static_cast<std::uint32_t>(l);
      }
      for (std::size_t t = 0; t < count; ++t) {
        piece.triangles.push_back({local[3 * t], local[3 * t + 1], local[3 * t + 2]});
      }
    }
    if (n == 1) return;
    std::size_t mine = 0;
    for (std::uint32_t v : piece.globals) {
      std::uint32_t expected = kUnset;
      if (owner[v].compare_exchange_strong(expected, static_cast<std::uint32_t>(p), std::memory_order_relaxed)) {
        ++mine;
      } else {
        std::atomic_ref<std::uint8_t>(shared[v]).store(1, std::memory_order_relaxed);
      }
    }
    owned[p] = mine;
  });
  triangles_ = 0;
  for (const Piece& piece : pieces_) triangles_ += piece.triangles.size();
  if (n == 1) {
    vertices_ = pieces_[0].globals.size();
    return;
  }
  vertices_ = std::accumulate(owned.begin(), owned.end(), std::size_t{0});
  tag_seams(shared);
  if (tags_.empty()) cut(std::numeric_limits<std::size_t>::max(), executor, control);  // ranks overflowed
}

void MeshPieces::tag_seams(const std::vector<std::uint8_t>& shared) {
  struct Seam {
    std::array<std::uint32_t, 3> key;
    std::uint32_t vertex;
    bool operator<(const Seam& o) const { return key != o.key ? key < o.key : vertex < o.vertex; }
  };
  std::vector<Seam> seams;
  for (std::size_t v = 0; v < shared.size(); ++v) {
    if (shared[v]) seams.push_back({grid_.quantize(mesh_.vertices[v]), static_cast<std::uint32_t>(v)});
  }
  std::sort(seams.begin(), seams.end());
  tags_.assign(mesh_.vertices.size(), 0);
  std::uint32_t rank = 0;
  for (std::size_t i = 0; i < seams.size(); ++i) {
    rank = i > 0 && seams[i].key == seams[i - 1].key ? rank + 1 : 1;
    if (rank > std::numeric_limits<std::uint16_t>::max()) {
      tags_.clear();
      return;
    }
    tags_[seams[i].vertex] = static_cast<std::uint16_t>(rank);
  }
}

QuantizedPiece MeshPieces::piece(int p) const {
  const Piece& piece = pieces_.at(p);
  QuantizedPiece out;
  out.positions.resize(piece.globals.size());
  out.seam_tags.assign(piece.globals.size(), 0);
  const bool normals = !mesh_.normals.empty();
  if (normals) out.normals.resize(piece.globals.size());
  for (std::size_t l = 0; l < piece.globals.size(); ++l) {
    const std::uint32_t v = piece.globals[l];
    out.positions[l] = grid_.quantize(mesh_.vertices[v]);
    if (!tags_.empty()) out.seam_tags[l] = tags_[v];
    if (normals) out.normals[l] = mesh_.normals[v];
  }
  out.triangles = piece.triangles;
  return out;
}

Mesh weld(const std::vector<QuantizedPiece>& pieces, const QuantizationGrid& grid, const Executor& executor) {
  const int n = static_cast<int>(pieces.size());
  const bool normals = n > 0 && !pieces[0].normals.empty();
  for (int p = 0; p < n; ++p) {
    const QuantizedPiece& piece = pieces[p];
    const std::size_t nv = piece.positions.size();
    const std::string where = "piece " + std::to_string(p) + ": ";
    if (piece.seam_tags.size() != nv || piece.normals.size() != (normals ? nv : 0)) {
      throw InvalidInput("frame", where + "attributes do not match its " + std::to_string(nv) + " vertices");
    }
  }
  // Shared vertices: (grid point, tag, piece, local index), sorted; the first of each group is the one kept.
  struct Entry {
    std::array<std::uint32_t, 3> key;
    std::uint16_t tag;
    std::uint32_t piece;
    std::uint32_t local;
    bool operator<(const Entry& o) const {
      if (key != o.key) return key < o.key;
      if (tag != o.tag) return tag < o.tag;
      return piece != o.piece ? piece < o.piece : local < o.local;
    }
    bool same_vertex(const Entry& o) const { return key == o.key && tag == o.tag; }
  };
  std::vector<Entry> entries;
  for (int p = 0; p < n; ++p) {
    const QuantizedPiece& piece = pieces[p];
    for (std::size_t l = 0; l < piece.positions.size(); ++l) {
      if (piece.seam_tags[l] != 0) {
        entries.push_back(
            {piece.positions[l], piece.seam_tags[l], static_cast<std::uint32_t>(p), static_cast<std::uint32_t>(l)});
      }
    }
  }
  std::sort(entries.begin(), entries.end());
  // copy_of[p][l]: the entry kept for a shared vertex that is a later copy (kUnset for vertices kept).
  std::vector<std::vector<std::uint32_t>> copy_of(n);
  for (int p = 0; p < n; ++p) copy_of[p].assign(pieces[p].positions.size(), kUnset);
  std::vector<std::size_t> kept(n);
  for (int p = 0; p < n; ++p) kept[p] = pieces[p].positions.size();
  for (std::size_t i = 0, head = 0; i < entries.size(); ++i) {
    if (i == 0 || !entries[i].same_vertex(entries[i - 1])) {
      head = i;
      if (i + 1 == entries.size() || !entries[i + 1].same_vertex(entries[i])) {
        throw InvalidInput("frame", "piece " + std::to_string(entries[i].piece) + ": vertex " +
                                        std::to_string(entries[i].local) +
                                        " is tagged as shared but no other piece has it");
      }
      continue;
    }
    copy_of[entries[i].piece][entries[i].local] = static_cast<std::uint32_t>(head);
    --kept[entries[i].piece];
  }
  std::vector<std::size_t> first(n + 1, 0);
  for (int p = 0; p < n; ++p) first[p + 1] = first[p] + kept[p];
  if (first[n] > std::numeric_limits<std::uint32_t>::max()) throw InvalidInput("frame", "too many vertices");

  Mesh mesh;
  mesh.vertices.resize(first[n]);
  if (normals) mesh.normals.resize(first[n]);
  std::vector<std::vector<std::uint32_t>> global(n);
  const std::uint32_t max_value = grid.max_value();
  executor.for_each(n, [&](int p) {
    const QuantizedPiece& piece = pieces[p];
    std::vector<std::uint32_t>& g = global[p];
    g.assign(piece.positions.size(), kUnset);
    auto next = static_cast<std::uint32_t>(first[p]);
    for (std::size_t l = 0; l < piece.positions.size(); ++l) {
      const auto& q = piece.positions[l];
      if (q[0] > max_value || q[1] > max_value || q[2] > max_value) {
        throw InvalidInput("frame", "piece " + std::to_string(p) + ": vertex " + std::to_string(l) +
                                        " lies beyond the quantization grid");
      }
      if (copy_of[p][l] != kUnset) continue;
      g[l] = next;
      mesh.vertices[next] = grid.dequantize(q);
      if (normals) mesh.normals[next] = piece.normals[l];
      ++next;
    }
  });
  for (int p = 0; p < n; ++p) {
    for (std::size_t l = 0; l < copy_of[p].size(); ++l) {
      if (copy_of[p][l] == kUnset) continue;
      const Entry& head = entries[copy_of[p][l]];
      global[p][l] = global[head.piece][head.local];
    }
  }
  std::vector<std::size_t> first_triangle(n + 1, 0);
  for (int p = 0; p < n; ++p) first_triangle[p + 1] = first_triangle[p] + pieces[p].triangles.size();
  mesh.triangles.resize(first_triangle[n]);
  executor.for_each(n, [&](int p) {
    const QuantizedPiece& piece = pieces[p];
    const std::vector<std::uint32_t>& g = global[p];
    for (std::size_t t = 0; t < piece.triangles.size(); ++t) {
      Triangle out;
      for (int c = 0; c < 3; ++c) {
        const std::uint32_t l = piece.triangles[t][c];
        if (l >= g.size()) {
          throw InvalidInput("frame", "piece " + std::to_string(p) + ": triangle " + std::to_string(t) +
                                          " uses vertex " + std::to_string(l) + " of " + std::to_string(g.size()));
        }
        out[c] = g[l];
      }
      mesh.triangles[first_triangle[p] + t] = out;
    }
  });
  return mesh;
}

}  // namespace surfacer
