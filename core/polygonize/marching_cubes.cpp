// Marching Cubes over z-slabs. Layout of the work (see marching_cubes.h for the contract):
//
// * The grid has (cells + 1) points per axis. A slab is a run of cell layers [k0, k1); it holds two point layers at a
//   time (values, inside bits, per-row crossing ranges) and, per point layer, the vertex ids of its crossed x- and
//   y-edges, plus the ids of the crossed z-edges between the two layers. No hash maps: a crossed edge's vertex id is
//   stored at the edge's slot in those arrays, so every crossed edge gets exactly one vertex (welded output).
// * Vertex order is fixed by the grid alone: x/y-edges of point layer 0, then for each cell layer k: its z-edges,
//   then the x/y-edges of point layer k + 1 (each in row order). A slab creates the vertices of its own cell layers
//   in that order, so concatenating slabs in z order reproduces the single-slab order exactly. A slab's bottom point
//   layer (k0 > 0) belongs to the slab below: the slab scans it in the same order and records "foreign" ids
//   (kForeign | ordinal), which the merge resolves to the lower slab's vertices of its top layer. Hence the result is
//   byte-identical whatever the number of threads or slabs.
// * Rows are trimmed as in flying edges (Schroeder et al. 2015): per point row we keep the first and last crossed
//   x-edge; a cell row only visits cells between the extreme crossings of its four point rows (or the whole row when
//   the rows start or end with different signs). The cube case is built from one byte per x position holding the
//   four (y, z) corner bits, so each cell costs two loads, a shift and an or.
#include "core/polygonize/marching_cubes.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "core/polygonize/edge_margin.h"
#include "core/polygonize/mc_tables.h"
#include "core/scene/scene.h"
#include "core/util/errors.h"
#include "core/util/parallel.h"
#include "core/util/triangle_limit.h"

namespace surfacer {
namespace {

constexpr std::uint32_t kForeign = 0x80000000u;
constexpr int kPad = 16;  // slack bytes after byte rows, so 8-byte loads never leave the allocation

inline std::uint64_t load8(const std::uint8_t* p) {
  std::uint64_t w;
  std::memcpy(&w, p, 8);
  if constexpr (std::endian::native == std::endian::big) w = __builtin_bswap64(w);
  return w;
}

// Calls f(i) for each i in [begin, end) where the 0/1 bytes a[i] and b[i] differ, eight positions per step.
template <class F>
inline void for_each_difference(const std::uint8_t* a, const std::uint8_t* b, int begin, int end, F&& f) {
  int i = begin;
  for (; i + 8 <= end; i += 8) {
    std::uint64_t x = load8(a + i) ^ load8(b + i);  // one set bit (bit 0 of its byte) per difference
    while (x != 0) {
      f(i + (std::countr_zero(x) >> 3));
      x &= x - 1;
    }
  }
  for (; i < end; ++i) {
    if (a[i] != b[i]) f(i);
  }
}

// Point coordinates per axis; the last one is exactly bounds.max.
struct Grid {
  std::array<int, 3> cells{};
  std::array<int, 3> points{};
  std::array<std::vector<double>, 3> coords;
  double vertex_margin = 0.0;  // MarchingCubesOptions::vertex_margin

