#include "core/particles/smoothing.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>

#include "core/util/parallel.h"

namespace surfacer::particle_smoothing {
namespace {

// How many vertex ranges a per-vertex table is filled in when each range scans the whole input: a few (each range
// repeats the scan), and one for small meshes.
int vertex_range_count(std::size_t rows, int threads) {
  return static_cast<int>(std::min<std::size_t>(std::clamp(threads, 1, 4), rows / 65536 + 1));
}

// A compressed-row table (offsets, values) of `items` input items: scan(begin, end, add) must call add(row, value)
// for every entry of items [begin, end), in the same order on every call (rows >= `rows` are left out). Each thread's
// share of the items counts and then writes its own entries (RowBuckets): every item is scanned twice, by one thread,
// and each row holds its entries in item order, the table of one serial pass.
template <class Values, class Scan>
void rows_by_items(std::size_t rows, std::size_t items, int threads, std::vector<std::uint32_t>& offsets,
                   Values& values, Scan&& scan) {
  const int parts = static_cast<int>(std::min<std::size_t>(std::clamp(threads, 1, 8), items / 4096 + 1));
  RowBuckets buckets(rows, parts);
  for_chunks(rows, threads, [&](std::size_t begin, std::size_t end) { buckets.clear(begin, end); });
  parallel_for(parts, threads, [&](int part) {
    const auto [begin, end] = chunk_range(items, parts, part);
    std::uint32_t* count = buckets.count(part);
    scan(begin, end, [&](std::uint32_t row, std::uint32_t) {
      if (row < rows) ++count[row];
    });
  });
  offsets.resize(rows + 1);
  values.resize(buckets.place(offsets.data(), [&](int blocks, auto&& body) { parallel_for(blocks, threads, body); }));
  parallel_for(parts, threads, [&](int part) {
    const auto [begin, end] = chunk_range(items, parts, part);
    std::uint32_t* cursor = buckets.cursor(part);
    scan(begin, end, [&](std::uint32_t row, std::uint32_t value) {
      if (row < rows) values[cursor[row]++] = value;
    });
  });
}

}  // namespace

Graph one_ring(std::size_t vertices, std::span<const Triangle> triangles, int threads) {
  // Both directions of every edge, bucketed by vertex, then each row sorted and deduplicated.
  std::vector<std::uint32_t> count;
  Buffer<std::uint32_t> raw;
  rows_by_items(vertices, triangles.size(), threads, count, raw, [&](std::size_t begin, std::size_t end, auto&& add) {
    for (std::size_t i = begin; i < end; ++i) {
      const Triangle& t = triangles[i];
      for (int c = 0; c < 3; ++c) {
        const std::uint32_t a = t[c], b = t[(c + 1) % 3];
        if (a == b) continue;
        add(a, b);
        add(b, a);
      }
    }
  });
  // Rows sorted and deduplicated in place (row_end[i]: the end of row i's distinct neighbours), then packed.
  Buffer<std::uint32_t> row_end(vertices);
  for_chunks(vertices, threads, [&](std::size_t begin, std::size_t end) {
    for (std::size_t i = begin; i < end; ++i) {
      auto row = raw.begin() + count[i];
      std::sort(row, raw.begin() + count[i + 1]);
      row_end[i] = static_cast<std::uint32_t>(std::unique(row, raw.begin() + count[i + 1]) - raw.begin());
    }
  });
  Graph g;
  g.offsets.assign(vertices + 1, 0);
  for (std::size_t i = 0; i < vertices; ++i) g.offsets[i + 1] = g.offsets[i] + (row_end[i] - count[i]);
  g.cols.resize(g.offsets[vertices]);
  for_chunks(vertices, threads, [&](std::size_t begin, std::size_t end) {
    for (std::size_t i = begin; i < end; ++i) {
      std::copy(raw.begin() + count[i], raw.begin() + row_end[i], g.cols.begin() + g.offsets[i]);
    }
  });
  return g;
}

namespace {

// The cotangents of a triangle's three angles and its area.
struct Corner {
  double cot[3];  // at corners 0, 1, 2 (opposite edges 12, 20, 01)
  double area;
};
Corner corner_of(std::span<const Vec3> x, const Triangle& tri) {
  Corner out;
  const Vec3 e01 = x[tri[1]] - x[tri[0]], e02 = x[tri[2]] - x[tri[0]], e12 = x[tri[2]] - x[tri[1]];
  const double cross = e01.cross(e02).norm();
  out.area = 0.5 * cross;
  const double scale = std::max({e01.squaredNorm(), e02.squaredNorm(), e12.squaredNorm()});
  if (!(cross > kDegenerateRelativeArea * scale) || tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2]) {
    out.cot[0] = out.cot[1] = out.cot[2] = 0.0;
    return out;
  }
  auto clamp = [](double v) { return std::clamp(v, -kMaxCotangent, kMaxCotangent); };
  out.cot[0] = clamp(e01.dot(e02) / cross);
  out.cot[1] = clamp(-e01.dot(e12) / cross);
  out.cot[2] = clamp(e02.dot(e12) / cross);
  return out;
}

// W's off-diagonal entries through store_w(e, value) (ring.cols order, each once), its diagonal and the inverse vertex
// areas into w_diag and inv_area (resized to the rows), as cotangent_laplacian() states.
template <class StoreW>
void assemble_cotangent(std::span<const Vec3> x, std::span<const Triangle> triangles, const Graph& ring, int threads,
                        const RunControl& control, StoreW&& store_w, Buffer<double>& w_diag, Buffer<double>& inv_area) {
  const std::size_t n = ring.rows();
  // The triangles of every vertex (its corners, 3 * triangle + corner), so that each vertex assembles its own row of W
  // from the cotangents of its triangles, computed where they are needed: a per-triangle table would be the largest
  // array of the stage, and a small per-worker cache of recent triangles finds most of them (a triangle's three
  // vertices are mostly near in index).
  std::vector<std::uint32_t> corner_offsets;
  Buffer<std::uint32_t> corner_list;
  rows_by_items(n, triangles.size(), threads, corner_offsets, corner_list,
                [&](std::size_t begin, std::size_t end, auto&& add) {
                  for (std::size_t t = begin; t < end; ++t) {
                    for (std::uint32_t k = 0; k < 3; ++k) add(triangles[t][k], static_cast<std::uint32_t>(3 * t + k));
                  }
                });
  control.check();

  // Row by row in parallel. Corner k of a triangle is at vertex i; the angle at the next corner is opposite edge (i,
  // previous) and vice versa. A row sums in double, in corner order, and is rounded to float once.
  w_diag.resize(n);
  inv_area.resize(n);
  const int row_chunks = static_cast<int>(std::min<std::size_t>(256, n / 2048 + 1));
  parallel_for(row_chunks, threads, [&](int c) {
    const auto [begin, end] = chunk_range(n, row_chunks, c);
    std::vector<double> row;
    // Direct-mapped by triangle index; the same values as computed afresh (corner_of is a function of the triangle).
    constexpr std::size_t kCacheSlots = 2048;
    std::vector<std::uint32_t> cached(kCacheSlots, std::numeric_limits<std::uint32_t>::max());
    std::vector<Corner> cache(kCacheSlots);
    auto corner = [&](std::uint32_t t) -> const Corner& {
      const std::size_t slot = t % kCacheSlots;
      if (cached[slot] != t) {
        cached[slot] = t;
        cache[slot] = corner_of(x, triangles[t]);
      }
      return cache[slot];
    };
    for (std::size_t i = begin; i < end; ++i) {
      const std::uint32_t r0 = ring.offsets[i], r1 = ring.offsets[i + 1];
      row.assign(r1 - r0, 0.0);
      double diag = 0.0;
      auto col = [&](std::uint32_t j) {
        for (std::uint32_t e = r0; e < r1; ++e) {
          if (ring.cols[e] == j) return e - r0;
        }
        return r1 - r0;  // not a neighbour (a triangle with a repeated index)
      };
      double area = 0.0;
      for (std::uint32_t q = corner_offsets[i]; q < corner_offsets[i + 1]; ++q) {
        const std::uint32_t t = corner_list[q] / 3, k = corner_list[q] % 3;
        const Triangle& tri = triangles[t];
        const Corner& cn = corner(t);
        area += cn.area;
        const std::uint32_t next = tri[(k + 1) % 3], prev = tri[(k + 2) % 3];
        // Edge (i, next) is opposite corner prev; edge (i, prev) is opposite corner next.
        const double half_next = 0.5 * cn.cot[(k + 2) % 3], half_prev = 0.5 * cn.cot[(k + 1) % 3];
        if (next != i && half_next != 0.0) {
          const std::uint32_t e = col(next);
          if (e < row.size()) row[e] -= half_next;
          diag += half_next;
        }
        if (prev != i && half_prev != 0.0) {
          const std::uint32_t e = col(prev);
          if (e < row.size()) row[e] -= half_prev;
          diag += half_prev;
        }
      }
      for (std::uint32_t e = r0; e < r1; ++e) store_w(e, static_cast<float>(row[e - r0]));
      w_diag[i] = diag;
      inv_area[i] = area > 0.0 ? 1.0 / area : 0.0;
    }
  });
  control.check();
}

}  // namespace

