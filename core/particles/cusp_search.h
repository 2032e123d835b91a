// The cusp search of particle surfacing (docs/ALGORITHMS.md §1, CHOICE "cusps held"): the lowest point where three
// outer spheres meet, uncovered by the other balls, that a vertex holds. Used by core/particles/particle_surfacer.cpp
// only; a header of its own so that tests can hold it against a search of every triple.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <optional>
#include <span>
#include <vector>

#include "core/util/geometry.h"

namespace surfacer::particle_cusps {

// A cusp is held by a vertex only when its axis is within 60 degrees of the vertex normal (docs/ALGORITHMS.md §1,
// CHOICE "cusps held"): a cusp seen edge-on belongs to another side of the fluid.
constexpr double kCuspFacing = 0.5;
// A vertex with more outer spheres than this passing near it holds no cusp (docs/ALGORITHMS.md §1, CHOICE "coincident
// particles merged"): the search is cubic in them.
constexpr std::size_t kMaxCuspSpheres = 96;
// lowest_cusp: pairs of spheres whose circle passes within cell (1 + this) + this radius of x may share a cusp with a
// third (a margin far above rounding; the exact test follows).
constexpr double kCuspPairMargin = 1e-6;
// lowest_cusp: an arc of a pair's circle counts as inside a ball only with this much to spare in the cosine of the
// angles compared, above their rounding (a sine taken as sqrt(1 - c^2) near c = +-1 loses about 1e-8).
constexpr double kCuspArcMargin = 1e-7;
// lowest_cusp: a pair of spheres with at least this many third spheres to try is first tested against this many of
// the deepest balls around the vertex, each of which may cover its whole arc near the vertex (then it is skipped).
constexpr int kCuspArcMinThirds = 4;
constexpr std::size_t kCuspArcBalls = 4;

// An outer ball near a vertex.
struct Ball {
  Vec3 centre;
  double radius;
};

// The plane through a cusp perpendicular to its axis, (axis, offset) . (y, -1) = 0; the particles lie on the side
// axis . y < offset. All zero: no plane. One 4-vector, so that sums of planes are two SIMD adds.
struct CuspPlane {
  Eigen::Vector4d equation = Eigen::Vector4d::Zero();
  Vec3 axis() const { return equation.head<3>(); }
  double offset() const { return equation[3]; }
};

// What a held cusp asks of a vertex x + t n: t <= bound, the plane through the cusp.
struct HeldCusp {
  double bound = std::numeric_limits<double>::infinity();
  CuspPlane plane;
};

// Whether q is inside the ball (by more than rounding): a point on its sphere is not.
inline bool inside_ball(const Vec3& q, const Ball& ball) {
  return (q - ball.centre).squaredNorm() < ball.radius * ball.radius * (1.0 - 1e-9);
}

// The circle where the spheres of A and B (dab apart) meet: centre A + u ex, in the plane normal to ex, of squared
// radius rho2, with the squared distance from x to it; nullopt when they do not meet in a circle.
struct Circle {
  Vec3 ex;
  double dab, u, rho2, distance2;
};
inline std::optional<Circle> pair_circle(const Ball& A, const Ball& B, const Vec3& x) {
  const Vec3 ab = B.centre - A.centre;
  const double dab = ab.norm();
  if (!(dab > 0.0) || dab >= A.radius + B.radius) return std::nullopt;
  const Vec3 ex = ab / dab;
  const double u = (A.radius * A.radius - B.radius * B.radius + dab * dab) / (2.0 * dab);
  const double rho2 = A.radius * A.radius - u * u;
  if (!(rho2 >= 0.0)) return std::nullopt;
  const Vec3 rel = x - A.centre - u * ex;
  const double axial = rel.dot(ex), radial = std::sqrt(std::max(0.0, rel.squaredNorm() - axial * axial));
  const double gap = radial - std::sqrt(rho2);
  return Circle{ex, dab, u, rho2, axial * axial + gap * gap};
}

// Where a third sphere C meets the circle of A and B: the points foot +- sqrt(w2) ez, ez the unit normal of the three
// centres' plane (trilateration in the frame A at 0, B on ex, C in the (ex, ey) plane); nullopt when the centres are
// collinear (the spheres meet in a circle or not at all) or C misses the circle.
struct TriplePoints {
  Vec3 foot, ez;
  double w2;
};
inline std::optional<TriplePoints> triple_points(const Ball& A, const Circle& ab, const Ball& C) {
  const Vec3& ex = ab.ex;
  const double u = ab.u, dab = ab.dab;
  const Vec3 ac = C.centre - A.centre;
  const double i = ex.dot(ac);
  const Vec3 off = ac - i * ex;
  const double j = off.norm();
  if (!(j > 1e-9 * dab)) return std::nullopt;
  const Vec3 ey = off / j;
  const double ra2 = A.radius * A.radius;
  const double v = (ra2 - C.radius * C.radius + i * i + j * j) / (2.0 * j) - (i / j) * u;
  const double w2 = ra2 - u * u - v * v;
  if (!(w2 >= 0.0)) return std::nullopt;
  return TriplePoints{A.centre + u * ex + v * ey, ex.cross(ey), w2};
}

// The lowest cusp a vertex x (unit normal n, Voronoi cell within `cell` of x) holds below: a point q where three outer
// spheres meet and that lies in no outer ball (a vertex of the boundary of their union), within `cell` of x, that
// owns(q) gives to this vertex, and whose axis (the unit normal of its three centres' plane, on q's side) faces the
// vertex's outside (axis . n >= kCuspFacing). `spheres` must hold every outer ball whose sphere passes within cell of
// x (the only ones on which such a q can lie) and `deeper` every other ball within its radius + cell of x: together,
// all the balls that can contain q. The bound keeps x + t n on the particles' side of the plane through q
// perpendicular to its axis; the lowest bound over the cusps wins. nullopt when no cusp qualifies. `circles` is
// scratch (the circles of the pairs that pass near x, computed once).
template <class Owns>
std::optional<HeldCusp> lowest_cusp(const Vec3& x, const Vec3& n, double cell, std::span<const Ball> spheres,
                                    std::span<const Ball> deeper, Owns&& owns, std::vector<Circle>& circles) {
  std::optional<HeldCusp> best;
  const std::size_t k = spheres.size();
  if (k < 3) return best;
  // A q of spheres a, b, c lies on all three circles of their pairs, within cell of x. So c is tried only with the
  // spheres whose circles with a and with b pass within cell of x, up to a margin far above rounding (near[a] bit c:
  // the pair passes): the same q are found as by trying every c, in the same order, at a fraction of the cost when
  // many spheres pass near x (balls many particle spacings wide).
  static_assert(kMaxCuspSpheres <= 128);
  std::array<std::array<std::uint64_t, 2>, kMaxCuspSpheres> near{};
  const double scale = spheres.front().radius;  // of the margins
  const double loose = cell * (1.0 + kCuspPairMargin) + kCuspPairMargin * scale;
  circles.clear();  // in the order the pairs are tried below
  for (std::size_t a = 0; a < k; ++a) {
    for (std::size_t b = a + 1; b < k; ++b) {
      const std::optional<Circle> ab = pair_circle(spheres[a], spheres[b], x);
      if (!ab || ab->distance2 > loose * loose) continue;
      circles.push_back(*ab);
      near[a][b >> 6] |= std::uint64_t{1} << (b & 63);
      near[b][a >> 6] |= std::uint64_t{1} << (a & 63);
    }
  }
  // Whether another ball covers a q does not depend on the order they are tried in: the balls deepest around x first
  // (most often the one that covers), so the test mostly ends at its first ball.
  std::array<std::uint8_t, kMaxCuspSpheres> by_depth;
  std::array<double, kMaxCuspSpheres> depth;
  for (std::size_t m = 0; m < k; ++m) {
    by_depth[m] = static_cast<std::uint8_t>(m);
    depth[m] = (x - spheres[m].centre).norm() - spheres[m].radius;
  }
  std::sort(
      by_depth.begin(), by_depth.begin() + static_cast<std::ptrdiff_t>(k),
      [&depth](std::uint8_t l, std::uint8_t r) { return depth[l] < depth[r] || (depth[l] == depth[r] && l < r); });
  // Whether the arc of A and B's circle within `loose` of x lies inside ball D by a margin (kCuspPairMargin of D's
  // radius and of the spheres' scale): then every q that a third sphere makes on that circle within cell of x is
  // covered by D, as the test below finds it. A q is computed on the circle up to rounding (about 1e-8 of the radius
  // at worst, where the spheres are nearly tangent), far below the margin. False whenever the arcs are not well
  // defined (x or D's centre near the circle's axis, a tiny circle): the pair is then searched.
  const auto arc_inside = [&](const Ball& A, const Circle& ab, const Ball& D) {
    const double rho2 = ab.rho2;
    if (!(rho2 > 1e-6 * scale * scale)) return false;
    const double rho = std::sqrt(rho2);
    const Vec3 centre = A.centre + ab.u * ab.ex;
    const Vec3 wx = x - centre, wd = D.centre - centre;
    const double ax = wx.dot(ab.ex), ad = wd.dot(ab.ex);
    const Vec3 px = wx - ax * ab.ex, pd = wd - ad * ab.ex;
    const double sx = px.norm(), sd = pd.norm();
    if (!(sx > 1e-9 * scale && sd > 1e-9 * scale)) return false;
    const double shrunk = D.radius * (1.0 - kCuspPairMargin) - kCuspPairMargin * scale;
    // |q - y|^2 = a_y^2 + rho^2 + s_y^2 - 2 rho s_y cos(theta - phi_y) for q at angle theta on the circle.
    const double cx = (ax * ax + rho2 + sx * sx - loose * loose) / (2.0 * rho * sx);    // near x: cos >= cx
    const double cd = (ad * ad + rho2 + sd * sd - shrunk * shrunk) / (2.0 * rho * sd);  // inside D: cos > cd
    if (!(cx <= 1.0) || !(shrunk > 0.0) || !(cd < 1.0)) return false;
    if (cd < -1.0) return true;  // the whole circle is inside D
    // The arc near x (half-width acos cx about phi_x) within the arc inside D (acos cd about phi_d): their centres'
    // angle apart, plus acos cx, below acos cd; as cosines, all angles being within [0, pi].
    if (!(cd < cx)) return false;
    const double cos_apart = px.dot(pd) / (sx * sd);
    const double cos_gap = cd * cx + std::sqrt(std::max(0.0, 1.0 - cd * cd)) * std::sqrt(std::max(0.0, 1.0 - cx * cx));
    return cos_apart > cos_gap + kCuspArcMargin;
  };
  std::size_t next_circle = 0;
  for (std::size_t a = 0; a < k; ++a) {
    const Ball& A = spheres[a];
    for (std::size_t b = a + 1; b < k; ++b) {
      if (!(near[a][b >> 6] >> (b & 63) & 1)) continue;
      // Their circle must pass within cell of x.
      const Circle& ab = circles[next_circle++];
      if (ab.distance2 > cell * cell) continue;
      std::array<std::uint64_t, 2> third{near[a][0] & near[b][0], near[a][1] & near[b][1]};
      third[b >> 6] &= ~((std::uint64_t{2} << (b & 63)) - 1);  // c > b
      if (b >= 64) third[0] = 0;
      if (third[0] == 0 && third[1] == 0) continue;
      // Where one of the deepest balls around x (other than A and B) covers the pair's whole arc near x, no q of it
      // is uncovered: the pair is skipped. Tried only for pairs with enough third spheres to repay the test (on
      // lattices with r_inner of a few spacings, where most pairs have dozens, 96 % of the pairs are skipped).
      bool covered_arc = false;
      const int thirds = std::popcount(third[0]) + std::popcount(third[1]);
      for (std::size_t o = 0, tried = 0; thirds >= kCuspArcMinThirds && o < k && tried < kCuspArcBalls && !covered_arc;
           ++o) {
        const std::size_t m = by_depth[o];
        if (m == a || m == b) continue;
        ++tried;
        covered_arc = arc_inside(A, ab, spheres[m]);
      }
      if (covered_arc) continue;
      for (std::size_t word = 0; word < 2; ++word) {
        for (std::uint64_t bits = third[word]; bits != 0; bits &= bits - 1) {
          const std::size_t c = word * 64 + static_cast<std::size_t>(std::countr_zero(bits));
          const std::optional<TriplePoints> meet = triple_points(A, ab, spheres[c]);
          if (!meet) continue;
          const Vec3& foot = meet->foot;
          const Vec3& ez = meet->ez;
          const double w2 = meet->w2;
          for (const double side : {1.0, -1.0}) {
            const Vec3 axis = side * ez;
            const double facing = axis.dot(n);
            if (facing < kCuspFacing) continue;
            const Vec3 q = foot + side * std::sqrt(w2) * ez;
            if ((q - x).squaredNorm() > cell * cell) continue;
            const double bound = (q - x).dot(axis) / facing;
            if (best && bound >= best->bound) continue;
            // In another ball? (The three defining spheres pass through q.)
            bool covered =
                std::any_of(deeper.begin(), deeper.end(), [&](const Ball& ball) { return inside_ball(q, ball); });
            for (std::size_t o = 0; o < k && !covered; ++o) {
              const std::size_t m = by_depth[o];
              covered = m != a && m != b && m != c && inside_ball(q, spheres[m]);
            }
            if (covered || !owns(q)) continue;
            best = HeldCusp{bound, CuspPlane{Eigen::Vector4d(axis.x(), axis.y(), axis.z(), axis.dot(q))}};
          }
        }
      }
    }
  }
  return best;
}

}  // namespace surfacer::particle_cusps