  Grid(const MarchingCubesOptions& options) : cells(options.cells), vertex_margin(options.vertex_margin) {
    for (int a = 0; a < 3; ++a) {
      points[a] = cells[a] + 1;
      coords[a].resize(points[a]);
      const double lo = options.bounds.min[a], hi = options.bounds.max[a];
      for (int i = 0; i <= cells[a]; ++i) {
        coords[a][i] = i == cells[a] ? hi : lo + (hi - lo) * (static_cast<double>(i) / cells[a]);
      }
    }
  }
  std::size_t layer_size() const { return static_cast<std::size_t>(points[0]) * points[1]; }
};

void validate(const MarchingCubesOptions& options) {
  const Aabb& b = options.bounds;
  if (!b.valid() || !b.min.allFinite() || !b.max.allFinite()) {
    throw InvalidInput("bounds", "bounds.min must be < bounds.max on every axis and both finite; got min " +
                                     format_point(b.min) + " max " + format_point(b.max));
  }
  static const char* const kAxis[3] = {"x", "y", "z"};
  for (int a = 0; a < 3; ++a) {
    const int n = options.cells[a];
    if (n < 1 || n > (1 << 24)) {
      throw InvalidInput("cells", std::string("cells.") + kAxis[a] + " (" + std::to_string(n) +
                                      ") must be in 1..16777216; use more cells for finer meshes");
    }
  }
  const double layer = (options.cells[0] + 1.0) * (options.cells[1] + 1.0);
  if (layer > 2147483647.0) {
    throw ResourceLimit("cells", "(cells.x + 1) * (cells.y + 1) = " + std::to_string(static_cast<std::int64_t>(layer)) +
                                     " points per z-layer exceeds 2^31; use fewer cells");
  }
  if (options.threads < 0) {
    throw InvalidInput("threads",
                       "threads (" + std::to_string(options.threads) + ") must be >= 0; 0 uses every hardware thread");
  }
  check_vertex_margin(options.vertex_margin);
}

// Per point row: the inside bit of its first and last point, and the range of x-edges that may be crossed:
// points [0, lo] all have sign `first`, points [hi, n] all have sign `last` (lo = cells, hi = 0 when uniform).
struct RowInfo {
  int lo = 0;
  int hi = 0;
  std::uint8_t first = 0;
  std::uint8_t last = 0;
};

// Pre-sampled values; the whole array is addressable, so layers are pointers into it.
struct SampleSource {
  using Value = float;
  const Grid& grid;
  std::span<const float> samples;

  const float* load(int k, std::vector<float>& /*buffer*/, const RunControl& /*control*/) const {
    return samples.data() + static_cast<std::size_t>(k) * grid.layer_size();
  }

  double at(int i, int j, int k) const {
    return samples[(static_cast<std::size_t>(k) * grid.points[1] + j) * grid.points[0] + i];
  }
  // Central difference (one-sided on the border) at grid point (i, j, k).
  Vec3 gradient(int i, int j, int k) const {
    const std::array<int, 3> p{i, j, k};
    Vec3 g;
    for (int a = 0; a < 3; ++a) {
      std::array<int, 3> lo = p, hi = p;
      lo[a] = std::max(0, p[a] - 1);
      hi[a] = std::min(grid.cells[a], p[a] + 1);
      g[a] = (at(hi[0], hi[1], hi[2]) - at(lo[0], lo[1], lo[2])) / (grid.coords[a][hi[a]] - grid.coords[a][lo[a]]);
    }
    return g;
  }
  // Gradient at the vertex on the edge from point (i, j, k) along `axis`, at parameter t.
  Vec3 normal(int axis, int i, int j, int k, double t, const Vec3& /*p*/) const {
    std::array<int, 3> q{i, j, k};
    ++q[axis];
    return (1.0 - t) * gradient(i, j, k) + t * gradient(q[0], q[1], q[2]);
  }
};

// A Field sampled one layer at a time.
struct FieldSource {
  using Value = double;
  const Grid& grid;
  const Field& field;
  std::optional<double> lipschitz = std::nullopt;  // set: sparse evaluation (MarchingCubesOptions::sparse)

  const double* load(int k, std::vector<double>& buffer, const RunControl& control) const {
    const int px = grid.points[0], py = grid.points[1];
    buffer.resize(grid.layer_size());
    if (lipschitz) {
      load_sparse(k, 0, px, 0, py, buffer.data(), control);
      return buffer.data();
    }
    Vec3 p;
    p.z() = grid.coords[2][k];
    for (int j = 0; j < py; ++j) {
      control.check();  // field evaluation may be slow: check per row, not only per layer
      p.y() = grid.coords[1][j];
      double* row = buffer.data() + static_cast<std::size_t>(j) * px;
      for (int i = 0; i < px; ++i) {
        p.x() = grid.coords[0][i];
        row[i] = field.value(p);
      }
    }
    return buffer.data();
  }
  Vec3 normal(int /*axis*/, int /*i*/, int /*j*/, int /*k*/, double /*t*/, const Vec3& p) const {
    Vec3 g;
    field.value_and_gradient(p, g);
    return g;
  }

