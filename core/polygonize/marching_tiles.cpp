// Marching Tiles: marching tetrahedra over the A15 tiling (core/polygonize/a15_table.h), sparse, block-parallel,
// deterministic. The contract is in marching_tiles.h; this is how it is met.
//
// Lattice. Lattice units are the table's (cell edge 4); world = bounds.min + unit * lattice with
// unit = spacing / a15::kMeanEdge, so the mean tetrahedron edge equals `spacing`. Cell c holds the sites
// 4c + kPoints[p]; a point is inside the region when its lattice coordinates are <= max_coord (floor of the bounds'
// size / unit), and a tetrahedron is used only when its 4 points are. A tetrahedron's home cell c has its points in
// cells c + {0,1}^3, with lattice coordinates in [4c, 4c + 5] per axis.
//
// Blocks. Cells are grouped in blocks of kBlock^3. A block evaluates the field lazily into a padded array of
// (kBlock + 1)^3 cells (its own cells and the +x/+y/+z layer its tetrahedra reach), so the one halo point a block
// shares with its neighbour may be evaluated by both: the value is the same (same lattice coordinates, same
// arithmetic), only the count of evaluations grows (~10-20% of a block's points where the surface crosses faces).
// With a Lipschitz bound L (Field::lipschitz_bound) the block first runs an octree down to single cells and drops
// every cube whose reachable points lie within a ball of radius R around a point c with |f(c)| > L R: no sign change
// is possible there, so none of its tetrahedra is crossed (about one evaluation per output triangle remains).
//
// Which blocks. (1) seeds: the blocks whose reachable box is within seed_radius of a seed. (2) a Lipschitz bound:
// a kd-tree descent over the block grid, clipped to bounds and to field.bounds() (outside it f > 0), keeps the
// blocks no ball test can exclude; with a valid bound this misses nothing. (3) neither: the signs of the field at
// the corners of every 2x2x2-cell sub-block (clipped as above) are scanned, and blocks with a sign change among
// them are seeds; a component that changes no such corner's sign (smaller than ~3.5 spacings, or a thin sheet
// between corners) can be missed, and this scan costs volume / 64 lattice points. In every mode the set is then
// closed by flood fill: a block with a crossed tetrahedron in a boundary cell adds the neighbours across that
// boundary (every tetrahedron sharing an edge with it has its home cell within +-1 cell). So every crossed edge
// has all its tetrahedra in processed blocks, and the output is closed wherever it stays inside `bounds`,
// whichever components were found. Rounds of the flood run their blocks in parallel.
//
// Welding without seams. A crossed edge's vertex is created by one owner block: the block of the first valid
// tetrahedron in a fixed order of the tetrahedra around the edge (that tetrahedron is crossed, so its block is
// processed and creates it). Inside a block, an array indexed by (edge home cell, edge class) -- kept for the two
// z-layers of home cells the current cell layer reaches, so it stays in L1 -- gives each crossed edge one id; edges
// owned elsewhere get a "foreign" id (owner block, slot). The merge groups foreign ids by owner and answers them from
// the owner's (slot -> vertex) table laid out in a worker's array; no hash maps, no sorting of vertex lists. Blocks
// are concatenated along a Morton curve over the block grid (so a range of indices is a compact piece of surface),
// vertices and triangles in each block's creation order: the mesh is byte-identical whatever the thread count or
// scheduling.
//
// Triangles. For each crossed tetrahedron (case = inside bits; 0 counts as outside) one triangle (1 or 3 inside) or
// a quad split along its shorter diagonal (2 inside), oriented outward (toward increasing f): the orientation is
// fixed per (tetrahedron, case) from the table's geometry and cannot flip for any interpolation parameter in (0, 1).
// The parameter is clamped to [kMinT, 1 - kMinT], so a zero sample never puts several vertices on one point (no
// zero-area triangles); it moves such a vertex by at most kMinT of its edge.
#include "core/polygonize/marching_tiles.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <mutex>
#include <numeric>
#include <string>
#include <unordered_set>
#include <vector>

#include "core/polygonize/a15_table.h"
#include "core/polygonize/edge_margin.h"
#include "core/scene/scene.h"
#include "core/util/errors.h"
#include "core/util/parallel.h"
#include "core/util/triangle_limit.h"

namespace surfacer {
namespace {

constexpr int kBlock = 8;                              // cells per block edge
constexpr int kPad = kBlock + 1;                       // padded cells per block edge
constexpr int kPadCells = kPad * kPad * kPad;          // 729
constexpr int kBlockCells = kBlock * kBlock * kBlock;  // 512
constexpr int kSub = 2;             // cells between the corners of the sign scan (fields without a Lipschitz bound)
constexpr int kCullCell = 1;        // smallest cube the Lipschitz cull tests, in cells
constexpr int kInsideCullCell = 4;  // smallest cube a field's inside test is asked about (without a Lipschitz bound)
constexpr int kReach = 5;           // tetrahedra of home cell c reach lattice 4c + 5
constexpr int kSlots = kPadCells * a15::kEdgeCount;  // edge slots of a block
constexpr int kRingSlots = 2 * kPad * kPad * a15::kEdgeCount;
constexpr double kMinT = 1e-3;              // clamp of the interpolation parameter
constexpr double kBallMargin = 1.0 + 1e-9;  // relative safety on Lipschitz radii
constexpr std::uint32_t kNone = 0xffffffffu;
constexpr std::uint32_t kForeign = 0x80000000u;

// --- Tables derived once from a15_table.h ------------------------------------------------------------------------

// Tetrahedron-local edges in a15::kTetEdges order.
constexpr int kEdgeEnds[6][2] = {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}};

struct Case {
  std::uint8_t count = 0;            // 0 (no crossing), 3 (triangle) or 4 (quad)
  std::array<std::uint8_t, 4> edge;  // tetrahedron-local edges, counter-clockwise seen from outside
};

struct RingTet {
  std::array<int, 3> offset;  // home cell relative to the edge's home cell, in {-1, 0}^3
  int tet;
};

// Per tetrahedron-local edge, relative to the tetrahedron's home cell: what the marcher needs without looking at
// the a15 tables again.
struct EdgeInfo {
  std::int32_t slot = 0;                 // (pad-index offset of the edge's home cell) * kEdgeCount + class
  std::int32_t ring_slot = 0;            // (in-layer pad-index offset of the home cell) * kEdgeCount + class
  std::int32_t ring_dk = 0;              // z offset of the home cell (0 or 1)
  std::array<std::int8_t, 3> owner{};    // interior owner cell (first ring tetrahedron's home) minus this home
  std::array<std::uint16_t, 2> value{};  // pad-value offsets (8 * pad-index offset + point) of ends a, b
  std::array<std::array<std::uint8_t, 3>, 2> lattice{};  // lattice coordinates of ends a, b minus 4 * home
};

struct Tables {
  std::array<std::array<std::uint8_t, 4>, a15::kTetCount> bit{};  // 8 * offset index + point, per vertex
  std::array<std::uint64_t, a15::kTetCount> tet_mask{};           // the 4 bits of each tetrahedron
  std::array<std::array<EdgeInfo, 6>, a15::kTetCount> edges{};
  std::uint64_t cell_mask = 0;                             // union of every tetrahedron's bits
  std::array<std::uint8_t, 8> offset_points{};             // points read in cell home + offset
  std::array<std::array<int, 3>, a15::kTetCount> reach{};  // max lattice coordinate - 4 * home, per axis
  std::array<std::array<Case, 16>, a15::kTetCount> cases{};
  std::array<std::vector<RingTet>, a15::kEdgeCount> ring;  // tetrahedra around each edge, fixed order

