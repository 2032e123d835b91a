#include "core/particles/spatial_hash.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <random>

#include "core/util/errors.h"

namespace surfacer {
namespace {

std::vector<Vec3> random_points(std::size_t n, double extent, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-extent, extent);
  std::vector<Vec3> p(n);
  for (Vec3& v : p) v = Vec3(u(rng), u(rng), u(rng));
  return p;
}

// A dense clump plus a few points very far away: forces the sparse (hashed) layout.
std::vector<Vec3> clump_and_spray(std::uint32_t seed) {
  std::vector<Vec3> p = random_points(2000, 1.0, seed);
  std::mt19937 rng(seed + 1);
  std::uniform_real_distribution<double> u(-5000.0, 5000.0);
  for (int i = 0; i < 50; ++i) p.emplace_back(u(rng), u(rng), u(rng));
  return p;
}

std::optional<SpatialHash::Neighbor> brute_nearest(const std::vector<Vec3>& p, const Vec3& q, double max_distance) {
  std::optional<SpatialHash::Neighbor> best;
  for (std::size_t i = 0; i < p.size(); ++i) {
    const double d = (p[i] - q).norm();
    if (d <= max_distance && (!best || d < best->distance))
      best = SpatialHash::Neighbor{static_cast<std::uint32_t>(i), d};
  }
  return best;
}

void check_against_brute_force(const std::vector<Vec3>& points, double cell, double query_extent, bool expect_dense) {
  const SpatialHash hash(points, cell);
  EXPECT_EQ(hash.dense(), expect_dense);
  EXPECT_EQ(hash.size(), points.size());
  const std::vector<Vec3> queries = random_points(300, query_extent, 99);
  for (const Vec3& q : queries) {
    for (const double max_distance : {0.05, 0.3, 2.0, std::numeric_limits<double>::infinity()}) {
      const auto expected = brute_nearest(points, q, max_distance);
      // The first search's radius changes the rounds, never the answer.
      for (const double first_radius : {0.0, 0.5 * cell, 0.3, 5.0}) {
        const auto got = hash.nearest(q, max_distance, first_radius);
        ASSERT_EQ(expected.has_value(), got.has_value()) << max_distance << " " << first_radius;
        if (expected) {
          EXPECT_DOUBLE_EQ(got->distance, expected->distance);
          EXPECT_DOUBLE_EQ((points[got->index] - q).norm(), got->distance);
        }
      }
    }
    // within(): exactly the brute-force set.
    std::vector<std::uint32_t> got;
    hash.within(q, 0.4, got);
    std::sort(got.begin(), got.end());
    std::vector<std::uint32_t> expected;
    for (std::size_t i = 0; i < points.size(); ++i) {
      if ((points[i] - q).norm() <= 0.4) expected.push_back(static_cast<std::uint32_t>(i));
    }
    EXPECT_EQ(got, expected);
    // bounded_distance(): exact inside [stop, max], below stop when something is closer, infinite when none.
    const double exact = brute_nearest(points, q, std::numeric_limits<double>::infinity())->distance;
    const double stop = 0.1, max_distance = 0.5;
    const double bounded = hash.bounded_distance(q, max_distance, stop);
    if (exact > max_distance) {
      EXPECT_TRUE(std::isinf(bounded));
    } else if (exact >= stop) {
      EXPECT_DOUBLE_EQ(bounded, exact);
    } else {
      EXPECT_GE(bounded, exact);
      EXPECT_LT(bounded, stop);
    }
  }
}

TEST(SpatialHash, DenseLayoutMatchesBruteForce) {
  check_against_brute_force(random_points(3000, 1.0, 1), 0.1, 1.5, true);
}

TEST(SpatialHash, DenseLayoutWithCrowdedCellsMatchesBruteForce) {
  // 3000 points in 27 cells: a group of cells holds more than a byte's count, so every cell keeps a full offset.
  check_against_brute_force(random_points(3000, 0.14, 5), 0.1, 1.5, true);
}

TEST(SpatialHash, DenseOffsetsTakeAboutAByteACell) {
  const std::vector<Vec3> points = random_points(3000, 1.0, 6);
  const double cell = 0.08;
  const SpatialHash hash(points, cell);
  ASSERT_TRUE(hash.dense());
  const Aabb box = Aabb::of(points);
  double cells = 1.0;
  for (int a = 0; a < 3; ++a) cells *= std::floor((box.max[a] - box.min[a]) / cell) + 1.0;
  const double per_point = sizeof(Vec3) + sizeof(std::uint32_t);  // the sorted copy and the order
  EXPECT_LE(static_cast<double>(hash.memory_bytes()), per_point * points.size() + 1.2 * cells + 64.0);
}

TEST(SpatialHash, SparseLayoutMatchesBruteForce) {
  const std::vector<Vec3> points = clump_and_spray(2);
  check_against_brute_force(points, 0.1, 1.5, false);
  // Far queries still find the exact nearest of the scattered points.
  const SpatialHash hash(points, 0.1);
  for (const Vec3& q : random_points(100, 6000.0, 3)) {
    const auto got = hash.nearest(q);
    ASSERT_TRUE(got);
    EXPECT_DOUBLE_EQ(got->distance, brute_nearest(points, q, std::numeric_limits<double>::infinity())->distance);
  }
  // Memory stays O(points) although the box spans ~10^5 cells per axis.
  EXPECT_LT(hash.memory_bytes(), 200 * points.size());
}

TEST(SpatialHash, CellOrderIsAPermutationAndSpatiallyCoherent) {
  const std::vector<Vec3> points = random_points(5000, 1.0, 4);
  const SpatialHash hash(points, 0.2);
  std::vector<std::uint32_t> order(hash.order().begin(), hash.order().end());
  for (std::size_t s = 0; s < order.size(); ++s) EXPECT_EQ(hash.sorted_points()[s], points[order[s]]);
  std::sort(order.begin(), order.end());
  for (std::size_t i = 0; i < order.size(); ++i) ASSERT_EQ(order[i], i);
  // Consecutive slots are much closer on average than consecutive input points.
  double sorted_step = 0.0, input_step = 0.0;
  for (std::size_t s = 1; s < points.size(); ++s) {
    sorted_step += (hash.sorted_points()[s] - hash.sorted_points()[s - 1]).norm();
    input_step += (points[s] - points[s - 1]).norm();
  }
  EXPECT_LT(sorted_step, 0.5 * input_step);
}

TEST(SpatialHash, EmptyAndDegenerateInputs) {
  SpatialHash empty(std::vector<Vec3>{}, 1.0);
  EXPECT_TRUE(empty.empty());
  EXPECT_FALSE(empty.nearest(Vec3::Zero()));
  EXPECT_TRUE(std::isinf(empty.bounded_distance(Vec3::Zero(), 1.0, 0.5)));
  // All points equal: one cell.
  const std::vector<Vec3> same(10, Vec3(1, 2, 3));
  const SpatialHash hash(same, 0.5);
  EXPECT_EQ(hash.occupied_cells(), 1u);
  const auto n = hash.nearest(Vec3(1, 2, 4));
  ASSERT_TRUE(n);
  EXPECT_DOUBLE_EQ(n->distance, 1.0);
  // Ties go to the first point in cell order, which is stable in input order.
  EXPECT_EQ(n->index, 0u);
  // Queries with NaN find nothing rather than crash.
  EXPECT_FALSE(hash.nearest(Vec3(std::nan(""), 0, 0), 1.0));
}

TEST(SpatialHash, RejectsBadArguments) {
  const std::vector<Vec3> p = {Vec3::Zero(), Vec3::Ones()};
  for (const double cell : {0.0, -1.0, std::nan(""), std::numeric_limits<double>::infinity()}) {
    try {
      SpatialHash h(p, cell);
      ADD_FAILURE() << cell;
    } catch (const Error& e) {
      EXPECT_EQ(e.kind(), ErrorKind::kInvalidInput);
      EXPECT_EQ(e.field(), "cell_size");
    }
  }
  const std::vector<Vec3> bad = {Vec3::Zero(), Vec3(0, std::numeric_limits<double>::infinity(), 0)};
  try {
    SpatialHash h(bad, 1.0);
    ADD_FAILURE();
  } catch (const Error& e) {
    EXPECT_EQ(e.field(), "points");
    EXPECT_NE(std::string(e.what()).find("point 1"), std::string::npos) << e.what();
  }
  // 10^12 cells along an axis exceed the limit.
  const std::vector<Vec3> wide = {Vec3::Zero(), Vec3(1e6, 0, 0)};
  try {
    SpatialHash h(wide, 1e-6);
    ADD_FAILURE();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kResourceLimit);
  }
}