Cotangent cotangent_laplacian(std::span<const Vec3> x, std::span<const Triangle> triangles, const Graph& ring,
                              int threads, const RunControl& control) {
  Cotangent cot;
  cot.w.resize(ring.cols.size());
  assemble_cotangent(
      x, triangles, ring, threads, control, [&](std::uint32_t e, float w) { cot.w[e] = w; }, cot.w_diag,
      cot.inv_area);
  return cot;
}

SparseMatrix bilaplacian(std::span<const Vec3> x, std::span<const Triangle> triangles, const Graph& ring, int threads,
                         const RunControl& control) {
  const Cotangent cot = cotangent_laplacian(x, triangles, ring, threads, control);
  const Buffer<float>& w = cot.w;
  const Buffer<double>& w_diag = cot.w_diag;
  const Buffer<double>& inv_area = cot.inv_area;
  const std::size_t n = ring.rows();
  const int row_chunks = static_cast<int>(std::min<std::size_t>(256, n / 2048 + 1));
  auto row_range = [&](int c) { return chunk_range(n, row_chunks, c); };

  // Gustavson row by row: row i of B = sum over k in {i} + ring(i) of (W_ik / D_k) * (row k of W), columns in
  // first-touch order. Each chunk of rows fills its own arrays (a column -> slot table per worker), then the chunks
  // are concatenated: deterministic whatever `threads`.
  struct Part {
    std::vector<std::uint32_t> cols;
    std::vector<float> values;
  };
  std::vector<Part> parts(static_cast<std::size_t>(row_chunks));
  SparseMatrix b;
  b.graph.offsets.assign(n + 1, 0);
  b.diagonal.assign(n, 0.0);
  const int workers = std::max(1, std::min(resolve_threads(threads), row_chunks));
  std::vector<std::vector<std::int32_t>> slots(static_cast<std::size_t>(workers));
  std::atomic<int> next_chunk{0};
  parallel_for(workers, workers, [&](int worker) {
    std::vector<std::int32_t>& slot = slots[static_cast<std::size_t>(worker)];
    slot.assign(n, -1);  // column -> position in the current row, -1 when absent
    std::vector<double> acc;
    for (int c = next_chunk.fetch_add(1); c < row_chunks; c = next_chunk.fetch_add(1)) {
      control.check();
      const auto [begin, end] = row_range(c);
      Part& part = parts[static_cast<std::size_t>(c)];
      part.cols.reserve((end - begin) * 20);
      for (std::size_t i = begin; i < end; ++i) {
        const std::size_t row_start = part.cols.size();
        acc.clear();
        double diag = 0.0;
        auto add = [&](std::uint32_t j, double v) {
          if (j == i) {
            diag += v;
            return;
          }
          std::int32_t& s = slot[j];
          if (s < 0) {
            s = static_cast<std::int32_t>(acc.size());
            part.cols.push_back(j);
            acc.push_back(0.0);
          }
          acc[static_cast<std::size_t>(s)] += v;
        };
        auto add_row = [&](std::uint32_t k, double coeff) {  // coeff * (row k of W); zero coefficients too, so the
          add(k, coeff * w_diag[k]);                         // columns are the whole 2-ring
          for (std::uint32_t e = ring.offsets[k]; e < ring.offsets[k + 1]; ++e) add(ring.cols[e], coeff * w[e]);
        };
        add_row(static_cast<std::uint32_t>(i), w_diag[i] * inv_area[i]);
        for (std::uint32_t e = ring.offsets[i]; e < ring.offsets[i + 1]; ++e) {
          const std::uint32_t k = ring.cols[e];
          add_row(k, w[e] * inv_area[k]);
        }
        for (std::size_t p = 0; p < acc.size(); ++p) {
          part.values.push_back(static_cast<float>(acc[p]));
          slot[part.cols[row_start + p]] = -1;
        }
        b.diagonal[i] = diag;
        b.graph.offsets[i + 1] = static_cast<std::uint32_t>(acc.size());
      }
    }
  });
  control.check();
  for (std::size_t i = 0; i < n; ++i) b.graph.offsets[i + 1] += b.graph.offsets[i];
  b.graph.cols.resize(b.graph.offsets[n]);
  b.values.resize(b.graph.offsets[n]);
  parallel_for(row_chunks, threads, [&](int c) {
    const Part& part = parts[static_cast<std::size_t>(c)];
    const std::size_t at = b.graph.offsets[row_range(c).first];
    std::copy(part.cols.begin(), part.cols.end(), b.graph.cols.begin() + static_cast<std::ptrdiff_t>(at));
    std::copy(part.values.begin(), part.values.end(), b.values.begin() + static_cast<std::ptrdiff_t>(at));
  });
  return b;
}