  Tables() {
    for (int t = 0; t < a15::kTetCount; ++t) {
      std::array<Vec3, 4> pos;
      for (int v = 0; v < 4; ++v) {
        const a15::Site& s = a15::kTets[t][v];
        const int oi = s.offset[0] + 2 * s.offset[1] + 4 * s.offset[2];
        bit[t][v] = static_cast<std::uint8_t>(8 * oi + s.point);
        cell_mask |= std::uint64_t{1} << bit[t][v];
        tet_mask[t] |= std::uint64_t{1} << bit[t][v];
        offset_points[oi] |= static_cast<std::uint8_t>(1u << s.point);
        for (int a = 0; a < 3; ++a) {
          const int l = 4 * s.offset[a] + a15::kPoints[s.point][a];
          pos[v][a] = l;
          reach[t][a] = std::max(reach[t][a], l);
          // The culling boxes assume every tetrahedron stays within [4 home, 4 home + kReach].
          if (l > kReach) throw Internal("a15 table: a tetrahedron reaches beyond kReach lattice units");
        }
      }
      for (int c = 1; c < 15; ++c) cases[t][c] = make_case(pos, c);
      for (int e = 0; e < 6; ++e) {
        const a15::TetEdge& te = a15::kTetEdges[t][e];
        ring[te.edge].push_back(RingTet{{-te.home[0], -te.home[1], -te.home[2]}, t});
      }
    }
    for (auto& r : ring) {
      std::sort(r.begin(), r.end(), [](const RingTet& a, const RingTet& b) {
        if (a.offset[2] != b.offset[2]) return a.offset[2] > b.offset[2];
        if (a.offset[1] != b.offset[1]) return a.offset[1] > b.offset[1];
        if (a.offset[0] != b.offset[0]) return a.offset[0] > b.offset[0];
        return a.tet < b.tet;
      });
    }
    for (int t = 0; t < a15::kTetCount; ++t) {
      for (int e = 0; e < 6; ++e) {
        const a15::TetEdge& te = a15::kTetEdges[t][e];
        EdgeInfo& info = edges[t][e];
        info.slot = (te.home[0] + kPad * te.home[1] + kPad * kPad * te.home[2]) * a15::kEdgeCount + te.edge;
        info.ring_slot = (te.home[0] + kPad * te.home[1]) * a15::kEdgeCount + te.edge;
        info.ring_dk = te.home[2];
        for (int a = 0; a < 3; ++a) info.owner[a] = static_cast<std::int8_t>(te.home[a] + ring[te.edge][0].offset[a]);
        int ends[2] = {kEdgeEnds[e][0], kEdgeEnds[e][1]};
        if (!te.a_first) std::swap(ends[0], ends[1]);
        for (int n = 0; n < 2; ++n) {
          const a15::Site& site = a15::kTets[t][ends[n]];
          info.value[n] = static_cast<std::uint16_t>(
              8 * (site.offset[0] + kPad * site.offset[1] + kPad * kPad * site.offset[2]) + site.point);
          for (int a = 0; a < 3; ++a) {
            info.lattice[n][a] = static_cast<std::uint8_t>(4 * site.offset[a] + a15::kPoints[site.point][a]);
          }
        }
      }
    }
  }

  static int local_edge(int a, int b) {
    if (a > b) std::swap(a, b);
    for (int e = 0; e < 6; ++e) {
      if (kEdgeEnds[e][0] == a && kEdgeEnds[e][1] == b) return e;
    }
    return -1;
  }

  // Case `c` (bit v: vertex v inside) of a tetrahedron with vertex positions pos: the crossed edges in an order
  // whose polygon normal points from the inside vertices to the outside ones (checked on the edge midpoints; the
  // sign cannot change for other interpolation parameters because no polygon vertex can reach an inside vertex's
  // plane through the others).
  static Case make_case(const std::array<Vec3, 4>& pos, int c) {
    std::vector<int> in, out;
    for (int v = 0; v < 4; ++v) ((c >> v) & 1 ? in : out).push_back(v);
    Case result;
    std::vector<std::pair<int, int>> ends;
    if (in.size() == 1) {
      for (int o : out) ends.emplace_back(in[0], o);
    } else if (in.size() == 3) {
      for (int i : in) ends.emplace_back(i, out[0]);
    } else {
      ends = {{in[0], out[0]}, {in[0], out[1]}, {in[1], out[1]}, {in[1], out[0]}};
    }
    std::vector<Vec3> mid;
    mid.reserve(ends.size());
    for (auto [a, b] : ends) mid.push_back(0.5 * (pos[a] + pos[b]));
    Vec3 in_c = Vec3::Zero(), out_c = Vec3::Zero();
    for (int i : in) in_c += pos[i] / static_cast<double>(in.size());
    for (int o : out) out_c += pos[o] / static_cast<double>(out.size());
    const Vec3 normal = (mid[1] - mid[0]).cross(mid[2] - mid[0]);
    if (normal.dot(out_c - in_c) < 0.0) std::reverse(ends.begin(), ends.end());
    result.count = static_cast<std::uint8_t>(ends.size());
    for (std::size_t i = 0; i < ends.size(); ++i) {
      result.edge[i] = static_cast<std::uint8_t>(local_edge(ends[i].first, ends[i].second));
    }
    return result;
  }
};

const Tables& tables() {
  static const Tables t;
  return t;
}

// --- Lattice -----------------------------------------------------------------------------------------------------

struct Lattice {
  Vec3 origin;
  double unit = 0.0;                        // world units per lattice unit
  std::array<std::int64_t, 3> max_coord{};  // largest lattice coordinate inside bounds, per axis
  std::array<std::int64_t, 3> cells{};      // cells with their corner inside bounds
  std::array<std::int64_t, 3> blocks{};

