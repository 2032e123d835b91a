#include "core/particles/smoothing.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

#include "core/util/parallel.h"

namespace surfacer::particle_smoothing {

Graph one_ring(std::size_t vertices, std::span<const Triangle> triangles) {
  // Both directions of every edge, counted then filled, then each row sorted and deduplicated in place.
  std::vector<std::uint32_t> count(vertices + 1, 0);
  for (const Triangle& t : triangles) {
    for (int c = 0; c < 3; ++c) {
      const std::uint32_t a = t[c], b = t[(c + 1) % 3];
      if (a == b) continue;
      ++count[a + 1];
      ++count[b + 1];
    }
  }
  for (std::size_t i = 0; i < vertices; ++i) count[i + 1] += count[i];
  std::vector<std::uint32_t> raw(count[vertices]);
  std::vector<std::uint32_t> fill(count.begin(), count.end() - 1);
  for (const Triangle& t : triangles) {
    for (int c = 0; c < 3; ++c) {
      const std::uint32_t a = t[c], b = t[(c + 1) % 3];
      if (a == b) continue;
      raw[fill[a]++] = b;
      raw[fill[b]++] = a;
    }
  }
  Graph g;
  g.offsets.assign(vertices + 1, 0);
  g.cols.reserve(raw.size() / 2 + vertices);
  for (std::size_t i = 0; i < vertices; ++i) {
    auto begin = raw.begin() + count[i], end = raw.begin() + count[i + 1];
    std::sort(begin, end);
    end = std::unique(begin, end);
    g.cols.insert(g.cols.end(), begin, end);
    g.offsets[i + 1] = static_cast<std::uint32_t>(g.cols.size());
  }
  return g;
}

namespace {

std::size_t find_col(const Graph& g, std::uint32_t row, std::uint32_t col) {
  const auto begin = g.cols.begin() + g.offsets[row], end = g.cols.begin() + g.offsets[row + 1];
  return static_cast<std::size_t>(std::lower_bound(begin, end, col) - g.cols.begin());
}

}  // namespace

SparseMatrix bilaplacian(std::span<const Vec3> x, std::span<const Triangle> triangles, const Graph& ring, int threads,
                         const RunControl& control) {
  const std::size_t n = ring.rows();
  // Cotangents of the three angles of every triangle (parallel), then a serial scatter into W and D.
  struct Corner {
    double cot[3];  // at corners 0, 1, 2 (opposite edges 12, 20, 01)
    double area;
  };
  std::vector<Corner> corners(triangles.size());
  const int chunks = static_cast<int>(std::min<std::size_t>(64, triangles.size() / 4096 + 1));
  parallel_for(chunks, threads, [&](int c) {
    const std::size_t begin = triangles.size() * static_cast<std::size_t>(c) / static_cast<std::size_t>(chunks);
    const std::size_t end = triangles.size() * static_cast<std::size_t>(c + 1) / static_cast<std::size_t>(chunks);
    for (std::size_t t = begin; t < end; ++t) {
      const Triangle& tri = triangles[t];
      Corner& out = corners[t];
      const Vec3 e01 = x[tri[1]] - x[tri[0]], e02 = x[tri[2]] - x[tri[0]], e12 = x[tri[2]] - x[tri[1]];
      const double cross = e01.cross(e02).norm();
      out.area = 0.5 * cross;
      const double scale = std::max({e01.squaredNorm(), e02.squaredNorm(), e12.squaredNorm()});
      if (!(cross > kDegenerateRelativeArea * scale) || tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2]) {
        out.cot[0] = out.cot[1] = out.cot[2] = 0.0;
        continue;
      }
      auto clamp = [](double v) { return std::clamp(v, -kMaxCotangent, kMaxCotangent); };
      out.cot[0] = clamp(e01.dot(e02) / cross);
      out.cot[1] = clamp(-e01.dot(e12) / cross);
      out.cot[2] = clamp(e02.dot(e12) / cross);
    }
  });
  control.check();
  std::vector<double> w(ring.cols.size(), 0.0), w_diag(n, 0.0), area(n, 0.0);
  for (std::size_t t = 0; t < triangles.size(); ++t) {
    const Triangle& tri = triangles[t];
    const Corner& c = corners[t];
    for (int k = 0; k < 3; ++k) {
      area[tri[k]] += c.area;
      // The angle at corner k is opposite edge (k+1, k+2).
      const std::uint32_t a = tri[(k + 1) % 3], b = tri[(k + 2) % 3];
      if (a == b || c.cot[k] == 0.0) continue;
      const double half = 0.5 * c.cot[k];
      w[find_col(ring, a, b)] -= half;
      w[find_col(ring, b, a)] -= half;
      w_diag[a] += half;
      w_diag[b] += half;
    }
  }
  control.check();
  std::vector<double> inv_area(n, 0.0);
  for (std::size_t i = 0; i < n; ++i) inv_area[i] = area[i] > 0.0 ? 1.0 / area[i] : 0.0;