  // Points [i0, i1) x [j0, j1) of layer k. Every grid edge from one of them ends in the box of points
  // [i0 - 1, i1] x [j0 - 1, j1] x [k - 1, k + 1]; when the Lipschitz ball around the box's centre proves one strict
  // sign there, no edge from these points is crossed, so their values are never interpolated and only their sign
  // matters: f(centre) stands in for all of them. Otherwise the tile is split in four, down to 64 points.
  void load_sparse(int k, int i0, int i1, int j0, int j1, double* layer, const RunControl& control) const {
    const int px = grid.points[0];
    const auto& cx = grid.coords[0];
    const auto& cy = grid.coords[1];
    const auto& cz = grid.coords[2];
    const Vec3 lo(cx[std::max(i0 - 1, 0)], cy[std::max(j0 - 1, 0)], cz[std::max(k - 1, 0)]);
    const Vec3 hi(cx[std::min(i1, grid.cells[0])], cy[std::min(j1, grid.cells[1])], cz[std::min(k + 1, grid.cells[2])]);
    const Vec3 centre = 0.5 * (lo + hi);
    const double f = field.value(centre);
    if (std::abs(f) > *lipschitz * 0.5 * (hi - lo).norm() * (1.0 + 1e-9)) {
      for (int j = j0; j < j1; ++j)
        std::fill(layer + static_cast<std::size_t>(j) * px + i0, layer + static_cast<std::size_t>(j) * px + i1, f);
      return;
    }
    if (static_cast<std::int64_t>(i1 - i0) * (j1 - j0) <= 64) {
      Vec3 p;
      p.z() = cz[k];
      for (int j = j0; j < j1; ++j) {
        p.y() = cy[j];
        double* row = layer + static_cast<std::size_t>(j) * px;
        for (int i = i0; i < i1; ++i) {
          p.x() = cx[i];
          row[i] = field.value(p);
        }
      }
      return;
    }
    control.check();
    const int im = (i0 + i1) / 2, jm = (j0 + j1) / 2;
    if (i1 - i0 >= 2 * (j1 - j0)) {
      load_sparse(k, i0, im, j0, j1, layer, control);
      load_sparse(k, im, i1, j0, j1, layer, control);
    } else if (j1 - j0 >= 2 * (i1 - i0)) {
      load_sparse(k, i0, i1, j0, jm, layer, control);
      load_sparse(k, i0, i1, jm, j1, layer, control);
    } else {
      load_sparse(k, i0, im, j0, jm, layer, control);
      load_sparse(k, im, i1, j0, jm, layer, control);
      load_sparse(k, i0, im, jm, j1, layer, control);
      load_sparse(k, im, i1, jm, j1, layer, control);
    }
  }
};

// Append-only storage in fixed-size blocks: growing never copies, and the blocks are small enough for malloc to
// recycle them between calls (large std::vector growth would map, fault in and copy fresh pages each time).
template <class T>
class BlockVector {
 public:
  static constexpr std::size_t kBlock = 1 << 14;
  void push_back(const T& value) {
    if (fill_ == kBlock || blocks_.empty()) {
      blocks_.push_back(std::make_unique_for_overwrite<T[]>(kBlock));
      fill_ = 0;
    }
    blocks_.back()[fill_++] = value;
  }
  std::size_t size() const { return blocks_.empty() ? 0 : (blocks_.size() - 1) * kBlock + fill_; }
  T* copy_to(T* out) const {
    for (std::size_t b = 0; b < blocks_.size(); ++b) {
      const std::size_t n = b + 1 == blocks_.size() ? fill_ : kBlock;
      out = std::copy(blocks_[b].get(), blocks_[b].get() + n, out);
    }
    return out;
  }
  template <class F>
  void for_each(F&& f) const {
    for (std::size_t b = 0; b < blocks_.size(); ++b) {
      const std::size_t n = b + 1 == blocks_.size() ? fill_ : kBlock;
      for (std::size_t i = 0; i < n; ++i) f(blocks_[b][i]);
    }
  }