  double world(int axis, std::int64_t l) const { return origin[axis] + unit * static_cast<double>(l); }
  std::uint64_t key(std::int64_t bx, std::int64_t by, std::int64_t bz) const {
    return static_cast<std::uint64_t>((bz * blocks[1] + by) * blocks[0] + bx);
  }
  std::array<std::int64_t, 3> block_of_key(std::uint64_t key) const {
    const auto k = static_cast<std::int64_t>(key);
    return {k % blocks[0], (k / blocks[0]) % blocks[1], k / (blocks[0] * blocks[1])};
  }
  // A tetrahedron of home cell h is used when all its points are inside the region.
  bool tet_valid(const std::array<std::int64_t, 3>& h, int t) const {
    const auto& reach = tables().reach[t];
    for (int a = 0; a < 3; ++a) {
      if (h[a] < 0 || 4 * h[a] + reach[a] > max_coord[a]) return false;
    }
    return true;
  }
};

// Box of the lattice range [lo, hi] (lattice units, per axis) in world units, clipped to `clip`. Empty (nullopt)
// when they do not meet.
std::optional<Aabb> clipped_box(const Lattice& lat, const std::array<std::int64_t, 3>& lo,
                                const std::array<std::int64_t, 3>& hi, const Aabb& clip) {
  Aabb box;
  for (int a = 0; a < 3; ++a) {
    box.min[a] = std::max(lat.world(a, lo[a]), clip.min[a]);
    box.max[a] = std::min(lat.world(a, hi[a]), clip.max[a]);
    if (box.min[a] > box.max[a]) return std::nullopt;
  }
  return box;
}

// True when the Lipschitz ball test proves f has one strict sign on `box`. Counts one evaluation.
bool ball_excludes(const Field& field, double lipschitz, const Aabb& box) {
  const Vec3 center = 0.5 * (box.min + box.max);
  const double radius = 0.5 * (box.max - box.min).norm();
  const double f = field.value(center);
  return std::abs(f) > lipschitz * radius * kBallMargin;
}

// --- Per-block work ----------------------------------------------------------------------------------------------

struct ForeignRef {
  std::uint64_t block;
  std::uint32_t slot;
};

struct BlockOutput {
  std::uint64_t key = 0;
  std::vector<Vec3> vertices;
  std::vector<Vec3> normals;
  std::vector<std::uint32_t> vertex_slots;  // slot of each vertex, creation order
  std::vector<Triangle> triangles;          // local ids, or kForeign | index into `foreign`
  std::vector<ForeignRef> foreign;
  std::uint32_t neighbours = 0;  // bit (dx+1) + 3 (dy+1) + 9 (dz+1): blocks the flood must add
};

struct alignas(64) Scratch {
  std::vector<double> values = std::vector<double>(static_cast<std::size_t>(kPadCells) * 8);
  std::array<std::uint8_t, kPadCells> evaluated{};  // bit p: point p of the padded cell has a value
  std::array<std::uint8_t, kPadCells> exact{};      // bit p: that value is value(), not only sign_value()
  std::array<std::uint8_t, kPadCells> valid{};      // bit p: inside bounds
  std::array<std::uint8_t, kPadCells> inside{};     // bit p: value < 0
  std::array<std::uint8_t, kBlockCells> active{};   // cell not culled
  // Vertex ids of the edges whose home cells lie in the two z-layers the current cell layer k reaches (k, k + 1),
  // at [(home z & 1) * kPad^2 + in-layer pad index] * kEdgeCount + class: small enough to stay in L1.
  std::vector<std::uint32_t> ring = std::vector<std::uint32_t>(kRingSlots, kNone);
  std::array<std::vector<std::uint32_t>, 2> ring_touched;
  std::vector<std::uint32_t> slots = std::vector<std::uint32_t>(kSlots, kNone);  // merge: owner slot -> vertex
  std::vector<Vec3> foreign_positions;  // of the block's foreign vertices, by foreign index
  struct Sizes {
    std::size_t vertices = 0, triangles = 0, foreign = 0;
  } last;  // output sizes of the worker's previous block
};

constexpr int pad_index(int i, int j, int k) { return (k * kPad + j) * kPad + i; }
constexpr std::array<int, 8> kOffsetDelta = {
    0, 1, kPad, kPad + 1, kPad* kPad, kPad* kPad + 1, kPad* kPad + kPad, kPad* kPad + kPad + 1};

class BlockMesher {
 public:
  BlockMesher(const Lattice& lat, const Field& field, const MarchingTilesOptions& options,
              std::optional<double> lipschitz, const RunControl& control)
      : lat_(lat),
        field_(field),
        options_(options),
        lipschitz_(lipschitz),
        control_(control),
        tab_(tables()),
        sign_only_(field.sign_is_cheaper()),
        inside_boxes_(field.answers_inside_boxes()) {}

  void run(std::uint64_t key, Scratch& s, BlockOutput& out) {
    out.key = key;
    const std::array<std::int64_t, 3> b = lat_.block_of_key(key);
    for (int a = 0; a < 3; ++a) c0_[a] = b[a] * kBlock;
    // Interior: every tetrahedron around an edge of this block's tetrahedra (home cells c0 - 1 .. c0 + kBlock) is
    // valid, so each edge's owner is its first ring tetrahedron.
    interior_ = true;
    for (int a = 0; a < 3; ++a) {
      interior_ = interior_ && c0_[a] >= 1 && 4 * (c0_[a] + kBlock) + kReach <= lat_.max_coord[a];
    }
    prepare(s);
    cull(s);
    evaluate(s);
    // Reserve what the worker's previous block needed (plus a margin), so the vectors rarely regrow.
    Scratch::Sizes& last = s.last;
    out.vertices.reserve(last.vertices + last.vertices / 4 + 16);
    if (options_.normals) out.normals.reserve(last.vertices + last.vertices / 4 + 16);
    out.vertex_slots.reserve(last.vertices + last.vertices / 4 + 16);
    out.triangles.reserve(last.triangles + last.triangles / 4 + 32);
    out.foreign.reserve(last.foreign + last.foreign / 4 + 16);
    march(s, out);
    last = {out.vertices.size(), out.triangles.size(), out.foreign.size()};
    for (auto& touched : s.ring_touched) {
      for (std::uint32_t slot : touched) s.ring[slot] = kNone;
      touched.clear();
    }
    s.foreign_positions.clear();
  }

 private:
  Vec3 point_position(int i, int j, int k, int p) const {
    const auto& q = a15::kPoints[p];
    return Vec3(lat_.world(0, 4 * (c0_[0] + i) + q[0]), lat_.world(1, 4 * (c0_[1] + j) + q[1]),
                lat_.world(2, 4 * (c0_[2] + k) + q[2]));
  }

  void prepare(Scratch& s) {
    std::array<std::array<std::uint8_t, kPad>, 3> axis_valid{};
    for (int a = 0; a < 3; ++a) {
      for (int i = 0; i < kPad; ++i) {
        std::uint8_t m = 0;
        for (int p = 0; p < 8; ++p) {
          if (4 * (c0_[a] + i) + a15::kPoints[p][a] <= lat_.max_coord[a]) m |= static_cast<std::uint8_t>(1u << p);
        }
        axis_valid[a][i] = m;
      }
    }
    for (int k = 0; k < kPad; ++k) {
      for (int j = 0; j < kPad; ++j) {
        const std::uint8_t m = axis_valid[1][j] & axis_valid[2][k];
        std::uint8_t* row = s.valid.data() + pad_index(0, j, k);
        for (int i = 0; i < kPad; ++i) row[i] = m & axis_valid[0][i];
      }
    }
    s.evaluated.fill(0);
    s.exact.fill(0);
    s.inside.fill(0);
  }

  // Marks the cells that the Lipschitz test, or the field's inside test, cannot exclude (every cell when the field
  // offers neither).
  void cull(Scratch& s) {
    if (!lipschitz_ && !inside_boxes_) {
      s.active.fill(1);
      return;
    }
    s.active.fill(0);
    cull_cube(s, {0, 0, 0}, kBlock);
  }

  // Octree over the block's cells: a cube of `size` cells at `lo` is dropped when the Lipschitz ball around the box
  // its tetrahedra reach excludes a sign change, or when the field knows the box to be inside everywhere; otherwise
  // its octants are tested, down to kCullCell cells (kInsideCullCell for the inside test alone: below that its
  // answers cost more than the cells they skip).
  void cull_cube(Scratch& s, const std::array<int, 3>& lo, int size) {
    std::array<std::int64_t, 3> llo, lhi;
    for (int a = 0; a < 3; ++a) {
      llo[a] = 4 * (c0_[a] + lo[a]);
      lhi[a] = 4 * (c0_[a] + lo[a] + size - 1) + kReach;
    }
    const std::optional<Aabb> box = clipped_box(lat_, llo, lhi, options_.bounds);
    if (!box || (lipschitz_ && ball_excludes(field_, *lipschitz_, *box)) ||
        (inside_boxes_ && field_.inside_everywhere(*box))) {
      return;
    }
    if (size <= (lipschitz_ ? kCullCell : kInsideCullCell)) {
      for (int k = lo[2]; k < lo[2] + size; ++k) {
        for (int j = lo[1]; j < lo[1] + size; ++j) {
          for (int i = lo[0]; i < lo[0] + size; ++i) s.active[(k * kBlock + j) * kBlock + i] = 1;
        }
      }
      return;
    }
    if (size == kBlock) control_.check();
    const int half = size / 2;
    for (int o = 0; o < 8; ++o) {
      cull_cube(s, {lo[0] + (o & 1) * half, lo[1] + ((o >> 1) & 1) * half, lo[2] + (o >> 2) * half}, half);
    }
  }

