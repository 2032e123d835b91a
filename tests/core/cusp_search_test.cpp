// The cusp search (core/particles/cusp_search.h) skips pairs of spheres whose third spheres cannot give a cusp near
// the vertex (their circle far from it, or its arc near the vertex inside a deep ball). Here it is held against the
// search of every triple, with the same arithmetic per cusp, on the neighbourhoods it meets: lattices (square,
// triangular, face-centred cubic) with outer radii of 1.2 to 5 spacings, jittered and random clouds, per-particle
// radii, vertices above and inside the surface, tilted normals and Voronoi cells of several sizes. The lowest cusp
// must be the same to the bit, or absent from both.
#include "core/particles/cusp_search.h"

#include <gtest/gtest.h>

#include <iostream>
#include <numbers>
#include <random>
#include <string>
#include <vector>

namespace surfacer::particle_cusps {
namespace {

// Every triple of `spheres` whose pair's circle passes within cell of x, in order, each cusp with the arithmetic of
// lowest_cusp (pair_circle, triple_points): no pair or third sphere is skipped, and every ball is tried for cover.
template <class Owns>
std::optional<HeldCusp> every_triple(const Vec3& x, const Vec3& n, double cell, const std::vector<Ball>& spheres,
                                     const std::vector<Ball>& deeper, Owns&& owns) {
  std::optional<HeldCusp> best;
  const std::size_t k = spheres.size();
  for (std::size_t a = 0; a < k; ++a) {
    for (std::size_t b = a + 1; b < k; ++b) {
      const std::optional<Circle> ab = pair_circle(spheres[a], spheres[b], x);
      if (!ab || ab->distance2 > cell * cell) continue;
      for (std::size_t c = b + 1; c < k; ++c) {
        const std::optional<TriplePoints> meet = triple_points(spheres[a], *ab, spheres[c]);
        if (!meet) continue;
        for (const double side : {1.0, -1.0}) {
          const Vec3 axis = side * meet->ez;
          const double facing = axis.dot(n);
          if (facing < kCuspFacing) continue;
          const Vec3 q = meet->foot + side * std::sqrt(meet->w2) * meet->ez;
          if ((q - x).squaredNorm() > cell * cell) continue;
          const double bound = (q - x).dot(axis) / facing;
          if (best && bound >= best->bound) continue;
          bool covered = false;
          for (const Ball& ball : deeper) covered = covered || inside_ball(q, ball);
          for (std::size_t m = 0; m < k; ++m) {
            covered = covered || (m != a && m != b && m != c && inside_ball(q, spheres[m]));
          }
          if (covered || !owns(q)) continue;
          best = HeldCusp{bound, CuspPlane{Eigen::Vector4d(axis.x(), axis.y(), axis.z(), axis.dot(q))}};
        }
      }
    }
  }
  return best;
}

struct Cloud {
  std::vector<Vec3> centres;
  std::vector<double> radii;
};

// Lattice points around the origin (spacing 1) up to `reach` from it: square, triangular layers, or face-centred cubic.
Cloud lattice(int kind, double reach, double radius) {
  Cloud cloud;
  const int m = static_cast<int>(std::ceil(reach)) + 2;
  for (int k = -m; k <= 0; ++k) {  // the particles fill z <= 0: their top layer is the fluid's surface
    for (int j = -m; j <= m; ++j) {
      for (int i = -m; i <= m; ++i) {
        Vec3 p;
        if (kind == 0) {
          p = Vec3(i, j, k);
        } else if (kind == 1) {
          p = Vec3(i + 0.5 * (j & 1), j * std::sqrt(3.0) / 2.0, k);
        } else {
          p = Vec3(i + 0.5 * ((j + k) & 1), j * std::sqrt(3.0) / 2.0 + ((k & 1) ? std::sqrt(3.0) / 6.0 : 0.0),
                   k * std::sqrt(2.0 / 3.0));
        }
        if (p.norm() <= reach + 2.0) {
          cloud.centres.push_back(p);
          cloud.radii.push_back(radius);
        }
      }
    }
  }
  return cloud;
}

// The balls lowest_cusp is given for a vertex at x (as the surfacer gathers them): within their radius + cell of x,
// those whose sphere passes within cell of it, and the others.
void gather(const Cloud& cloud, const Vec3& x, double cell, std::vector<Ball>& spheres, std::vector<Ball>& deeper) {
  spheres.clear();
  deeper.clear();
  for (std::size_t p = 0; p < cloud.centres.size(); ++p) {
    const double r = cloud.radii[p];
    const double d2 = (cloud.centres[p] - x).squaredNorm();
    if (d2 > (r + cell) * (r + cell)) continue;
    (d2 >= (r - cell) * (r - cell) ? spheres : deeper).push_back({cloud.centres[p], r});
  }
}

TEST(CuspSearch, FindsWhatTheSearchOfEveryTripleFinds) {
  std::mt19937_64 rng(20261129);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const auto uniform = [&](double lo, double hi) { return lo + (hi - lo) * unit(rng); };
  int cases = 0, with_cusp = 0, without = 0, wide = 0;
  std::vector<Ball> spheres, deeper;
  std::vector<Circle> circles;
  for (int round = 0; round < 900; ++round) {
    const int shape = round % 6;  // 0-2 lattices, 3 jittered lattice, 4 random cloud, 5 per-particle radii
    const double radius = shape == 5 ? 1.5 : uniform(1.2, shape <= 2 ? 5.0 : 3.0);
    Cloud cloud = lattice(shape <= 2 ? shape : 0, radius, radius);
    if (shape >= 3) {
      for (Vec3& p : cloud.centres) p += Vec3(uniform(-0.3, 0.3), uniform(-0.3, 0.3), uniform(-0.3, 0.3));
    }
    if (shape == 4) {
      for (Vec3& p : cloud.centres) p = Vec3(uniform(-4, 4), uniform(-4, 4), uniform(-4, 0));
    }
    if (shape == 5) {
      for (double& r : cloud.radii) r = uniform(1.0, 2.2);
    }
    // A vertex near the union's top (or inside it), its normal tilted up to about 40 degrees from +z.
    const Vec3 x(uniform(-0.5, 0.5), uniform(-0.5, 0.5), uniform(-0.3, 1.1) * radius);
    const Vec3 n = Vec3(uniform(-0.8, 0.8), uniform(-0.8, 0.8), 1.0).normalized();
    const double cell = uniform(0.2, 1.2);
    gather(cloud, x, cell, spheres, deeper);
    if (spheres.size() > kMaxCuspSpheres) continue;
    // Half of the cases own every point; the others only those nearer x than to six points around it.
    std::vector<Vec3> ring;
    if (round % 2 == 1) {
      for (int r = 0; r < 6; ++r) {
        const double angle = r * std::numbers::pi / 3.0 + uniform(-0.2, 0.2);
        ring.push_back(x + cell * uniform(0.6, 1.0) * Vec3(std::cos(angle), std::sin(angle), uniform(-0.3, 0.3)));
      }
    }
    const auto owns = [&](const Vec3& q) {
      const double mine = (q - x).squaredNorm();
      for (const Vec3& y : ring) {
        if ((q - y).squaredNorm() < mine) return false;
      }
      return true;
    };
    const std::optional<HeldCusp> fast = lowest_cusp(x, n, cell, spheres, deeper, owns, circles);
    const std::optional<HeldCusp> slow = every_triple(x, n, cell, spheres, deeper, owns);
    ++cases;
    wide += spheres.size() >= 30;
    ASSERT_EQ(fast.has_value(), slow.has_value()) << "round " << round << ", " << spheres.size() << " spheres";
    if (!slow) {
      ++without;
      continue;
    }
    ++with_cusp;
    EXPECT_EQ(fast->bound, slow->bound) << "round " << round;
    EXPECT_EQ(fast->plane.equation, slow->plane.equation) << "round " << round;
  }
  // The cases cover both answers and the wide neighbourhoods where most pairs are skipped.
  const std::string counts = std::to_string(cases) + " cases, " + std::to_string(with_cusp) + " with a cusp, " +
                             std::to_string(without) + " without, " + std::to_string(wide) + " with 30 spheres or more";
  EXPECT_GT(cases, 700) << counts;
  EXPECT_GT(with_cusp, 100) << counts;
  EXPECT_GT(without, 100) << counts;
  EXPECT_GT(wide, 100) << counts;
  std::cout << counts << "\n";
}

}  // namespace
}  // namespace surfacer::particle_cusps