std::size_t default_block_count(std::size_t vertices) { return std::clamp<std::size_t>(vertices / 65536, 1, 64); }

SweepPlan plan_sweeps(const Graph& rows, std::size_t blocks) {
  const std::size_t n = rows.rows();
  blocks = std::max<std::size_t>(1, std::min(blocks, std::max<std::size_t>(1, n)));
  SweepPlan plan;
  plan.block_begin.assign(blocks + 1, 0);
  plan.interior.reserve(n);
  auto block_of = [&](std::size_t v) { return v * blocks / std::max<std::size_t>(1, n); };
  for (std::size_t b = 0; b < blocks; ++b) {
    const std::size_t begin = (n * b + blocks - 1) / blocks;  // first v with block_of(v) == b
    const std::size_t end = (n * (b + 1) + blocks - 1) / blocks;
    for (std::size_t v = begin; v < end; ++v) {
      bool inside = true;
      for (std::uint32_t e = rows.offsets[v]; e < rows.offsets[v + 1] && inside; ++e) {
        inside = block_of(rows.cols[e]) == b;
      }
      (inside ? plan.interior : plan.seams).push_back(static_cast<std::uint32_t>(v));
    }
    plan.block_begin[b + 1] = static_cast<std::uint32_t>(plan.interior.size());
  }
  std::sort(plan.seams.begin(), plan.seams.end());
  return plan;
}