  // Values of every valid point an active cell's tetrahedra read.
  void evaluate(Scratch& s) {
    for (int k = 0; k < kBlock; ++k) {
      control_.check();
      for (int j = 0; j < kBlock; ++j) {
        for (int i = 0; i < kBlock; ++i) {
          if (!s.active[(k * kBlock + j) * kBlock + i]) continue;
          const int pc = pad_index(i, j, k);
          for (int oi = 0; oi < 8; ++oi) {
            const int n = pc + kOffsetDelta[oi];
            unsigned need = tab_.offset_points[oi] & s.valid[n] & ~s.evaluated[n];
            if (need == 0) continue;
            s.evaluated[n] |= static_cast<std::uint8_t>(need);
            const int ni = i + (oi & 1), nj = j + ((oi >> 1) & 1), nk = k + (oi >> 2);
            double* v = s.values.data() + static_cast<std::size_t>(n) * 8;
            std::uint8_t in = 0;
            if (!sign_only_) s.exact[n] |= static_cast<std::uint8_t>(need);
            while (need != 0) {
              const int p = std::countr_zero(need);
              need &= need - 1;
              const Vec3 x = point_position(ni, nj, nk, p);
              v[p] = sign_only_ ? field_.sign_value(x) : field_.value(x);
              if (v[p] < 0.0) in |= static_cast<std::uint8_t>(1u << p);
            }
            s.inside[n] |= in;
          }
        }
      }
    }
  }

  void march(Scratch& s, BlockOutput& out) {
    const std::uint64_t mask = tab_.cell_mask;
    for (int k = 0; k < kBlock; ++k) {
      control_.check();
      // Home layer k - 1 is out of reach from now on; its ring half becomes home layer k + 1's.
      auto& stale = s.ring_touched[(k + 1) & 1];
      for (std::uint32_t slot : stale) s.ring[slot] = kNone;
      stale.clear();
      for (int j = 0; j < kBlock; ++j) {
        for (int i = 0; i < kBlock; ++i) {
          if (!s.active[(k * kBlock + j) * kBlock + i]) continue;
          const int pc = pad_index(i, j, k);
          std::uint64_t w = 0, v = 0;
          for (int oi = 0; oi < 8; ++oi) {
            w |= static_cast<std::uint64_t>(s.inside[pc + kOffsetDelta[oi]]) << (8 * oi);
            v |= static_cast<std::uint64_t>(s.valid[pc + kOffsetDelta[oi]]) << (8 * oi);
          }
          const bool all_valid = (v & mask) == mask;
          if (all_valid && ((w & mask) == 0 || (w & mask) == mask)) continue;
          march_cell(s, out, i, j, k, w, v, all_valid);
        }
      }
    }
  }

  void march_cell(Scratch& s, BlockOutput& out, int i, int j, int k, std::uint64_t w, std::uint64_t v, bool all_valid) {
    bool crossed = false;
    const int pc = pad_index(i, j, k);
    for (int t = 0; t < a15::kTetCount; ++t) {
      const std::uint64_t m = tab_.tet_mask[t];
      const std::uint64_t x = w & m;
      if (x == 0 || x == m) continue;
      if (!all_valid && (v & m) != m) continue;
      const auto& bit = tab_.bit[t];
      const unsigned c = static_cast<unsigned>(((w >> bit[0]) & 1) | (((w >> bit[1]) & 1) << 1) |
                                               (((w >> bit[2]) & 1) << 2) | (((w >> bit[3]) & 1) << 3));
      crossed = true;
      const Case& cs = tab_.cases[t][c];
      std::array<std::uint32_t, 4> id;
      for (int e = 0; e < cs.count; ++e) id[e] = edge_vertex(s, out, pc, i, j, k, t, cs.edge[e]);
      if (cs.count == 3) {
        out.triangles.push_back(Triangle{id[0], id[1], id[2]});
        continue;
      }
      // Quad: split along the shorter diagonal.
      const auto pos = [&](std::uint32_t q) -> const Vec3& {
        return (q & kForeign) ? s.foreign_positions[q & ~kForeign] : out.vertices[q];
      };
      if ((pos(id[2]) - pos(id[0])).squaredNorm() <= (pos(id[3]) - pos(id[1])).squaredNorm()) {
        out.triangles.push_back(Triangle{id[0], id[1], id[2]});
        out.triangles.push_back(Triangle{id[0], id[2], id[3]});
      } else {
        out.triangles.push_back(Triangle{id[1], id[2], id[3]});
        out.triangles.push_back(Triangle{id[1], id[3], id[0]});
      }
    }
    if (crossed) {
      // Tetrahedra sharing an edge with this cell's have home cells within +-1: add the blocks across the faces
      // this cell touches.
      const std::array<int, 3> c{i, j, k};
      std::array<std::array<int, 3>, 3> dirs{};
      std::array<int, 3> count{};
      for (int a = 0; a < 3; ++a) {
        dirs[a][count[a]++] = 0;
        if (c[a] == 0) dirs[a][count[a]++] = -1;
        if (c[a] == kBlock - 1) dirs[a][count[a]++] = 1;
      }
      for (int z = 0; z < count[2]; ++z) {
        for (int y = 0; y < count[1]; ++y) {
          for (int x = 0; x < count[0]; ++x) {
            out.neighbours |= 1u << ((dirs[0][x] + 1) + 3 * (dirs[1][y] + 1) + 9 * (dirs[2][z] + 1));
          }
        }
      }
    }
  }

  // value() at the point behind values[index] (8 * pad index + point), computed once when the evaluation pass asked
  // only sign_value().
  double exact_value(Scratch& s, std::size_t index) const {
    const std::size_t n = index / 8;
    const auto bit = static_cast<std::uint8_t>(1u << (index % 8));
    if (!(s.exact[n] & bit)) {
      const int pi = static_cast<int>(n % kPad), pj = static_cast<int>(n / kPad % kPad),
                pk = static_cast<int>(n / (kPad * kPad));
      s.values[index] = field_.value(point_position(pi, pj, pk, static_cast<int>(index % 8)));
      s.exact[n] |= bit;
    }
    return s.values[index];
  }

  // The interpolated point on an edge, from its end a to its end b (every block computes the same numbers);
  // `param` receives the interpolation parameter.
  Vec3 edge_point(Scratch& s, int pc, int i, int j, int k, const EdgeInfo& info, double& param) const {
    const double fa = exact_value(s, static_cast<std::size_t>(pc) * 8 + info.value[0]);
    const double fb = exact_value(s, static_cast<std::size_t>(pc) * 8 + info.value[1]);
    const std::array<std::int64_t, 3> base{4 * (c0_[0] + i), 4 * (c0_[1] + j), 4 * (c0_[2] + k)};
    Vec3 xa, xb;
    for (int a = 0; a < 3; ++a) {
      xa[a] = lat_.world(a, base[a] + info.lattice[0][a]);
      xb[a] = lat_.world(a, base[a] + info.lattice[1][a]);
    }
    const double floor = std::max(kMinT, edge_parameter_floor(options_.vertex_margin, (xb - xa).norm()));
    param = std::clamp(fa / (fa - fb), floor, 1.0 - floor);
    Vec3 p;
    for (int a = 0; a < 3; ++a) p[a] = xa[a] + param * (xb[a] - xa[a]);
    return p;
  }