 private:
  std::vector<std::unique_ptr<T[]>> blocks_;
  std::size_t fill_ = 0;
};

// Layers finished across all slabs, reported as a non-decreasing fraction (callbacks are serialized).
struct Progress {
  std::mutex mutex;
  int done = 0;
  void layer_done(const RunControl& control, int layers) {
    std::lock_guard lock(mutex);
    ++done;
    control.report("polygonize", static_cast<double>(done) / layers);
  }
};

struct SlabOutput {
  BlockVector<Vec3> vertices;
  BlockVector<Vec3> normals;
  BlockVector<Triangle> triangles;    // ids local to the slab, or kForeign | ordinal in the lower slab's top layer
  std::uint32_t top_layer_start = 0;  // local id of the first vertex on the slab's top point layer
};

template <class Source>
class SlabMesher {
  using Value = typename Source::Value;

 public:
  SlabMesher(const Grid& grid, const Source& source, bool normals, const RunControl& control, Progress& progress,
             TriangleCounter& triangles)
      : grid_(grid),
        source_(source),
        normals_(normals),
        control_(control),
        progress_(progress),
        triangles_(triangles),
        px_(grid.points[0]),
        py_(grid.points[1]) {
    for (Layer& layer : layers_) {
      layer.inside.resize(grid.layer_size() + kPad);
      layer.rows.resize(py_);
      layer.xid.resize(static_cast<std::size_t>(px_ - 1) * py_);
      layer.yid.resize(static_cast<std::size_t>(px_) * (py_ - 1));
    }
    zid_.resize(grid.layer_size());
    column_.resize(static_cast<std::size_t>(px_) + kPad);
  }

  // Cell layers [k0, k1).
  SlabOutput run(int k0, int k1) {
    control_.check();
    load_layer(layers_[0], k0);
    make_layer_vertices(layers_[0], /*foreign=*/k0 > 0);
    Layer* bottom = &layers_[0];
    Layer* top = &layers_[1];
    for (int k = k0; k < k1; ++k) {
      control_.check();
      load_layer(*top, k + 1);
      make_z_vertices(*bottom, *top);
      out_.top_layer_start = static_cast<std::uint32_t>(out_.vertices.size());
      make_layer_vertices(*top, /*foreign=*/false);
      emit_triangles(*bottom, *top);
      std::swap(bottom, top);
      progress_.layer_done(control_, grid_.cells[2]);
    }
    return std::move(out_);
  }

 private:
  struct Layer {
    int k = 0;
    const Value* values = nullptr;
    std::vector<Value> buffer;
    std::vector<std::uint8_t> inside;  // 1 where value < 0
    std::vector<RowInfo> rows;
    std::vector<std::uint32_t> xid;  // [j * (px - 1) + i]: edge (i, j) - (i + 1, j)
    std::vector<std::uint32_t> yid;  // [j * px + i]: edge (i, j) - (i, j + 1)
  };

  void load_layer(Layer& layer, int k) {
    layer.k = k;
    layer.values = source_.load(k, layer.buffer, control_);
    const int nx = px_ - 1;
    for (int j = 0; j < py_; ++j) {
      const Value* __restrict v = layer.values + static_cast<std::size_t>(j) * px_;
      std::uint8_t* __restrict s = layer.inside.data() + static_cast<std::size_t>(j) * px_;
      unsigned count = 0;
      for (int i = 0; i < px_; ++i) {
        const std::uint8_t in = v[i] < Value(0);
        s[i] = in;
        count += in;
      }
      RowInfo& row = layer.rows[j];
      row.first = s[0];
      row.last = s[nx];
      row.lo = nx;
      row.hi = 0;
      if (count == 0 || count == static_cast<unsigned>(px_)) continue;
      int lo = 0;
      while (lo + 8 <= nx && load8(s + lo) == load8(s + lo + 1)) lo += 8;
      while (s[lo] == s[lo + 1]) ++lo;
      int hi = nx;
      while (hi - 8 >= 0 && load8(s + hi - 8) == load8(s + hi - 7)) hi -= 8;
      while (s[hi] == s[hi - 1]) --hi;
      row.lo = lo;
      row.hi = hi;
    }
  }