namespace {

template <class Update>
void sweep(const SweepPlan& plan, int threads, Update&& update) {
  parallel_for(static_cast<int>(plan.blocks()), threads, [&](int b) {
    for (std::uint32_t s = plan.block_begin[b]; s < plan.block_begin[b + 1]; ++s) update(plan.interior[s]);
  });
  for (const std::uint32_t v : plan.seams) update(v);
}

}  // namespace

void laplacian_sweep(std::vector<Vec3>& x, const Graph& ring, double relaxation, const SweepPlan& plan, int threads) {
  sweep(plan, threads, [&](std::uint32_t i) {
    const std::uint32_t begin = ring.offsets[i], end = ring.offsets[i + 1];
    if (begin != end) {
      Vec3 sum = Vec3::Zero();
      for (std::uint32_t e = begin; e < end; ++e) sum += x[ring.cols[e]];
      x[i] += relaxation * (sum / static_cast<double>(end - begin) - x[i]);
    }
  });
}

SweepPlan plan_two_ring_sweeps(const Graph& ring, std::size_t blocks, int threads) {
  const std::size_t n = ring.rows();
  blocks = std::max<std::size_t>(1, std::min(blocks, std::max<std::size_t>(1, n)));
  auto block_begin = [&](std::size_t b) { return (n * b + blocks - 1) / blocks; };  // first v of block b
  // inside[k]: k's whole 1-ring lies in k's block. Then v's 2-ring lies in v's block exactly when inside[k] holds
  // for every neighbour k of v (v itself is in k's ring, so k shares v's block). Blocks in parallel: each writes
  // its own vertices, then its own lists, joined in block order.
  std::vector<std::uint8_t> inside(n);
  const int block_count = static_cast<int>(blocks);
  parallel_for(block_count, threads, [&](int b) {
    const std::size_t begin = block_begin(b), end = block_begin(b + 1);
    for (std::size_t k = begin; k < end; ++k) {
      bool all = true;
      for (std::uint32_t f = ring.offsets[k]; f < ring.offsets[k + 1] && all; ++f) {
        all = ring.cols[f] >= begin && ring.cols[f] < end;
      }
      inside[k] = all;
    }
  });
  std::vector<std::vector<std::uint32_t>> interior(blocks), seams(blocks);
  parallel_for(block_count, threads, [&](int b) {
    for (std::size_t v = block_begin(b); v < block_begin(b + 1); ++v) {
      bool in = true;
      for (std::uint32_t e = ring.offsets[v]; e < ring.offsets[v + 1] && in; ++e) in = inside[ring.cols[e]];
      (in ? interior[b] : seams[b]).push_back(static_cast<std::uint32_t>(v));
    }
  });
  SweepPlan plan;
  plan.block_begin.assign(blocks + 1, 0);
  plan.interior.reserve(n);
  for (std::size_t b = 0; b < blocks; ++b) {
    plan.interior.insert(plan.interior.end(), interior[b].begin(), interior[b].end());
    plan.seams.insert(plan.seams.end(), seams[b].begin(), seams[b].end());
    plan.block_begin[b + 1] = static_cast<std::uint32_t>(plan.interior.size());
  }
  return plan;
}