  std::uint32_t edge_vertex(Scratch& s, BlockOutput& out, int pc, int i, int j, int k, int t, int e) {
    const EdgeInfo& info = tab_.edges[t][e];
    const int half = (k + info.ring_dk) & 1;
    const auto ring_slot =
        static_cast<std::uint32_t>((half * kPad * kPad + j * kPad + i) * a15::kEdgeCount + info.ring_slot);
    std::uint32_t& id = s.ring[ring_slot];
    if (id != kNone) return id;
    s.ring_touched[half].push_back(ring_slot);
    const auto slot = static_cast<std::uint32_t>(pc * a15::kEdgeCount + info.slot);
    // Owner: the cell of the first valid tetrahedron around the edge, relative to this block.
    std::array<int, 3> owner{i + info.owner[0], j + info.owner[1], k + info.owner[2]};
    if (!interior_) owner = boundary_owner(i, j, k, t, e);
    const bool own =
        owner[0] >= 0 && owner[0] < kBlock && owner[1] >= 0 && owner[1] < kBlock && owner[2] >= 0 && owner[2] < kBlock;
    double param = 0.0;
    const Vec3 p = edge_point(s, pc, i, j, k, info, param);
    if (!own) {
      const a15::TetEdge& te = a15::kTetEdges[t][e];
      std::array<std::int64_t, 3> owner_block{};
      std::array<int, 3> local{};
      for (int a = 0; a < 3; ++a) {
        const int d = owner[a] < 0 ? -1 : (owner[a] >= kBlock ? 1 : 0);
        owner_block[a] = c0_[a] / kBlock + d;
        local[a] = (a == 0 ? i : a == 1 ? j : k) + te.home[a] - d * kBlock;  // edge home in the owner block
      }
      const auto owner_slot =
          static_cast<std::uint32_t>(pad_index(local[0], local[1], local[2]) * a15::kEdgeCount + te.edge);
      id = kForeign | static_cast<std::uint32_t>(out.foreign.size());
      out.foreign.push_back(ForeignRef{lat_.key(owner_block[0], owner_block[1], owner_block[2]), owner_slot});
      s.foreign_positions.push_back(p);
      return id;
    }
    if (out.vertices.size() >= kForeign) {
      throw ResourceLimit("spacing",
                          "marching tiles produced more than 2^31 vertices in one block; use a larger spacing");
    }
    id = static_cast<std::uint32_t>(out.vertices.size());
    out.vertices.push_back(p);
    out.vertex_slots.push_back(slot);
    if (options_.normals) {
      Vec3 g;
      field_.value_and_gradient(p, g);
      const double len = g.norm();
      if (len > 0.0 && std::isfinite(len)) {
        g /= len;
      } else {  // flat or broken gradient: the edge direction from its inside end to its outside end
        for (int a = 0; a < 3; ++a) g[a] = static_cast<double>(info.lattice[1][a]) - info.lattice[0][a];
        if (s.values[static_cast<std::size_t>(pc) * 8 + info.value[0]] >= 0.0) g = -g;
        g.normalize();
      }
      out.normals.push_back(g);
    }
    return id;
  }

  // Near the region's boundary some tetrahedra around an edge are not used: the owner is the home cell of the first
  // valid one in ring order (relative to this block).
  std::array<int, 3> boundary_owner(int i, int j, int k, int t, int e) const {
    const a15::TetEdge& te = a15::kTetEdges[t][e];
    const std::array<int, 3> home{i + te.home[0], j + te.home[1], k + te.home[2]};
    for (const RingTet& r : tab_.ring[te.edge]) {
      std::array<std::int64_t, 3> cell{};
      for (int a = 0; a < 3; ++a) cell[a] = c0_[a] + home[a] + r.offset[a];
      if (lat_.tet_valid(cell, r.tet)) return {home[0] + r.offset[0], home[1] + r.offset[1], home[2] + r.offset[2]};
    }
    throw Internal("marching tiles: a crossed edge has no valid tetrahedron");
  }

  const Lattice& lat_;
  const Field& field_;
  const MarchingTilesOptions& options_;
  const std::optional<double> lipschitz_;
  const RunControl& control_;
  const Tables& tab_;
  const bool sign_only_;     // the evaluation pass asks sign_value(); crossed edges' ends get value()
  const bool inside_boxes_;  // the cull asks field_.inside_everywhere()
  std::array<std::int64_t, 3> c0_{};
  bool interior_ = false;
};

// --- Parallel loop with per-worker scratch -------------------------------------------------------------------------

// Runs body(item, worker) for items [0, n) on `threads` workers; worker indexes a per-worker scratch. Items are
// handed out from a shared counter; the first exception stops the hand-out and is rethrown after the join.
template <class Body>
void for_each_item(int n, int threads, Body&& body) {
  if (n <= 0) return;
  const int workers = std::clamp(threads, 1, n);
  std::atomic<int> next{0};
  std::atomic<bool> failed{false};
  parallel_for(workers, workers, [&](int worker) {
    try {
      while (!failed.load(std::memory_order_relaxed)) {
        const int i = next.fetch_add(1, std::memory_order_relaxed);
        if (i >= n) return;
        body(i, worker);
      }
    } catch (...) {
      failed.store(true, std::memory_order_relaxed);
      throw;
    }
  });
}

// Non-decreasing progress over a growing amount of work.
class Progress {
 public:
  explicit Progress(const RunControl& control) : control_(control) {}
  void update(std::int64_t done, std::int64_t total) {
    std::lock_guard lock(mutex_);
    const double f = total > 0 ? std::min(1.0, static_cast<double>(done) / static_cast<double>(total)) : 0.0;
    if (f > last_) {
      last_ = f;
      control_.report("polygonize", 0.05 + 0.9 * f);
    }
  }

