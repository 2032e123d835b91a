// The cut is by triangle count and index alone, so the pieces, and every byte encoded from them, are the same whatever
// the number of threads. Local vertex numbers follow first use in the piece (a window over the vertex ids the piece
// touches, or a sort when the ids are scattered; the windows are reused from piece to piece). Every piece writes its
// number on its vertices and then reads them back: a piece that finds another's number lists the vertex as shared.
// Shared vertices on the same grid point are ranked by mesh index, which makes the tags deterministic.
#include "core/mesh/mesh_pieces.h"

#include <algorithm>
#include <atomic>
#include <limits>
#include <memory>
#include <mutex>
#include <numeric>
#include <string>

#include "core/util/errors.h"
#include "core/util/parallel.h"

namespace surfacer {
namespace {

constexpr std::uint32_t kUnset = std::numeric_limits<std::uint32_t>::max();
// In MeshPieces::owner_: set on a vertex that more than one piece uses; the low bits then hold its seam tag.
constexpr std::uint32_t kShared = 0x80000000u;
constexpr std::size_t kPieceMultiple = 4;

bool repeated(const Triangle& t) { return t[0] == t[1] || t[1] == t[2] || t[0] == t[2]; }

bool operator<(const std::array<std::uint32_t, 3>& a, const std::array<std::uint32_t, 3>& b) {
  return std::lexicographical_compare(a.begin(), a.end(), b.begin(), b.end());
}

}  // namespace

// Arrays of local vertex numbers, kUnset everywhere between uses, shared by the pieces a cut builds: a piece takes
// one, numbers its vertices in it and resets the entries it set before giving it back, so no piece clears or
// faults in a window of its own.
class MeshPieces::WindowPool {
 public:
  std::vector<std::uint32_t> take(std::size_t size) {
    std::vector<std::uint32_t> window;
    {
      const std::lock_guard lock(mutex_);
      if (!free_.empty()) {
        window = std::move(free_.back());
        free_.pop_back();
      }
    }
    if (window.size() < size) window.resize(size, kUnset);
    return window;
  }
  void give_back(std::vector<std::uint32_t> window) {
    const std::lock_guard lock(mutex_);
    free_.push_back(std::move(window));
  }