  std::uint32_t new_vertex(int axis, int i, int j, int k, Value v0, Value v1) {
    const std::size_t id = out_.vertices.size();
    if (id >= kForeign) {
      throw ResourceLimit("cells", "marching cubes produced more than 2^31 vertices in one slab; use fewer cells");
    }
    // v0 and v1 have different inside bits, so v0 != v1; t in [0, 1].
    const double a = static_cast<double>(v0), b = static_cast<double>(v1);
    std::array<int, 3> idx{i, j, k};
    const double floor =
        edge_parameter_floor(grid_.vertex_margin, grid_.coords[axis][idx[axis] + 1] - grid_.coords[axis][idx[axis]]);
    const double t = std::clamp(a / (a - b), floor, 1.0 - floor);
    Vec3 p(grid_.coords[0][i], grid_.coords[1][j], grid_.coords[2][k]);
    p[axis] = (1.0 - t) * grid_.coords[axis][idx[axis]] + t * grid_.coords[axis][idx[axis] + 1];
    out_.vertices.push_back(p);
    if (normals_) {
      Vec3 n = source_.normal(axis, i, j, k, t, p);
      const double len = n.norm();
      if (len > 0.0 && std::isfinite(len)) {
        n /= len;
      } else {  // flat or broken gradient: the edge direction from its inside to its outside end
        n = Vec3::Zero();
        n[axis] = a < 0.0 ? 1.0 : -1.0;
      }
      out_.normals.push_back(n);
    }
    return static_cast<std::uint32_t>(id);
  }

  // Vertices on the crossed x- and y-edges of one point layer. `foreign`: the layer belongs to the slab below; only
  // number its crossed edges in creation order.
  void make_layer_vertices(Layer& layer, bool foreign) {
    std::uint32_t ordinal = 0;
    const int nx = px_ - 1;
    const int k = layer.k;
    for (int j = 0; j < py_; ++j) {
      const RowInfo& row = layer.rows[j];
      const std::uint8_t* s = layer.inside.data() + static_cast<std::size_t>(j) * px_;
      const Value* v = layer.values + static_cast<std::size_t>(j) * px_;
      std::uint32_t* xid = layer.xid.data() + static_cast<std::size_t>(j) * nx;
      for_each_difference(s, s + 1, row.lo, row.hi, [&](int i) {
        xid[i] = foreign ? (kForeign | ordinal++) : new_vertex(0, i, j, k, v[i], v[i + 1]);
      });
      if (j + 1 == py_) break;
      const auto [begin, end] = point_range(row, layer.rows[j + 1]);
      const Value* v1 = v + px_;
      std::uint32_t* yid = layer.yid.data() + static_cast<std::size_t>(j) * px_;
      for_each_difference(s, s + px_, begin, end, [&](int i) {
        yid[i] = foreign ? (kForeign | ordinal++) : new_vertex(1, i, j, k, v[i], v1[i]);
      });
    }
  }

  // Points of two rows whose inside bits may differ: outside the range both rows are uniform with equal signs.
  std::pair<int, int> point_range(const RowInfo& a, const RowInfo& b) const {
    const int begin = a.first == b.first ? std::min(a.lo, b.lo) + 1 : 0;
    const int end = a.last == b.last ? std::max(a.hi, b.hi) : px_;
    return {begin, end};
  }

  void make_z_vertices(const Layer& bottom, const Layer& top) {
    const int k = bottom.k;
    for (int j = 0; j < py_; ++j) {
      const std::size_t off = static_cast<std::size_t>(j) * px_;
      const Value* v0 = bottom.values + off;
      const Value* v1 = top.values + off;
      std::uint32_t* zid = zid_.data() + off;
      const auto [begin, end] = point_range(bottom.rows[j], top.rows[j]);
      for_each_difference(bottom.inside.data() + off, top.inside.data() + off, begin, end,
                          [&](int i) { zid[i] = new_vertex(2, i, j, k, v0[i], v1[i]); });
    }
  }

