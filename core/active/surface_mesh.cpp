// Polygonization and measures of the active surface's potential (NarrowBand, core/active/narrow_band.h).
//
// * Sparse Marching Cubes on the potential's own grid, with the table of core/polygonize/mc_tables.h (so ambiguous
//   faces are resolved as in core/polygonize/marching_cubes.cpp). A crossed grid edge belongs to the block of its
//   lower node; a cube to the block of its lowest corner. Vertices are created per block in (node, axis) order and
//   blocks are concatenated in block order, so the mesh does not depend on the thread count. A vertex is computed
//   from the global node coordinates and the two samples of its edge in a fixed order, so every cube sharing an edge
//   computes the same point bit for bit; the unwelded measures (area, divergence-theorem volume) therefore see a
//   closed surface.
// * The sample points of the speed extension are these edge crossings; the speed is stored per (node, axis) of the
//   owning block, the target evaluated once per crossing.
// * Marching Tiles (core/polygonize/marching_tiles.h) runs on the trilinear interpolant of f through a Field adapter,
//   seeded with one point per band block (the mean of its crossings).
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <string>

#include "core/active/narrow_band.h"
#include "core/active/schemes.h"
#include "core/polygonize/edge_margin.h"
#include "core/polygonize/marching_tiles.h"
#include "core/polygonize/mc_tables.h"
#include "core/util/errors.h"
#include "core/util/parallel.h"

namespace surfacer {
namespace {

using sparse::apron_at;
using sparse::apron_side;
using sparse::block_of;
using sparse::kBlockMask;
using sparse::kBlockNodes;
using sparse::kBlockSize;
using sparse::local_index;
using sparse::neighbor_slot;

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr int kCubeCorners = 8;  // corner c of a grid cube at offset (c & 1, (c >> 1) & 1, c >> 2)

float* mesh_scratch(std::size_t size) {
  thread_local std::vector<float> buffer;
  if (buffer.size() < size) buffer.resize(size);
  return buffer.data();
}

// Cube edge e (mc_tables.h numbering: kEdgesPerAxis edges along x, then along y, then along z) as (lower corner
// offset, axis).
struct CubeEdge {
  int dx, dy, dz, axis;
};
constexpr int kEdgesPerAxis = 4;
constexpr CubeEdge cube_edge(int e) {
  if (e < kEdgesPerAxis) return {0, e & 1, e >> 1, 0};
  if (e < 2 * kEdgesPerAxis) return {(e - kEdgesPerAxis) & 1, 0, (e - kEdgesPerAxis) >> 1, 1};
  return {(e - 2 * kEdgesPerAxis) & 1, (e - 2 * kEdgesPerAxis) >> 1, 0, 2};
}

struct BlockMeasure {
  double area = 0.0, volume = 0.0;
  std::int64_t crossings = 0;
  double max_grad = 0.0, sum_abs_kappa = 0.0;
};

int count_components(const Mesh& mesh) {
  std::vector<std::uint32_t> parent(mesh.vertices.size());
  std::iota(parent.begin(), parent.end(), 0u);
  auto find = [&](std::uint32_t v) {
    while (parent[v] != v) {
      parent[v] = parent[parent[v]];
      v = parent[v];
    }
    return v;
  };
  std::vector<char> used(mesh.vertices.size(), 0);
  for (const Triangle& t : mesh.triangles) {
    for (int k = 0; k < 3; ++k) used[t[k]] = 1;
    const std::uint32_t a = find(t[0]), b = find(t[1]), c = find(t[2]);
    parent[b] = a;
    parent[find(c)] = a;
  }
  int n = 0;
  for (std::uint32_t v = 0; v < parent.size(); ++v) n += used[v] && find(v) == v;
  return n;
}

// The trilinear potential as a normalized Field (negative inside) for Marching Tiles.
class PotentialField final : public Field {
 public:
  PotentialField(const active_detail::NarrowBand& band, const Aabb& box) : band_(band), box_(box) {}
  double value(const Vec3& p) const override {
    Vec3 g;
    return value_and_gradient(p, g);
  }
  double value_and_gradient(const Vec3& p, Vec3& gradient) const override;
  std::optional<Aabb> bounds() const override { return box_; }