 private:
  const RunControl& control_;
  std::mutex mutex_;
  double last_ = 0.0;
};

// --- Seeding -------------------------------------------------------------------------------------------------------

void validate(const MarchingTilesOptions& o) {
  const Aabb& b = o.bounds;
  if (!b.min.allFinite() || !b.max.allFinite() || !b.valid()) {
    throw InvalidInput("bounds", "bounds.min must be < bounds.max on every axis and both finite; got min " +
                                     format_point(b.min) + " max " + format_point(b.max));
  }
  if (!std::isfinite(o.spacing) || !(o.spacing > 0.0)) {
    throw InvalidInput("spacing", "spacing (" + format_number(o.spacing) +
                                      ") must be a finite number > 0: the mean distance between lattice samples");
  }
  check_vertex_margin(o.vertex_margin);
  if (o.threads < 0) {
    throw InvalidInput("threads",
                       "threads (" + std::to_string(o.threads) + ") must be >= 0; 0 uses every hardware thread");
  }
  if (!std::isfinite(o.seed_radius) || o.seed_radius < 0.0) {
    throw InvalidInput("seed_radius", "seed_radius (" + format_number(o.seed_radius) + ") must be finite and >= 0");
  }
  if (!o.seeds.empty() && !(o.seed_radius > 0.0)) {
    throw InvalidInput("seed_radius",
                       "seed_radius must be > 0 when seeds are given: the distance from a seed beyond "
                       "which the field is outside (> 0)");
  }
  if (o.search != TileSearch::kAuto && o.search != TileSearch::kLipschitz && o.search != TileSearch::kSignScan) {
    throw InvalidInput("search", "search is not a known TileSearch value; use kAuto, kLipschitz or kSignScan");
  }
  for (std::size_t i = 0; i < o.seeds.size(); ++i) {
    if (!o.seeds[i].allFinite()) {
      throw InvalidInput("seeds[" + std::to_string(i) + "]", "seeds[" + std::to_string(i) + "] is not finite");
    }
  }
  if (!o.seed_radii.empty() && o.seed_radii.size() != o.seeds.size()) {
    throw InvalidInput("seed_radii", "seed_radii has " + std::to_string(o.seed_radii.size()) + " values for " +
                                         std::to_string(o.seeds.size()) + " seeds; give one per seed, or none");
  }
  for (std::size_t i = 0; i < o.seed_radii.size(); ++i) {
    if (!(std::isfinite(o.seed_radii[i]) && o.seed_radii[i] >= 0.0)) {
      throw InvalidInput(
          "seed_radii[" + std::to_string(i) + "]",
          "seed_radii[" + std::to_string(i) + "] (" + format_number(o.seed_radii[i]) + ") must be finite and >= 0");
    }
  }
}

Lattice make_lattice(const MarchingTilesOptions& o) {
  Lattice lat;
  lat.origin = o.bounds.min;
  lat.unit = o.spacing / a15::kMeanEdge;
  constexpr double kLimit = 2147483647.0;  // lattice coordinates stay below 2^31 per axis
  double total_blocks = 1.0;
  for (int a = 0; a < 3; ++a) {
    const double extent = std::floor(o.bounds.size()[a] / lat.unit);
    if (!(extent < kLimit)) {
      throw ResourceLimit("spacing", "the lattice would need " + std::to_string(extent) +
                                         " > 2^31 points along one axis; use a larger spacing or smaller bounds");
    }
    lat.max_coord[a] = static_cast<std::int64_t>(extent);
    lat.cells[a] = lat.max_coord[a] / 4 + 1;
    lat.blocks[a] = (lat.cells[a] + kBlock - 1) / kBlock;
    total_blocks *= static_cast<double>(lat.blocks[a]);
  }
  if (total_blocks > 4.0e18) {
    throw ResourceLimit("spacing", "the lattice would need more than 4e18 blocks; use a larger spacing");
  }
  return lat;
}

// Lattice box reached by the tetrahedra of blocks [lo, hi) (block indices).
void block_range_lattice(const std::array<std::int64_t, 3>& lo, const std::array<std::int64_t, 3>& hi,
                         std::array<std::int64_t, 3>& llo, std::array<std::int64_t, 3>& lhi) {
  for (int a = 0; a < 3; ++a) {
    llo[a] = std::int64_t{4} * kBlock * lo[a];
    lhi[a] = 4 * (kBlock * hi[a] - 1) + kReach;
  }
}

// The region where the surface can be: bounds, clipped to the field's solid box (outside it f > 0) when known.
// nullopt when empty.
std::optional<Aabb> search_region(const Field& field, const MarchingTilesOptions& o) {
  Aabb region = o.bounds;
  if (const std::optional<Aabb> solid = field.bounds()) {
    const double pad = 1e-9 * std::max(1.0, (o.bounds.max - o.bounds.min).norm());
    for (int a = 0; a < 3; ++a) {
      region.min[a] = std::max(region.min[a], solid->min[a] - pad);
      region.max[a] = std::min(region.max[a], solid->max[a] + pad);
      if (region.min[a] > region.max[a]) return std::nullopt;
    }
  }
  return region;
}

// Calls add(key) for every block whose reachable box lies within o.seed_radius (+ o.seed_radii[i]) of seed i and
// that known(key) does not report as added already (the same block may still come more than once).
template <class Known, class Add>
void blocks_near_seed(const Lattice& lat, const MarchingTilesOptions& o, std::size_t i, const RunControl& control,
                      Known&& known, Add&& add) {
  const Vec3& seed = o.seeds[i];
  const double r = o.seed_radius + (o.seed_radii.empty() ? 0.0 : o.seed_radii[i]);
  const double block_world = 4.0 * kBlock * lat.unit;
  std::array<std::int64_t, 3> lo, hi;
  for (int a = 0; a < 3; ++a) {
    // A block b reaches lattice [4 kBlock b, 4 kBlock (b + 1) + 1]: meets [s - r, s + r] for b in this range.
    const double l = (seed[a] - r - lat.origin[a]) / block_world - (kReach - 4.0) / (4.0 * kBlock);
    const double h = (seed[a] + r - lat.origin[a]) / block_world;
    lo[a] = static_cast<std::int64_t>(std::max(0.0, std::floor(l) - 1.0));
    hi[a] = static_cast<std::int64_t>(std::min(static_cast<double>(lat.blocks[a] - 1), std::floor(h)));
    if (hi[a] < lo[a]) return;
  }
  for (std::int64_t bz = lo[2]; bz <= hi[2]; ++bz) {
    if (hi[2] > lo[2]) control.check();  // a large seed_radius covers many blocks
    for (std::int64_t by = lo[1]; by <= hi[1]; ++by) {
      for (std::int64_t bx = lo[0]; bx <= hi[0]; ++bx) {
        const std::uint64_t key = lat.key(bx, by, bz);
        if (known(key)) continue;
        std::array<std::int64_t, 3> llo, lhi;
        block_range_lattice({bx, by, bz}, {bx + 1, by + 1, bz + 1}, llo, lhi);
        double d2 = 0.0;
        for (int a = 0; a < 3; ++a) {
          const double x0 = lat.world(a, llo[a]), x1 = lat.world(a, lhi[a]);
          const double d = std::max({x0 - seed[a], seed[a] - x1, 0.0});
          d2 += d * d;
        }
        if (d2 <= r * r * kBallMargin) add(key);
      }
    }
  }
}

// The blocks near the seeds, sorted. A bit per block of the lattice when that costs at most 64 bits per seed (plus
// 2^20): the seeds are then cut into chunks over the threads, which set bits (an atomic OR), and the set bits come
// out in key order. Most blocks near a seed were set by the seeds before it (neighbours in space are mostly
// neighbours in the list): a plain read of the bit skips the block's distance test. A hash set otherwise.
std::vector<std::uint64_t> seed_blocks(const Lattice& lat, const MarchingTilesOptions& o, int threads,
                                       const RunControl& control) {
  const double blocks =
      static_cast<double>(lat.blocks[0]) * static_cast<double>(lat.blocks[1]) * static_cast<double>(lat.blocks[2]);
  std::vector<std::uint64_t> keys;
  if (blocks <= 64.0 * static_cast<double>(o.seeds.size()) + static_cast<double>(1 << 20)) {
    std::vector<std::uint64_t> bits((static_cast<std::size_t>(blocks) + 63) / 64, 0);
    for_chunks(o.seeds.size(), threads, [&](std::size_t begin, std::size_t end) {
      for (std::size_t i = begin; i < end; ++i) {
        if (((i - begin) & 1023) == 0) control.check();
        auto word = [&](std::uint64_t key) { return std::atomic_ref<std::uint64_t>(bits[key >> 6]); };
        blocks_near_seed(
            lat, o, i, control,
            [&](std::uint64_t key) { return (word(key).load(std::memory_order_relaxed) >> (key & 63)) & 1; },
            [&](std::uint64_t key) { word(key).fetch_or(std::uint64_t{1} << (key & 63), std::memory_order_relaxed); });
      }
    });
    for (std::size_t w = 0; w < bits.size(); ++w) {
      for (std::uint64_t m = bits[w]; m != 0; m &= m - 1) keys.push_back(w * 64 + std::countr_zero(m));
    }
    return keys;
  }
  std::unordered_set<std::uint64_t> set;
  for (std::size_t i = 0; i < o.seeds.size(); ++i) {
    if (((i + 1) & 1023) == 0) control.check();
    blocks_near_seed(
        lat, o, i, control, [](std::uint64_t) { return false; }, [&](std::uint64_t key) { set.insert(key); });
  }
  keys.assign(set.begin(), set.end());
  std::sort(keys.begin(), keys.end());
  return keys;
}

// kd-descent over the block grid with the Lipschitz ball test.
void lipschitz_scan(const Lattice& lat, const Field& field, double lipschitz, const Aabb& region,
                    const std::array<std::int64_t, 3>& lo, const std::array<std::int64_t, 3>& hi,
                    std::vector<std::uint64_t>& out, std::int64_t& evaluations, const RunControl& control) {
  if ((evaluations & 255) == 0) control.check();
  std::array<std::int64_t, 3> llo, lhi;
  block_range_lattice(lo, hi, llo, lhi);
  const std::optional<Aabb> box = clipped_box(lat, llo, lhi, region);
  if (!box) return;
  ++evaluations;
  if (ball_excludes(field, lipschitz, *box)) return;
  int axis = 0;
  for (int a = 1; a < 3; ++a) {
    if (hi[a] - lo[a] > hi[axis] - lo[axis]) axis = a;
  }
  if (hi[axis] - lo[axis] == 1) {
    out.push_back(lat.key(lo[0], lo[1], lo[2]));
    return;
  }
  const std::int64_t mid = lo[axis] + (hi[axis] - lo[axis]) / 2;
  std::array<std::int64_t, 3> a_hi = hi, b_lo = lo;
  a_hi[axis] = mid;
  b_lo[axis] = mid;
  lipschitz_scan(lat, field, lipschitz, region, lo, a_hi, out, evaluations, control);
  lipschitz_scan(lat, field, lipschitz, region, b_lo, hi, out, evaluations, control);
}

// Signs at the corners of every kSub^3-cell sub-block in the region; blocks holding a sub-block with mixed corner
// signs. Rows of corners are evaluated in parallel (one z-layer per item).
std::vector<std::uint64_t> sign_scan(const Lattice& lat, const Field& field, const Aabb& region, int threads,
                                     std::int64_t& evaluations, const RunControl& control) {
  const std::int64_t step = std::int64_t{4} * kSub;  // lattice units between corners
  std::array<std::int64_t, 3> lo, n;
  for (int a = 0; a < 3; ++a) {
    lo[a] = std::max<std::int64_t>(0, static_cast<std::int64_t>(std::floor((region.min[a] - lat.origin[a]) /
                                                                           (lat.unit * static_cast<double>(step)))));
    const auto hi =
        static_cast<std::int64_t>(std::ceil((region.max[a] - lat.origin[a]) / (lat.unit * static_cast<double>(step))));
    n[a] = std::max<std::int64_t>(0, hi - lo[a] + 1);
  }
  if (n[0] < 2 || n[1] < 2 || n[2] < 2) return {};
  std::vector<std::uint8_t> inside(static_cast<std::size_t>(n[0] * n[1] * n[2]));
  std::atomic<std::int64_t> count{0};
  parallel_for(static_cast<int>(n[2]), threads, [&](int k) {
    for (std::int64_t j = 0; j < n[1]; ++j) {
      control.check();  // a row is at most a few thousand evaluations
      for (std::int64_t i = 0; i < n[0]; ++i) {
        const Vec3 p(std::min(lat.world(0, (lo[0] + i) * step), region.max[0]),
                     std::min(lat.world(1, (lo[1] + j) * step), region.max[1]),
                     std::min(lat.world(2, (lo[2] + k) * step), region.max[2]));
        inside[static_cast<std::size_t>((k * n[1] + j) * n[0] + i)] = field.value(p) < 0.0;
      }
    }
    count.fetch_add(n[0] * n[1], std::memory_order_relaxed);
  });
  evaluations += count.load();
  std::unordered_set<std::uint64_t> set;
  for (std::int64_t k = 0; k + 1 < n[2]; ++k) {
    for (std::int64_t j = 0; j + 1 < n[1]; ++j) {
      for (std::int64_t i = 0; i + 1 < n[0]; ++i) {
        int sum = 0;
        for (int c = 0; c < 8; ++c) {
          sum += inside[static_cast<std::size_t>(((k + (c >> 2)) * n[1] + j + ((c >> 1) & 1)) * n[0] + i + (c & 1))];
        }
        if (sum == 0 || sum == 8) continue;
        // Sub-block (lo + (i, j, k)) in cells: kSub * (lo + i); its block, clamped to the grid.
        std::array<std::int64_t, 3> b{};
        const std::array<std::int64_t, 3> ijk{i, j, k};
        for (int a = 0; a < 3; ++a) b[a] = std::min(lat.blocks[a] - 1, (lo[a] + ijk[a]) * kSub / kBlock);
        set.insert(lat.key(b[0], b[1], b[2]));
      }
    }
  }
  std::vector<std::uint64_t> keys(set.begin(), set.end());
  std::sort(keys.begin(), keys.end());
  return keys;
}

// --- Merge ---------------------------------------------------------------------------------------------------------

// Whether block a comes before block b along a Morton (Z-order) curve over the block grid, z the most significant
// axis at every bit: the axis whose coordinates differ in the highest bit decides. No limit on the coordinates.
bool morton_less(const std::array<std::int64_t, 3>& a, const std::array<std::int64_t, 3>& b) {
  int axis = 2;
  std::uint64_t highest = 0;
  for (int d = 2; d >= 0; --d) {
    const std::uint64_t diff = static_cast<std::uint64_t>(a[d] ^ b[d]);
    if (highest < diff && highest < (highest ^ diff)) {  // diff's top bit is above highest's
      highest = diff;
      axis = d;
    }
  }
  return a[axis] < b[axis];
}

// Resolves foreign ids without sorting whole vertex lists: the references are grouped by owner block, and each
// owner's (slot -> id) table is laid out in a worker's slot array just long enough to answer them.
Mesh merge(const Lattice& lat, std::vector<BlockOutput>& blocks, bool normals, std::vector<Scratch>& scratch,
           const RunControl& control) {
  std::sort(blocks.begin(), blocks.end(), [](const BlockOutput& a, const BlockOutput& b) { return a.key < b.key; });
  const std::size_t n = blocks.size();
  const int threads = static_cast<int>(scratch.size());
  std::vector<std::uint64_t> keys(n);
  std::vector<std::size_t> vbase(n + 1, 0), tbase(n + 1, 0), fbase(n + 1, 0);
  for (std::size_t b = 0; b < n; ++b) {
    keys[b] = blocks[b].key;
    fbase[b + 1] = fbase[b] + blocks[b].foreign.size();
  }
  // The blocks' vertices and triangles are laid out along a Morton curve over the block grid, so that any range of
  // indices is a compact piece of the surface (the particle surfacer's sweep blocks, the codecs' pieces).
  {
    std::vector<std::array<std::int64_t, 3>> coords(n);
    for (std::size_t b = 0; b < n; ++b) coords[b] = lat.block_of_key(keys[b]);
    std::vector<std::uint32_t> place(n);
    std::iota(place.begin(), place.end(), 0u);
    std::sort(place.begin(), place.end(),
              [&](std::uint32_t a, std::uint32_t b) { return morton_less(coords[a], coords[b]); });
    std::size_t v = 0, t = 0;
    for (const std::uint32_t b : place) {
      vbase[b] = v;
      tbase[b] = t;
      v += blocks[b].vertices.size();
      t += blocks[b].triangles.size();
    }
    vbase[n] = v;
    tbase[n] = t;
  }
  if (vbase[n] > std::numeric_limits<std::uint32_t>::max()) {
    throw ResourceLimit("spacing", "marching tiles produced more than 2^32 vertices; use a larger spacing");
  }
  const auto missing = [] {
    return Internal(
        "marching tiles: an edge vertex was not created by its owner block (is the field's lipschitz_bound() too "
        "small, or is the field not deterministic?)");
  };
  // Owner of every foreign reference (index into the sorted blocks), then references grouped by owner.
  std::vector<std::uint32_t> owner(fbase[n]);
  parallel_for(static_cast<int>(n), threads, [&](int b) {
    for (std::size_t f = 0; f < blocks[b].foreign.size(); ++f) {
      const auto it = std::lower_bound(keys.begin(), keys.end(), blocks[b].foreign[f].block);
      if (it == keys.end() || *it != blocks[b].foreign[f].block) throw missing();
      owner[fbase[b] + f] = static_cast<std::uint32_t>(it - keys.begin());
    }
  });
  std::vector<std::size_t> incoming_start(n + 1, 0);
  for (std::uint32_t o : owner) ++incoming_start[o + 1];
  for (std::size_t b = 0; b < n; ++b) incoming_start[b + 1] += incoming_start[b];
  std::vector<std::uint32_t> incoming(fbase[n]);  // global reference index (fbase[b] + f), grouped by owner
  {
    std::vector<std::size_t> fill(incoming_start.begin(), incoming_start.end() - 1);
    for (std::size_t r = 0; r < owner.size(); ++r) incoming[fill[owner[r]]++] = static_cast<std::uint32_t>(r);
  }
  std::vector<std::uint32_t> resolved(fbase[n]);  // global vertex id per reference
  std::vector<std::uint32_t> ref_block(fbase[n]);
  for (std::size_t b = 0; b < n; ++b) {
    std::fill(ref_block.begin() + static_cast<std::ptrdiff_t>(fbase[b]),
              ref_block.begin() + static_cast<std::ptrdiff_t>(fbase[b + 1]), static_cast<std::uint32_t>(b));
  }
  for_each_item(static_cast<int>(n), threads, [&](int b, int worker) {
    if (incoming_start[b] == incoming_start[b + 1]) return;
    std::vector<std::uint32_t>& table = scratch[worker].slots;
    const auto& slots = blocks[b].vertex_slots;
    for (std::uint32_t i = 0; i < slots.size(); ++i) table[slots[i]] = static_cast<std::uint32_t>(vbase[b] + i);
    bool ok = true;
    for (std::size_t k = incoming_start[b]; k < incoming_start[b + 1]; ++k) {
      const std::uint32_t r = incoming[k];
      const std::uint32_t id = table[blocks[ref_block[r]].foreign[r - fbase[ref_block[r]]].slot];
      ok = ok && id != kNone;
      resolved[r] = id;
    }
    for (std::uint32_t slot : slots) table[slot] = kNone;
    if (!ok) throw missing();
  });
  Mesh mesh;
  mesh.vertices.resize(vbase[n]);
  if (normals) mesh.normals.resize(vbase[n]);
  mesh.triangles.resize(tbase[n]);
  parallel_for(static_cast<int>(n), threads, [&](int b) {
    if ((b & 63) == 0) control.check();
    const BlockOutput& out = blocks[b];
    std::copy(out.vertices.begin(), out.vertices.end(), mesh.vertices.begin() + static_cast<std::ptrdiff_t>(vbase[b]));
    if (normals) {
      std::copy(out.normals.begin(), out.normals.end(), mesh.normals.begin() + static_cast<std::ptrdiff_t>(vbase[b]));
    }
    const std::uint32_t* foreign = resolved.data() + fbase[b];
    const auto base = static_cast<std::uint32_t>(vbase[b]);
    Triangle* dst = mesh.triangles.data() + tbase[b];
    for (const Triangle& t : out.triangles) {
      for (int c = 0; c < 3; ++c) (*dst)[c] = (t[c] & kForeign) ? foreign[t[c] & ~kForeign] : base + t[c];
      ++dst;
    }
  });
  return mesh;
}

}  // namespace