  // Gustavson row by row: row i of B = sum over k in {i} + ring(i) of (W_ik / D_k) * (row k of W). Two passes over
  // static row ranges, one per worker: count each row's distinct columns, then fill the exactly sized arrays.
  const int workers = std::max(1, std::min(resolve_threads(threads), static_cast<int>(n / 1024 + 1)));
  auto range = [&](int worker) {
    return std::pair<std::size_t, std::size_t>{
        n * static_cast<std::size_t>(worker) / static_cast<std::size_t>(workers),
        n * static_cast<std::size_t>(worker + 1) / static_cast<std::size_t>(workers)};
  };
  SparseMatrix b;
  b.graph.offsets.assign(n + 1, 0);
  b.diagonal.assign(n, 0.0);
  parallel_for(workers, threads, [&](int worker) {
    control.check();
    const auto [begin, end] = range(worker);
    std::vector<std::uint32_t> mark(n, 0xffffffffu);  // column -> last row that touched it
    for (std::size_t i = begin; i < end; ++i) {
      std::uint32_t count = 0;
      auto touch = [&](std::uint32_t j) {
        if (j != i && mark[j] != i) {
          mark[j] = static_cast<std::uint32_t>(i);
          ++count;
        }
      };
      auto touch_row = [&](std::uint32_t k) {
        touch(k);
        for (std::uint32_t e = ring.offsets[k]; e < ring.offsets[k + 1]; ++e) touch(ring.cols[e]);
      };
      touch_row(static_cast<std::uint32_t>(i));
      for (std::uint32_t e = ring.offsets[i]; e < ring.offsets[i + 1]; ++e) touch_row(ring.cols[e]);
      b.graph.offsets[i + 1] = count;
    }
  });
  control.check();
  for (std::size_t i = 0; i < n; ++i) b.graph.offsets[i + 1] += b.graph.offsets[i];
  b.graph.cols.resize(b.graph.offsets[n]);
  b.values.resize(b.graph.offsets[n]);
  parallel_for(workers, threads, [&](int worker) {
    control.check();
    const auto [begin, end] = range(worker);
    std::vector<std::int32_t> slot(n, -1);  // column -> position in the current row, -1 when absent
    std::vector<double> acc;
    for (std::size_t i = begin; i < end; ++i) {
      const std::size_t row_start = b.graph.offsets[i];
      std::uint32_t used = 0;
      acc.assign(b.graph.offsets[i + 1] - row_start, 0.0);
      double diag = 0.0;
      auto add = [&](std::uint32_t j, double v) {
        if (j == i) {
          diag += v;
          return;
        }
        std::int32_t& s = slot[j];
        if (s < 0) {
          s = static_cast<std::int32_t>(used);
          b.graph.cols[row_start + used++] = j;
        }
        acc[static_cast<std::size_t>(s)] += v;
      };
      auto add_row = [&](std::uint32_t k, double coeff) {  // coeff * (row k of W); zero coefficients too, so the
        add(k, coeff * w_diag[k]);                         // columns are exactly those counted above
        for (std::uint32_t e = ring.offsets[k]; e < ring.offsets[k + 1]; ++e) add(ring.cols[e], coeff * w[e]);
      };
      add_row(static_cast<std::uint32_t>(i), w_diag[i] * inv_area[i]);
      for (std::uint32_t e = ring.offsets[i]; e < ring.offsets[i + 1]; ++e) {
        const std::uint32_t k = ring.cols[e];
        add_row(k, w[e] * inv_area[k]);
      }
      for (std::uint32_t p = 0; p < used; ++p) {
        const std::uint32_t j = b.graph.cols[row_start + p];
        b.values[row_start + p] = static_cast<float>(acc[p]);
        slot[j] = -1;
      }
      b.diagonal[i] = diag;
    }
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

void bilaplacian_sweep(std::vector<Vec3>& x, const SparseMatrix& b, const SweepPlan& plan, int threads) {
  sweep(plan, threads, [&](std::uint32_t i) {
    const double diag = b.diagonal[i];
    if (diag > 0.0) {
      Vec3 sum = Vec3::Zero();
      for (std::uint32_t e = b.graph.offsets[i]; e < b.graph.offsets[i + 1]; ++e) {
        sum += static_cast<double>(b.values[e]) * x[b.graph.cols[e]];
      }
      x[i] = -sum / diag;
    }
  });
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

std::vector<Vec3> vertex_normals(std::span<const Vec3> x, std::span<const Triangle> triangles) {
  std::vector<Vec3> n(x.size(), Vec3::Zero());
  for (const Triangle& t : triangles) {
    const Vec3 a = (x[t[1]] - x[t[0]]).cross(x[t[2]] - x[t[0]]);  // |a| = 2 area
    for (int c = 0; c < 3; ++c) n[t[c]] += a;
  }
  for (Vec3& v : n) {
    const double len = v.norm();
    v = len > 0.0 ? Vec3(v / len) : Vec3::Zero();
  }
  return n;
}

}  // namespace surfacer::particle_smoothing