  void emit_triangles(const Layer& bottom, const Layer& top) {
    const int nx = px_ - 1;
    auto& tris = out_.triangles;
    for (int j = 0; j + 1 < py_; ++j) {
      const RowInfo* r[4] = {&bottom.rows[j], &bottom.rows[j + 1], &top.rows[j], &top.rows[j + 1]};
      const bool same_first = r[0]->first == r[1]->first && r[0]->first == r[2]->first && r[0]->first == r[3]->first;
      const bool same_last = r[0]->last == r[1]->last && r[0]->last == r[2]->last && r[0]->last == r[3]->last;
      const int begin = same_first ? std::min({r[0]->lo, r[1]->lo, r[2]->lo, r[3]->lo}) : 0;
      const int end = same_last ? std::max({r[0]->hi, r[1]->hi, r[2]->hi, r[3]->hi}) : nx;
      if (begin >= end) continue;
      const std::size_t row_start = tris.size();

      const std::size_t off0 = static_cast<std::size_t>(j) * px_, off1 = off0 + px_;
      const std::uint8_t* b0 = bottom.inside.data() + off0;
      const std::uint8_t* b1 = bottom.inside.data() + off1;
      const std::uint8_t* t0 = top.inside.data() + off0;
      const std::uint8_t* t1 = top.inside.data() + off1;
      // Edge id arrays, indexed by the cell's x index; order as in mc_tables.h.
      const std::uint32_t* ep[12] = {
          bottom.xid.data() + static_cast<std::size_t>(j) * nx,
          bottom.xid.data() + static_cast<std::size_t>(j + 1) * nx,
          top.xid.data() + static_cast<std::size_t>(j) * nx,
          top.xid.data() + static_cast<std::size_t>(j + 1) * nx,
          bottom.yid.data() + off0,
          bottom.yid.data() + off0 + 1,
          top.yid.data() + off0,
          top.yid.data() + off0 + 1,
          zid_.data() + off0,
          zid_.data() + off0 + 1,
          zid_.data() + off1,
          zid_.data() + off1 + 1,
      };
      // Corner (x, y, z) is bit x + 2y + 4z; column[i] packs the four corners at x = i into bits 0, 2, 4, 6, so
      // cell i's case is column[i] | column[i + 1] << 1.
      std::uint8_t* __restrict column = column_.data();
      for (int i = begin; i <= end; ++i) column[i] = b0[i] | (b1[i] << 2) | (t0[i] << 4) | (t1[i] << 6);
      auto emit = [&](int i) {
        const unsigned cube = column[i] | (column[i + 1] << 1);
        const std::int8_t* e = mc::kTriangles[cube];
        for (int n = mc::kTriangleCount[cube]; n > 0; --n, e += 3) {
          tris.push_back(Triangle{ep[e[0]][i], ep[e[1]][i], ep[e[2]][i]});
        }
      };
      // Eight cells per step: a cell is empty when its two columns are equal and uniform (0x00 or 0x55).
      int i = begin;
      for (; i + 8 <= end; i += 8) {
        const std::uint64_t w0 = load8(column + i), w1 = load8(column + i + 1);
        std::uint64_t m = (w0 ^ w1) | ((w0 ^ (w0 >> 2)) & 0x1515151515151515ull);
        m |= m >> 4;  // fold each byte onto its bit 0
        m |= m >> 2;
        m |= m >> 1;
        m &= 0x0101010101010101ull;
        while (m != 0) {
          emit(i + (std::countr_zero(m) >> 3));
          m &= m - 1;
        }
      }
      for (; i < end; ++i) {
        const unsigned cube = column[i] | (column[i + 1] << 1);
        if (cube != 0 && cube != 255) emit(i);
      }
      triangles_.add(static_cast<std::int64_t>(tris.size() - row_start));
    }
  }