// group_coincident against the greedy rule done by brute force: clusters of near points, exact duplicates and
// points exactly the tolerance apart.
TEST(GroupCoincident, MatchesTheGreedyRule) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> coord(-1.0, 1.0), jitter(-1e-4, 1e-4);
  const double tolerance = 1e-4;
  std::vector<Vec3> points;
  for (int c = 0; c < 60; ++c) {
    const Vec3 centre(coord(rng), coord(rng), coord(rng));
    for (int i = 0; i < 1 + c % 7; ++i) points.push_back(centre + Vec3(jitter(rng), jitter(rng), jitter(rng)));
    if (c % 5 == 0) points.push_back(centre);
    if (c % 9 == 0) points.push_back(centre + Vec3(tolerance, 0, 0));
  }
  std::shuffle(points.begin(), points.end(), rng);
  const CoincidentGroups groups = group_coincident(points, tolerance);
  std::vector<std::uint32_t> kept;
  for (std::uint32_t i = 0; i < points.size(); ++i) {
    std::uint32_t joined = static_cast<std::uint32_t>(kept.size());
    for (std::uint32_t k = 0; k < kept.size(); ++k) {
      if ((points[kept[k]] - points[i]).norm() <= tolerance) {
        joined = k;
        break;
      }
    }
    if (joined == kept.size()) kept.push_back(i);
    ASSERT_EQ(groups.group[i], joined) << i;
  }
  EXPECT_EQ(groups.kept, kept);
  EXPECT_LT(kept.size(), points.size());
}