OffsetSmoothing::OffsetSmoothing(const Graph& ring, Cotangent cotangent, std::span<const Vec3> x0,
                                 std::span<const Vec3> normals, std::size_t blocks, int threads)
    : ring_(ring),
      w_diag_(std::move(cotangent.w_diag)),
      inv_area_(std::move(cotangent.inv_area)),
      x0_(x0),
      normals_(normals),
      plan_(plan_two_ring_sweeps(ring, blocks, threads)),
      offsets_(ring.rows(), 0.0),
      z_(ring.rows()) {
  w_.resize(cotangent.w.size());
  pack([&](std::uint32_t e) { return cotangent.w[e]; }, threads);
}

OffsetSmoothing::OffsetSmoothing(const Graph& ring, std::span<const Triangle> triangles, std::span<const Vec3> x0,
                                 std::span<const Vec3> normals, std::size_t blocks, int threads,
                                 const RunControl& control)
    : ring_(ring),
      x0_(x0),
      normals_(normals),
      plan_(plan_two_ring_sweeps(ring, blocks, threads)),
      offsets_(ring.rows(), 0.0),
      z_(ring.rows()) {
  w_.resize(ring.cols.size());
  assemble_cotangent(
      x0, triangles, ring, threads, control, [&](std::uint32_t e, float w) { w_[e] = w; }, w_diag_, inv_area_);
  pack([&](std::uint32_t e) { return w_[e]; }, threads);
}

template <class W>
void OffsetSmoothing::pack(W&& w_of, int threads) {
  const Graph& ring = ring_;
  const std::size_t n = ring.rows();
  rows_.resize(n);
  for_chunks(n, threads, [&](std::size_t begin, std::size_t end) {
    for (std::size_t i = begin; i < end; ++i) {
      const double c_diag = w_diag_[i] * inv_area_[i];
      double d = w_diag_[i] * c_diag;
      for (std::uint32_t e = ring.offsets[i]; e < ring.offsets[i + 1]; ++e) {
        const double w = w_of(e), c = w * inv_area_[ring.cols[e]];
        w_[e] = static_cast<float>(w);
        d += w * c;
      }
      // inv_diag 0: a vertex without area does not move.
      rows_[i] = {normals_[i].cast<float>(), d > 0.0 ? static_cast<float>(1.0 / d) : 0.0f};
    }
  });
}

void OffsetSmoothing::update_z(int threads) {
  const std::span<const double> t = offsets_;
  const std::size_t n = ring_.rows();
  const int chunks = static_cast<int>(std::min<std::size_t>(64, n / 4096 + 1));
  parallel_for(chunks, threads, [&](int c) {
    const auto [begin, end] = chunk_range(n, chunks, c);
    for (std::size_t k = begin; k < end; ++k) {
      Vec3 z = w_diag_[k] * (x0_[k] + t[k] * normals_[k]);
      for (std::uint32_t e = ring_.offsets[k]; e < ring_.offsets[k + 1]; ++e) {
        const std::uint32_t j = ring_.cols[e];
        z += static_cast<double>(w_[e]) * (x0_[j] + t[j] * normals_[j]);
      }
      z_[k] = z.cast<float>();
    }
  });
}