  const Grid& grid_;
  const Source& source_;
  const bool normals_;
  const RunControl& control_;
  Progress& progress_;
  TriangleCounter& triangles_;  // every slab's, against control.triangles
  const int px_, py_;
  Layer layers_[2];
  std::vector<std::uint32_t> zid_;    // [j * px + i]: edge (i, j, k) - (i, j, k + 1) of the current cell layer
  std::vector<std::uint8_t> column_;  // scratch for emit_triangles
  SlabOutput out_;
};

// Concatenates the slabs in z order, resolving foreign ids; copies run in parallel (one slab per item).
Mesh merge(std::vector<SlabOutput>& slabs, bool normals, int threads) {
  const std::size_t n = slabs.size();
  std::vector<std::size_t> vertex_base(n + 1, 0), triangle_base(n + 1, 0);
  for (std::size_t s = 0; s < n; ++s) {
    vertex_base[s + 1] = vertex_base[s] + slabs[s].vertices.size();
    triangle_base[s + 1] = triangle_base[s] + slabs[s].triangles.size();
  }
  if (vertex_base[n] > std::numeric_limits<std::uint32_t>::max()) {
    throw ResourceLimit("cells", "marching cubes produced more than 2^32 vertices; use fewer cells");
  }
  Mesh mesh;
  mesh.vertices.resize(vertex_base[n]);
  if (normals) mesh.normals.resize(vertex_base[n]);
  mesh.triangles.resize(triangle_base[n]);
  parallel_for(static_cast<int>(n), threads, [&](int s) {
    SlabOutput& slab = slabs[s];
    slab.vertices.copy_to(mesh.vertices.data() + vertex_base[s]);
    if (normals) slab.normals.copy_to(mesh.normals.data() + vertex_base[s]);
    Triangle* out = mesh.triangles.data() + triangle_base[s];
    if (s == 0) {
      slab.triangles.copy_to(out);  // the first slab has no foreign ids
      return;
    }
    const auto own = static_cast<std::uint32_t>(vertex_base[s]);
    // Global id of the first vertex on the top point layer of the slab below.
    const auto foreign = static_cast<std::uint32_t>(vertex_base[s - 1] + slabs[s - 1].top_layer_start);
    slab.triangles.for_each([&](const Triangle& t) {
      for (int c = 0; c < 3; ++c) (*out)[c] = (t[c] & kForeign) ? foreign + (t[c] & ~kForeign) : own + t[c];
      ++out;
    });
  });
  return mesh;
}

template <class Source>
Mesh run(const Grid& grid, const Source& source, const MarchingCubesOptions& options, const RunControl& control) {
  const int nz = grid.cells[2];
  const int threads = std::min(resolve_threads(options.threads), nz);
  // A few slabs per thread balance uneven work; each extra slab re-reads one point layer.
  const int slabs = threads == 1 ? 1 : std::min(nz, threads * 2);
  std::vector<SlabOutput> out(slabs);
  Progress progress;
  TriangleCounter triangles(control, "marching cubes", "use fewer cells (a larger cell size)");
  control.report("polygonize", 0.0);
  parallel_for(slabs, threads, [&](int s) {
    const int k0 = static_cast<int>(static_cast<std::int64_t>(nz) * s / slabs);
    const int k1 = static_cast<int>(static_cast<std::int64_t>(nz) * (s + 1) / slabs);
    SlabMesher<Source> mesher(grid, source, options.normals, control, progress, triangles);
    out[s] = mesher.run(k0, k1);
  });
  return merge(out, options.normals, threads);
}

}  // namespace

Mesh marching_cubes(const Field& field, const MarchingCubesOptions& options, const RunControl& control) {
  validate(options);
  const Grid grid(options);
  FieldSource source{grid, field};
  if (options.sparse) source.lipschitz = field.lipschitz_bound();
  if (source.lipschitz && !(*source.lipschitz >= 0.0 && std::isfinite(*source.lipschitz))) source.lipschitz.reset();
  return run(grid, source, options, control);
}

std::int64_t marching_cubes_fixed_bytes(const MarchingCubesOptions& options) {
  // Per point of a z-layer: two layers of (double sample, inside byte, x-edge id, y-edge id) and a z-edge id.
  constexpr std::int64_t kBytesPerLayerPoint = 2 * (8 + 1 + 4 + 4) + 4;
  const std::int64_t layer = (std::int64_t{options.cells[0]} + 1) * (std::int64_t{options.cells[1]} + 1);
  const std::int64_t slabs = std::min<std::int64_t>(resolve_threads(options.threads), options.cells[2]);
  return slabs * layer * kBytesPerLayerPoint;
}

Mesh marching_cubes_samples(std::span<const float> samples, const MarchingCubesOptions& options,
                            const RunControl& control) {
  validate(options);
  const Grid grid(options);
  const std::size_t expected = grid.layer_size() * static_cast<std::size_t>(grid.points[2]);
  if (samples.size() != expected) {
    throw InvalidInput("samples", "samples has " + std::to_string(samples.size()) + " values but cells (" +
                                      std::to_string(grid.cells[0]) + ", " + std::to_string(grid.cells[1]) + ", " +
                                      std::to_string(grid.cells[2]) + ") needs " + std::to_string(expected) +
                                      " ((cells + 1) per axis, x fastest)");
  }
  return run(grid, SampleSource{grid, samples}, options, control);
}

}  // namespace surfacer