 private:
  std::mutex mutex_;
  std::vector<std::vector<std::uint32_t>> free_;
};

MeshPieces::MeshPieces(const Mesh& mesh, const QuantizationGrid& grid, std::size_t max_piece_triangles, int threads,
                       const RunControl& control)
    : mesh_(mesh), grid_(grid) {
  cut(std::max<std::size_t>(1, max_piece_triangles), threads, control);
}

void MeshPieces::cut(std::size_t max_piece_triangles, int threads, const RunControl& control) {
  const std::size_t nf = mesh_.triangles.size();
  const std::size_t nv = mesh_.vertices.size();
  // As many pieces as needed, rounded up to a multiple of kPieceMultiple so that they share out evenly over 1, 2 and 4
  // threads (9 pieces on 2 threads would take 5 rounds for 4.5 rounds of work).
  std::size_t n = (nf + max_piece_triangles - 1) / max_piece_triangles;
  n = n <= 1 ? 1 : (n + kPieceMultiple - 1) / kPieceMultiple * kPieceMultiple;
  if (n >= kShared) throw ResourceLimit("max_piece_triangles", "a frame of more than 2^31 pieces");
  pieces_.assign(n, Piece{});
  // Written where a piece claims a vertex, and read only there.
  owner_ = n > 1 ? std::make_unique_for_overwrite<std::uint32_t[]>(nv) : nullptr;
  WindowPool windows;
  parallel_for(static_cast<int>(n), threads, [&](int p) {
    control.check();
    number(nf * p / n, nf * (p + 1) / n, pieces_[p], windows);
    // Every piece writes its number on its vertices; one of the writes stays.
    if (n > 1) {
      for (std::uint32_t v : pieces_[p].globals) std::atomic_ref(owner_[v]).store(p, std::memory_order_relaxed);
    }
  });
  triangles_ = 0;
  for (const Piece& piece : pieces_) triangles_ += piece.triangles.size();
  if (n == 1) {
    vertices_ = pieces_[0].globals.size();
    return;
  }
  // The piece whose number stayed counts the vertex; the others find another number there: the vertex is shared, and
  // they list it with its grid point. Plain loads and stores, no read-modify-write per vertex.
  struct Seam {
    std::array<std::uint32_t, 3> key;
    std::uint32_t vertex;
    bool operator<(const Seam& o) const { return key != o.key ? key < o.key : vertex < o.vertex; }
    bool operator==(const Seam& o) const { return vertex == o.vertex; }
  };
  std::vector<std::vector<Seam>> listed(n);
  std::vector<std::size_t> owned(n, 0);
  parallel_for(static_cast<int>(n), threads, [&](int p) {
    control.check();
    for (std::uint32_t v : pieces_[p].globals) {
      if (std::atomic_ref(owner_[v]).load(std::memory_order_relaxed) == static_cast<std::uint32_t>(p)) {
        ++owned[p];
      } else {
        listed[p].push_back({grid_.quantize(mesh_.vertices[v]), v});
      }
    }
  });
  vertices_ = std::accumulate(owned.begin(), owned.end(), std::size_t{0});
  // Shared vertices on one grid point are ranked by mesh index: the tag, stored in the owner's place.
  std::vector<Seam> seams;
  for (const auto& l : listed) seams.insert(seams.end(), l.begin(), l.end());
  std::sort(seams.begin(), seams.end());
  seams.erase(std::unique(seams.begin(), seams.end()), seams.end());  // listed by several pieces
  std::uint32_t rank = 0;
  for (std::size_t i = 0; i < seams.size(); ++i) {
    rank = i > 0 && seams[i].key == seams[i - 1].key ? rank + 1 : 1;
    if (rank > std::numeric_limits<std::uint16_t>::max()) {  // never on real surfaces: one piece, no seams
      cut(std::numeric_limits<std::size_t>::max(), threads, control);
      return;
    }
    owner_[seams[i].vertex] = kShared | rank;
  }
}

void MeshPieces::number(std::size_t begin, std::size_t end, Piece& piece, WindowPool& windows) const {
  std::size_t count = 0;
  for (std::size_t t = begin; t < end; ++t) count += repeated(mesh_.triangles[t]) ? 0 : 1;
  piece.triangles.reserve(count);
  if (count == 0) return;
  // The window of vertex ids: a plain min/max over the indices, which vectorizes (repeated triangles only widen it).
  std::uint32_t lo = kUnset, hi = 0;
  for (std::size_t t = begin; t < end; ++t) {
    for (std::uint32_t v : mesh_.triangles[t]) {
      lo = std::min(lo, v);
      hi = std::max(hi, v);
    }
  }
  const std::size_t window = std::size_t{hi} - lo + 1;
  if (window <= 8 * 3 * count + 4096) {
    std::vector<std::uint32_t> local = windows.take(window);
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
    for (std::uint32_t v : piece.globals) local[v - lo] = kUnset;
    windows.give_back(std::move(local));
    return;
  }
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
  for (std::size_t t = 0; t < count; ++t) piece.triangles.push_back({local[3 * t], local[3 * t + 1], local[3 * t + 2]});
}

QuantizedPiece MeshPieces::take(int p) {
  Piece& piece = pieces_.at(p);
  QuantizedPiece out;
  const std::size_t nv = piece.globals.size();
  out.positions.resize(nv);
  out.seam_tags.assign(nv, 0);
  const bool normals = !mesh_.normals.empty();
  if (normals) out.normals.resize(nv);
  out.attributes.reserve(mesh_.attributes.size());
  for (const Attribute& a : mesh_.attributes) {
    Attribute& local = out.attributes.emplace_back(Attribute{a.name, a.components, {}});
    local.values.resize(nv * static_cast<std::size_t>(a.components));
  }
  for (std::size_t l = 0; l < nv; ++l) {
    const std::uint32_t v = piece.globals[l];
    out.positions[l] = grid_.quantize(mesh_.vertices[v]);
    if (owner_ && (owner_[v] & kShared)) out.seam_tags[l] = static_cast<std::uint16_t>(owner_[v] & 0xffffu);
    if (normals) out.normals[l] = mesh_.normals[v];
    for (std::size_t a = 0; a < out.attributes.size(); ++a) {
      const auto k = static_cast<std::size_t>(out.attributes[a].components);
      std::copy_n(mesh_.attributes[a].values.begin() + v * k, k, out.attributes[a].values.begin() + l * k);
    }
  }
  out.triangles = std::move(piece.triangles);
  piece = Piece{};
  return out;
}

Mesh weld(const std::vector<QuantizedPiece>& pieces, const QuantizationGrid& grid, int threads) {
  const int n = static_cast<int>(pieces.size());
  const bool normals = n > 0 && !pieces[0].normals.empty();
  for (int p = 0; p < n; ++p) {
    const QuantizedPiece& piece = pieces[p];
    const std::size_t nv = piece.positions.size();
    const std::string where = "piece " + std::to_string(p) + ": ";
    if (piece.seam_tags.size() != nv || piece.normals.size() != (normals ? nv : 0)) {
      throw InvalidInput("frame", where + "attributes do not match its " + std::to_string(nv) + " vertices");
    }
    if (piece.attributes.size() != pieces[0].attributes.size()) {
      throw InvalidInput("frame", where + std::to_string(piece.attributes.size()) + " attributes, piece 0 has " +
                                      std::to_string(pieces[0].attributes.size()));
    }
    for (std::size_t a = 0; a < piece.attributes.size(); ++a) {
      const Attribute& attribute = piece.attributes[a];
      if (attribute.name != pieces[0].attributes[a].name ||
          attribute.components != pieces[0].attributes[a].components || attribute.components < 1 ||
          attribute.components > Attribute::kMaxComponents ||
          attribute.values.size() != nv * static_cast<std::size_t>(attribute.components)) {
        throw InvalidInput("frame", where + "attribute " + std::to_string(a) + " (" + attribute.name +
                                        ") does not match piece 0's or its " + std::to_string(nv) + " vertices");
      }
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
  if (n > 0) {
    for (const Attribute& a : pieces[0].attributes) {
      mesh.attributes.push_back(Attribute{a.name, a.components, std::vector<float>(first[n] * a.components)});
    }
  }
  std::vector<std::vector<std::uint32_t>> global(n);
  const std::uint32_t max_value = grid.max_value();
  parallel_for(n, threads, [&](int p) {
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
      for (std::size_t a = 0; a < mesh.attributes.size(); ++a) {
        const auto k = static_cast<std::size_t>(mesh.attributes[a].components);
        std::copy_n(piece.attributes[a].values.begin() + l * k, k, mesh.attributes[a].values.begin() + next * k);
      }
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
  parallel_for(n, threads, [&](int p) {
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