void OffsetSmoothing::sweep(std::span<const double> lo, std::span<const double> hi, double omega, int threads) {
  if (!z_current_) {  // z = W x for these offsets (then kept up to date by the updates below)
    update_z(threads);
    z_current_ = true;
  }
  std::vector<double>& t = offsets_;
  const bool bounded = !lo.empty();
  const float step = static_cast<float>(omega);
  auto update = [&](std::uint32_t i) {
    const Row& row = rows_[i];
    if (row.inv_diag == 0.0f) return;
    const std::uint32_t begin = ring_.offsets[i], end = ring_.offsets[i + 1];
    float grad = diagonal_coefficient(i) * row.normal.dot(z_[i]);
    for (std::uint32_t e = begin; e < end; ++e) grad += coefficient(e) * row.normal.dot(z_[ring_.cols[e]]);
    double next = t[i] - static_cast<double>(step * grad * row.inv_diag);
    if (bounded) next = std::clamp(next, lo[i], hi[i]);
    const double delta = next - t[i];
    if (delta == 0.0) return;
    t[i] = next;
    const Eigen::Vector3f dn = static_cast<float>(delta) * row.normal;
    z_[i] += static_cast<float>(w_diag_[i]) * dn;
    for (std::uint32_t e = begin; e < end; ++e) z_[ring_.cols[e]] += w_[e] * dn;
  };
  parallel_for(static_cast<int>(plan_.blocks()), threads, [&](int b) {
    for (std::uint32_t s = plan_.block_begin[b]; s < plan_.block_begin[b + 1]; ++s) update(plan_.interior[s]);
  });
  for (const std::uint32_t v : plan_.seams) update(v);
}

double OffsetSmoothing::clamp(std::span<const double> lo, std::span<const double> hi) {
  double largest = 0.0;
  for (std::size_t i = 0; i < offsets_.size(); ++i) {
    const double clamped = std::clamp(offsets_[i], lo[i], hi[i]);
    if (clamped == offsets_[i]) continue;
    largest = std::max(largest, std::abs(clamped - offsets_[i]));
    offsets_[i] = clamped;
    z_current_ = false;
  }
  return largest;
}

double OffsetSmoothing::energy(std::span<const double> t) const {
  const std::size_t n = ring_.rows();
  double e = 0.0;
  for (std::size_t k = 0; k < n; ++k) {
    Vec3 z = w_diag_[k] * (x0_[k] + t[k] * normals_[k]);
    for (std::uint32_t f = ring_.offsets[k]; f < ring_.offsets[k + 1]; ++f) {
      const std::uint32_t j = ring_.cols[f];
      z += static_cast<double>(w_[f]) * (x0_[j] + t[j] * normals_[j]);
    }
    e += inv_area_[k] * z.squaredNorm();
  }
  return e;
}

double energy(const SparseMatrix& b, std::span<const Vec3> x) {
  double e = 0.0;
  for (std::size_t i = 0; i < b.graph.rows(); ++i) {
    Vec3 bx = b.diagonal[i] * x[i];
    for (std::uint32_t k = b.graph.offsets[i]; k < b.graph.offsets[i + 1]; ++k)
      bx += static_cast<double>(b.values[k]) * x[b.graph.cols[k]];
    e += x[i].dot(bx);
  }
  return e;
}

std::vector<Vec3> vertex_normals(std::span<const Vec3> x, std::span<const Triangle> triangles, int threads) {
  // Each vertex range sums, in triangle order, the face normals of the triangles at its vertices: the same sums as
  // one serial pass.
  const std::size_t n = x.size();
  std::vector<Vec3> normals(n);  // not initialized (Eigen): each part zeroes its own range
  const int parts = vertex_range_count(n, threads);
  parallel_for(parts, threads, [&](int part) {
    const auto [lo, hi] = chunk_range(n, parts, part);
    std::fill(normals.begin() + lo, normals.begin() + hi, Vec3::Zero());
    for (const Triangle& t : triangles) {
      const bool mine[3] = {t[0] >= lo && t[0] < hi, t[1] >= lo && t[1] < hi, t[2] >= lo && t[2] < hi};
      if (!mine[0] && !mine[1] && !mine[2]) continue;
      const Vec3 a = (x[t[1]] - x[t[0]]).cross(x[t[2]] - x[t[0]]);  // |a| = 2 area
      for (int c = 0; c < 3; ++c) {
        if (mine[c]) normals[t[c]] += a;
      }
    }
    for (std::size_t v = lo; v < hi; ++v) {
      const double len = normals[v].norm();
      normals[v] = len > 0.0 ? Vec3(normals[v] / len) : Vec3::Zero();
    }
  });
  return normals;
}

}  // namespace surfacer::particle_smoothing