std::int64_t marching_tiles_fixed_bytes(const MarchingTilesOptions& options) {
  constexpr double kBytesPerBlock = 128.0;  // keys in the frontier and the seen set; the sign scan's corners
  const Lattice lat = make_lattice(options);
  const double blocks =
      static_cast<double>(lat.blocks[0]) * static_cast<double>(lat.blocks[1]) * static_cast<double>(lat.blocks[2]);
  // A worker's scratch: the struct, the padded values, the slot and ring tables (the touched lists stay smaller).
  constexpr double kScratchBytes =
      sizeof(Scratch) + sizeof(double) * kPadCells * 8.0 + sizeof(std::uint32_t) * (kSlots + 3.0 * kRingSlots);
  const double scratch = static_cast<double>(std::min(resolve_threads(options.threads), 64)) * kScratchBytes;
  return static_cast<std::int64_t>(std::min(4.0e18, blocks * kBytesPerBlock + scratch));
}

Mesh marching_tiles(const Field& field, const MarchingTilesOptions& options, const RunControl& control) {
  validate(options);
  const Lattice lat = make_lattice(options);
  const int threads = resolve_threads(options.threads);
  control.report("polygonize", 0.0);
  control.check();

  std::optional<double> lipschitz = field.lipschitz_bound();
  if (lipschitz && !(*lipschitz >= 0.0 && std::isfinite(*lipschitz))) lipschitz.reset();  // unusable: no bound
  if (options.search == TileSearch::kLipschitz && !lipschitz) {
    throw InvalidInput("search",
                       "search is kLipschitz but the field has no (finite, >= 0) lipschitz_bound(); use "
                       "kAuto or kSignScan");
  }
  std::int64_t scan_evaluations = 0;
  std::vector<std::uint64_t> frontier;
  if (!options.seeds.empty()) {
    frontier = seed_blocks(lat, options, threads, control);
  } else if (const std::optional<Aabb> region = search_region(field, options)) {
    if (lipschitz && options.search != TileSearch::kSignScan) {
      lipschitz_scan(lat, field, *lipschitz, *region, {0, 0, 0}, lat.blocks, frontier, scan_evaluations, control);
      std::sort(frontier.begin(), frontier.end());
    } else {
      frontier = sign_scan(lat, field, *region, threads, scan_evaluations, control);
    }
  }
  control.report("polygonize", 0.05);

  const BlockMesher mesher_proto(lat, field, options, lipschitz, control);
  std::vector<Scratch> scratch(static_cast<std::size_t>(std::min(threads, 64)));
  std::unordered_set<std::uint64_t> seen(frontier.begin(), frontier.end());
  std::vector<BlockOutput> done;
  Progress progress(control);
  TriangleCounter triangles(control, "marching tiles", "use a larger spacing (fewer cells)");
  std::atomic<std::int64_t> finished{0};
  std::int64_t scheduled = static_cast<std::int64_t>(frontier.size());
  while (!frontier.empty()) {
    std::vector<BlockOutput> round(frontier.size());
    const int workers = std::min<int>(static_cast<int>(scratch.size()), static_cast<int>(frontier.size()));
    for_each_item(static_cast<int>(frontier.size()), workers, [&](int item, int worker) {
      BlockMesher mesher = mesher_proto;
      BlockOutput out;  // filled here, moved once: outputs side by side in `round` would share cache lines
      mesher.run(frontier[item], scratch[worker], out);
      triangles.add(static_cast<std::int64_t>(out.triangles.size()));
      round[item] = std::move(out);
      progress.update(finished.fetch_add(1, std::memory_order_relaxed) + 1, scheduled);
    });
    std::vector<std::uint64_t> next;
    for (BlockOutput& out : round) {
      if (out.neighbours != 0) {
        const std::array<std::int64_t, 3> b = lat.block_of_key(out.key);
        for (int d = 0; d < 27; ++d) {
          if (!((out.neighbours >> d) & 1)) continue;
          const std::array<std::int64_t, 3> nb{b[0] + d % 3 - 1, b[1] + (d / 3) % 3 - 1, b[2] + d / 9 - 1};
          bool inside = true;
          for (int a = 0; a < 3; ++a) inside = inside && nb[a] >= 0 && nb[a] < lat.blocks[a];
          if (!inside) continue;
          const std::uint64_t key = lat.key(nb[0], nb[1], nb[2]);
          if (seen.insert(key).second) next.push_back(key);
        }
      }
      if (!out.triangles.empty()) done.push_back(std::move(out));
    }
    std::sort(next.begin(), next.end());
    scheduled += static_cast<std::int64_t>(next.size());
    frontier = std::move(next);
  }
  Mesh mesh = merge(lat, done, options.normals, scratch, control);
  control.report("polygonize", 1.0);
  return mesh;
}

}  // namespace surfacer