 private:
  const active_detail::NarrowBand& band_;
  Aabb box_;
};

}  // namespace

double PotentialField::value_and_gradient(const Vec3& p, Vec3& gradient) const {
  Vec3 g;
  const double v = band_.trilinear(p, &g);
  gradient = -g;
  return -v;
}

// Sign (+1 inside, -1 outside) of the saturated region around node g of a missing block: the value of the first
// allocated node along +x (blocks are allocated around the whole band, so that node is saturated with the region's
// sign); outside when no block follows.
double active_detail::NarrowBand::missing_sign(std::int64_t gx, std::int64_t gy, std::int64_t gz) const {
  const int by = block_of(gy), bz = block_of(gz);
  const int ly = static_cast<int>(gy - std::int64_t{kBlockSize} * by),
            lz = static_cast<int>(gz - std::int64_t{kBlockSize} * bz);
  for (int bx = block_of(gx) + 1; bx <= max_block_x_; ++bx) {
    const int b = grid_.find(bx, by, bz);
    if (b >= 0) return grid_.data(b, kChanF)[local_index(0, ly, lz)] > 0.0f ? 1.0 : -1.0;
  }
  return -1.0;
}

double active_detail::NarrowBand::trilinear(const Vec3& p, Vec3* gradient) const {
  const Vec3 u = (p - frame_.origin()) * frame_.inv_spacing();
  if (!u.allFinite()) {
    if (gradient != nullptr) *gradient = Vec3::Zero();
    return -1.0;
  }
  const Vec3 fl = u.array().floor();
  double c[kCubeCorners];
  for (int k = 0; k < kCubeCorners; ++k) {
    std::int64_t g[3];
    for (int a = 0; a < 3; ++a) g[a] = static_cast<std::int64_t>(fl[a]) + ((k >> a) & 1);
    const int bx = block_of(g[0]), by = block_of(g[1]), bz = block_of(g[2]);
    const int b = grid_.find(bx, by, bz);
    c[k] = b >= 0 ? grid_.data(
                        b, kChanF)[local_index(static_cast<int>(g[0] & kBlockMask), static_cast<int>(g[1] & kBlockMask),
                                               static_cast<int>(g[2] & kBlockMask))]
                  : missing_sign(g[0], g[1], g[2]);
  }
  const Vec3 t = u - fl;
  double v = 0.0;
  Vec3 grad = Vec3::Zero();
  for (int k = 0; k < kCubeCorners; ++k) {
    double w = 1.0;
    Vec3 dw = Vec3::Ones();
    for (int a = 0; a < 3; ++a) {
      const double wa = ((k >> a) & 1) ? t[a] : 1.0 - t[a];
      const double da = ((k >> a) & 1) ? 1.0 : -1.0;
      w *= wa;
      for (int j = 0; j < 3; ++j) dw[j] *= (a == j) ? da : wa;
    }
    v += w * c[k];
    grad += dw * c[k];
  }
  if (gradient != nullptr) *gradient = grad * frame_.inv_spacing();
  return v;
}

// ------------------------------------------------------------------------------------------------------------------

ActiveMeasures active_detail::NarrowBand::measure(const RunControl& control) const {
  return measure(nullptr, nullptr, control);
}

ActiveMeasures active_detail::NarrowBand::measure(const CrossingSpeed& speed, std::vector<std::vector<float>>& edges,
                                                  const RunControl& control) const {
  return measure(&speed, &edges, control);
}

ActiveMeasures active_detail::NarrowBand::measure(const CrossingSpeed* speed, std::vector<std::vector<float>>* edges,
                                                  const RunControl& control) const {
  control.check();
  const int nb = grid_.block_count();
  if (edges != nullptr) {
    edges->resize(nb);
    for (int b = 0; b < nb; ++b) {
      if (band_[b]) {
        (*edges)[b].assign(std::size_t{3} * kBlockNodes, kNaN);
      } else {
        (*edges)[b].clear();
      }
    }
  }
  if (nb == 0) return {};
  const Vec3 ref = frame_.node_position(grid_.coord(0), 0, 0, 0);
  // The speed's terms (used only when sampling, so `speed` is then given).
  const double kmax = speed != nullptr ? speed->max_curvature * frame_.inv_spacing() : 0.0;
  const bool want_target = speed != nullptr && speed->target != nullptr;
  const bool want_kappa = speed != nullptr && speed->curvature;
  std::vector<BlockMeasure> parts(nb);
  parallel_for(nb, threads_, [&](int b) {
    if ((b & 31) == 0) control.check();
    const bool cubes = owns_cubes(b);
    const bool sample = edges != nullptr && band_[b];
    if (!cubes && !sample) return;
    constexpr int G = 2;
    constexpr std::ptrdiff_t S = apron_side<G>();
    float* ap = mesh_scratch(S * S * S);
    grid_.gather<G>(b, kChanF, ap);
    const sparse::BlockCoord& bc = grid_.coord(b);
    const double base[3] = {double(kBlockSize) * bc[0], double(kBlockSize) * bc[1], double(kBlockSize) * bc[2]};
    auto vertex = [&](int x, int y, int z, int axis, double v0, double v1) {
      const double t = v0 / (v0 - v1);
      Vec3 q(base[0] + x, base[1] + y, base[2] + z);
      q[axis] += t;
      return Vec3(frame_.origin() + frame_.spacing() * q);
    };
    BlockMeasure& part = parts[b];
    if (sample) {
      std::vector<float>& out = (*edges)[b];
      const std::ptrdiff_t st[3] = {1, S, S * S};
      for (int z = 0; z < kBlockSize; ++z)
        for (int y = 0; y < kBlockSize; ++y)
          for (int x = 0; x < kBlockSize; ++x) {
            const float* p = ap + apron_at<G>(x, y, z);
            for (int a = 0; a < 3; ++a) {
              const float v0 = p[0], v1 = p[st[a]];
              if ((v0 > 0.0f) == (v1 > 0.0f)) continue;
              ++part.crossings;
              const double t = double(v0) / (double(v0) - double(v1));
              double s = 0.0;
              if (want_target) {
                Vec3 grad;
                s -= speed->alpha * speed->target->value_and_gradient(vertex(x, y, z, a, v0, v1), grad);
                const double gn = grad.norm();
                if (std::isfinite(gn)) part.max_grad = std::max(part.max_grad, gn);
              }
              if (want_kappa) {
                const double k0 =
                    std::clamp(active_detail::curvature(p, 1, S, S * S, frame_.inv_spacing()), -kmax, kmax);
                const double k1 =
                    std::clamp(active_detail::curvature(p + st[a], 1, S, S * S, frame_.inv_spacing()), -kmax, kmax);
                const double k = (1.0 - t) * k0 + t * k1;
                s -= speed->beta * k;
                part.sum_abs_kappa += std::abs(k);
              }
              out[local_index(x, y, z) * 3 + a] = static_cast<float>(s);
            }
          }
    }
    if (cubes) {
      for (int z = 0; z < kBlockSize; ++z)
        for (int y = 0; y < kBlockSize; ++y)
          for (int x = 0; x < kBlockSize; ++x) {
            float v[kCubeCorners];
            int cs = 0;
            for (int c = 0; c < kCubeCorners; ++c) {
              v[c] = ap[apron_at<G>(x + (c & 1), y + ((c >> 1) & 1), z + (c >> 2))];
              cs |= (v[c] > 0.0f) << c;
            }
            if (cs == 0 || cs == 255) continue;
            Vec3 pos[12];
            unsigned have = 0;
            auto edge_pos = [&](int e) -> const Vec3& {
              if (!(have & (1u << e))) {
                const CubeEdge ce = cube_edge(e);
                const int c0 = mc::kEdgeCorners[e][0], c1 = mc::kEdgeCorners[e][1];
                pos[e] = vertex(x + ce.dx, y + ce.dy, z + ce.dz, ce.axis, v[c0], v[c1]);
                have |= 1u << e;
              }
              return pos[e];
            };
            for (int k = 0; k < mc::kTriangleCount[cs]; ++k) {
              const Vec3 a = edge_pos(mc::kTriangles[cs][3 * k + 0]) - ref;
              const Vec3 bb = edge_pos(mc::kTriangles[cs][3 * k + 1]) - ref;
              const Vec3 cc = edge_pos(mc::kTriangles[cs][3 * k + 2]) - ref;
              part.area += 0.5 * (bb - a).cross(cc - a).norm();
              part.volume += a.dot(bb.cross(cc)) / 6.0;
            }
          }
    }
  });
  ActiveMeasures m;
  double sum_kappa = 0.0;
  for (const BlockMeasure& p : parts) {
    m.area += p.area;
    m.volume += p.volume;
    m.crossings += p.crossings;
    m.max_target_gradient = std::max(m.max_target_gradient, p.max_grad);
    sum_kappa += p.sum_abs_kappa;
  }
  if (m.crossings > 0) m.mean_abs_curvature = sum_kappa / static_cast<double>(m.crossings);
  return m;
}

Mesh active_detail::NarrowBand::cubes_mesh(bool normals, const RunControl& control) const {
  control.check();
  const int nb = grid_.block_count();
  // Pass 1: vertices of the crossed edges owned by each band block.
  std::vector<std::vector<Vec3>> verts(nb), norms(nb);
  std::vector<std::vector<std::int32_t>> ids(nb);
  const double floor = edge_parameter_floor(vertex_margin_, frame_.spacing());
  parallel_for(nb, threads_, [&](int b) {
    if ((b & 31) == 0) control.check();
    if (!band_[b]) return;
    constexpr int G = 2;
    constexpr std::ptrdiff_t S = apron_side<G>();
    float* ap = mesh_scratch(S * S * S);
    grid_.gather<G>(b, kChanF, ap);
    const sparse::BlockCoord& bc = grid_.coord(b);
    std::vector<std::int32_t>& map = ids[b];
    map.assign(std::size_t{3} * kBlockNodes, -1);
    const std::ptrdiff_t st[3] = {1, S, S * S};
    for (int z = 0; z < kBlockSize; ++z)
      for (int y = 0; y < kBlockSize; ++y)
        for (int x = 0; x < kBlockSize; ++x) {
          const float* p = ap + apron_at<G>(x, y, z);
          for (int a = 0; a < 3; ++a) {
            const float v0 = p[0], v1 = p[st[a]];
            if ((v0 > 0.0f) == (v1 > 0.0f)) continue;
            const double t = std::clamp(double(v0) / (double(v0) - double(v1)), floor, 1.0 - floor);
            Vec3 q(double(kBlockSize) * bc[0] + x, double(kBlockSize) * bc[1] + y, double(kBlockSize) * bc[2] + z);
            q[a] += t;
            map[local_index(x, y, z) * 3 + a] = static_cast<std::int32_t>(verts[b].size());
            verts[b].push_back(frame_.origin() + frame_.spacing() * q);
            if (normals) {
              // -grad f by central differences at both ends, interpolated.
              auto grad = [&](const float* c) { return Vec3(c[1] - c[-1], c[S] - c[-S], c[S * S] - c[-S * S]); };
              Vec3 n = -((1.0 - t) * grad(p) + t * grad(p + st[a]));
              const double len = n.norm();
              if (len > 0.0) {
                n /= len;
              } else {
                n = Vec3::Zero();
                n[a] = v0 > 0.0f ? 1.0 : -1.0;  // from the inside end to the outside end
              }
              norms[b].push_back(n);
            }
          }
        }
  });
  std::vector<std::int64_t> offset(nb + 1, 0);
  for (int b = 0; b < nb; ++b) offset[b + 1] = offset[b] + static_cast<std::int64_t>(verts[b].size());
  if (offset[nb] > std::int64_t{0x7fffffff}) {
    throw ResourceLimit("vertices", "the surface has more than 2^31 vertices; coarsen h");
  }
  // Pass 2: triangles of the cubes owned by each block.
  std::vector<std::vector<Triangle>> tris(nb);
  parallel_for(nb, threads_, [&](int b) {
    if ((b & 31) == 0) control.check();
    if (!owns_cubes(b)) return;
    constexpr int G = 1;
    constexpr std::ptrdiff_t S = apron_side<G>();
    (void)S;
    float* ap = mesh_scratch(std::size_t{apron_side<G>()} * apron_side<G>() * apron_side<G>());
    grid_.gather<G>(b, kChanF, ap);
    for (int z = 0; z < kBlockSize; ++z)
      for (int y = 0; y < kBlockSize; ++y)
        for (int x = 0; x < kBlockSize; ++x) {
          int cs = 0;
          for (int c = 0; c < kCubeCorners; ++c) {
            cs |= (ap[apron_at<G>(x + (c & 1), y + ((c >> 1) & 1), z + (c >> 2))] > 0.0f) << c;
          }
          if (cs == 0 || cs == 255) continue;
          for (int k = 0; k < mc::kTriangleCount[cs]; ++k) {
            Triangle tri;
            for (int j = 0; j < 3; ++j) {
              const CubeEdge ce = cube_edge(mc::kTriangles[cs][3 * k + j]);
              int lx = x + ce.dx, ly = y + ce.dy, lz = z + ce.dz;
              const int ox = lx >> sparse::kBlockLog2, oy = ly >> sparse::kBlockLog2,
                        oz = lz >> sparse::kBlockLog2;  // 0 or 1
              const int owner = grid_.neighbor(b, neighbor_slot(ox, oy, oz));
              lx &= kBlockMask;
              ly &= kBlockMask;
              lz &= kBlockMask;
              const std::int32_t local =
                  owner >= 0 && !ids[owner].empty() ? ids[owner][local_index(lx, ly, lz) * 3 + ce.axis] : -1;
              if (local < 0) throw Internal("active surface: a crossed grid edge has no vertex (band bookkeeping)");
              tri[j] = static_cast<std::uint32_t>(offset[owner] + local);
            }
            tris[b].push_back(tri);
          }
        }
  });
  Mesh mesh;
  mesh.vertices.reserve(offset[nb]);
  for (int b = 0; b < nb; ++b) {
    mesh.vertices.insert(mesh.vertices.end(), verts[b].begin(), verts[b].end());
    if (normals) mesh.normals.insert(mesh.normals.end(), norms[b].begin(), norms[b].end());
  }
  std::size_t nt = 0;
  for (const auto& t : tris) nt += t.size();
  mesh.triangles.reserve(nt);
  for (const auto& t : tris) mesh.triangles.insert(mesh.triangles.end(), t.begin(), t.end());
  return mesh;
}

Mesh active_detail::NarrowBand::tiles_mesh(bool normals, const RunControl& control) const {
  control.check();
  const int nb = grid_.block_count();
  // One seed per band block with crossings: the mean of its crossings.
  std::vector<Vec3> block_seed(nb, Vec3::Constant(std::numeric_limits<double>::quiet_NaN()));
  parallel_for(nb, threads_, [&](int b) {
    if (!band_[b]) return;
    constexpr int G = 1;
    constexpr std::ptrdiff_t S = apron_side<G>();
    float* ap = mesh_scratch(S * S * S);
    grid_.gather<G>(b, kChanF, ap);
    const sparse::BlockCoord& bc = grid_.coord(b);
    const std::ptrdiff_t st[3] = {1, S, S * S};
    Vec3 sum = Vec3::Zero();
    int n = 0;
    for (int z = 0; z < kBlockSize; ++z)
      for (int y = 0; y < kBlockSize; ++y)
        for (int x = 0; x < kBlockSize; ++x) {
          const float* p = ap + apron_at<G>(x, y, z);
          for (int a = 0; a < 3; ++a) {
            if ((p[0] > 0.0f) == (p[st[a]] > 0.0f)) continue;
            Vec3 q(double(kBlockSize) * bc[0] + x, double(kBlockSize) * bc[1] + y, double(kBlockSize) * bc[2] + z);
            q[a] += double(p[0]) / (double(p[0]) - double(p[st[a]]));
            sum += frame_.origin() + frame_.spacing() * q;
            ++n;
          }
        }
    if (n > 0) block_seed[b] = sum / n;
  });
  std::vector<Vec3> seeds;
  Aabb box = Aabb::empty();
  for (int b = 0; b < nb; ++b) {
    const sparse::BlockCoord& bc = grid_.coord(b);
    box.merge(Aabb{frame_.node_position(bc, 0, 0, 0), frame_.node_position(bc, kBlockSize, kBlockSize, kBlockSize)});
    if (!std::isnan(block_seed[b][0])) seeds.push_back(block_seed[b]);
  }
  if (seeds.empty()) return {};
  PotentialField field(*this, box);
  MarchingTilesOptions o;
  o.bounds = box;
  o.spacing = frame_.spacing();
  o.normals = normals;
  o.threads = tiles_threads_;
  o.vertex_margin = vertex_margin_;
  o.seeds = seeds;
  // Every crossing lies in its band block: within the block's half-diagonal of the seed (plus a lattice cell).
  o.seed_radius = (4.0 * std::sqrt(3.0) + 2.0) * frame_.spacing();
  return marching_tiles(field, o, control);
}

void active_detail::NarrowBand::surface_stats(ActiveFrameStats& s, const RunControl& control) const {
  const ActiveMeasures m = measure(control);
  s.area = m.area;
  s.volume = m.volume;
  s.components = count_components(cubes_mesh(false, control));
  s.memory_bytes = grid_.memory_bytes();
}

}  // namespace surfacer