TEST(SpatialHash, AnyPairWithinFindsTheClosePairOnly) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> coord(0.0, 1.0);
  std::vector<Vec3> points(20000);
  for (Vec3& p : points) p = Vec3(coord(rng), coord(rng), coord(rng));
  double closest = std::numeric_limits<double>::infinity();
  const SpatialHash hash(points, 0.05);
  for (std::size_t i = 0; i < points.size(); ++i) {
    hash.for_each_within(points[i], 0.01, [&](std::uint32_t j, const Vec3&, double d2) {
      if (j != i) closest = std::min(closest, std::sqrt(d2));
    });
  }
  ASSERT_LT(closest, 0.01);
  EXPECT_FALSE(hash.any_pair_within(0.999 * closest));
  EXPECT_TRUE(hash.any_pair_within(closest * (1.0 + 1e-12)));
  points.push_back(points[123] + Vec3(0, 0, 1e-12));
  EXPECT_TRUE(SpatialHash(points, 0.05).any_pair_within(1e-12));
  EXPECT_TRUE(SpatialHash(std::vector<Vec3>(3, Vec3::Ones()), 1.0).any_pair_within(0.0));
  EXPECT_FALSE(SpatialHash(std::vector<Vec3>{Vec3::Ones()}, 1.0).any_pair_within(1.0));
}

TEST(GroupCoincident, ManyIdenticalPointsInLinearTime) {
  const std::vector<Vec3> same(1000000, Vec3(3.0, -2.0, 1e6));
  const auto t0 = std::chrono::steady_clock::now();
  const CoincidentGroups groups = group_coincident(same, 0.0);
  EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::seconds(2));
  EXPECT_EQ(groups.kept, std::vector<std::uint32_t>{0});
  EXPECT_TRUE(std::all_of(groups.group.begin(), groups.group.end(), [](std::uint32_t g) { return g == 0; }));
  EXPECT_TRUE(group_coincident({}, 1.0).kept.empty());
}

}  // namespace
}  // namespace surfacer
