// Radius tiers (core/particles/particle_index.h): particles of per-particle radii indexed in tiers answer every query
// exactly as one hash over all of them does. Held on droplets with radii spread 2.5x, droplets with a few particles
// 5 to 100 times larger or 1e2 and 1e12 times smaller, radii spread over two and a half decades, and a lattice (ties
// everywhere): the nearest values, the band along a line (its faithful point and interval, to the bit) and the outer
// balls a cusp search receives (as sets). Queries sit on and near the outer and inner spheres, deep inside and far
// outside, along random and radial lines, so that the band's window grows on the large particles' spheres.
#include "core/particles/particle_index.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <string>
#include <tuple>
#include <vector>

namespace surfacer::particle_index {
namespace {

struct Cloud {
  std::string name;
  std::vector<Vec3> positions;
  std::vector<double> radii;  // inner
};

constexpr double kRatio = 2.0;  // r_outer / r_inner
constexpr double kR = 0.01;     // the typical radius

Vec3 random_unit(std::mt19937& rng) {
  std::normal_distribution<double> g;
  Vec3 u(g(rng), g(rng), g(rng));
  return u.norm() > 1e-12 ? Vec3(u.normalized()) : Vec3::UnitX();
}

// Clusters of particles about kR apart, radii kR times U(lo, hi).
Cloud droplets(std::mt19937& rng, double lo, double hi) {
  Cloud c{"droplets", {}, {}};
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int d = 0; d < 6; ++d) {
    const Vec3 centre(u(rng) * 0.3, u(rng) * 0.3, u(rng) * 0.3);
    const double size = 0.02 + 0.04 * u(rng);
    for (int i = 0; i < 150; ++i) {
      c.positions.push_back(centre + size * std::cbrt(u(rng)) * random_unit(rng));
      c.radii.push_back(kR * (lo + (hi - lo) * u(rng)));
    }
  }
  return c;
}

Particles index_of(const Cloud& c, double spread) {
  Particles P;
  P.positions = c.positions;
  P.weighted = true;
  P.inner = c.radii;
  for (const double r : c.radii) P.outer.push_back(kRatio * r);
  P.r_inner = kR;
  P.r_outer = kRatio * kR;
  P.min_inner = *std::min_element(c.radii.begin(), c.radii.end());
  P.max_inner = *std::max_element(c.radii.begin(), c.radii.end());
  P.max_outer = kRatio * P.max_inner;
  P.index(0.5 * kR, spread);
  return P;
}

std::vector<std::tuple<double, double, double, double>> sorted(const std::vector<particle_cusps::Ball>& balls) {
  std::vector<std::tuple<double, double, double, double>> out;
  for (const particle_cusps::Ball& b : balls) out.emplace_back(b.centre.x(), b.centre.y(), b.centre.z(), b.radius);
  std::sort(out.begin(), out.end());
  return out;
}

// `wide`: how many queries had a band wider than the tiered index's first window.
void expect_same_answers(const Cloud& c, std::mt19937& rng, std::size_t min_tiers, int& wide) {
  const Particles one = index_of(c, kInf);
  const Particles tiered = index_of(c, kTierSpread);
  EXPECT_EQ(one.tiers.size(), 1u) << c.name;
  EXPECT_GE(tiered.tiers.size(), min_tiers) << c.name;
  std::size_t held = 0;
  for (const Tier& t : tiered.tiers) held += t.hash.size();
  EXPECT_EQ(held, c.positions.size()) << c.name;
  const double reach = one.max_outer - one.min_inner;
  const double first_window = tiered.tiers[tiered.main_tier].max_outer - tiered.min_inner;
  std::uniform_real_distribution<double> u(0.0, 1.0);
  BandScratch a, b;
  wide = 0;
  for (int q = 0; q < 1500; ++q) {
    const std::size_t i = static_cast<std::size_t>(u(rng) * static_cast<double>(c.positions.size()));
    const Vec3 dir = random_unit(rng);
    Vec3 x;
    switch (q % 5) {
      case 0:  // on the outer sphere
        x = c.positions[i] + kRatio * c.radii[i] * dir;
        break;
      case 1:  // near the outer sphere
        x = c.positions[i] + kRatio * c.radii[i] * (0.9 + 0.25 * u(rng)) * dir;
        break;
      case 2:  // near the inner sphere
        x = c.positions[i] + c.radii[i] * (0.95 + 0.1 * u(rng)) * dir;
        break;
      case 3:  // anywhere in the box, grown
        x = one.box.min + (one.box.max - one.box.min + 0.1 * Vec3::Ones()).cwiseProduct(Vec3(u(rng), u(rng), u(rng))) -
            0.05 * Vec3::Ones();
        break;
      default:  // far outside
        x = one.box.max + (1.0 + u(rng)) * dir.cwiseAbs();
    }
    const std::string where = c.name + " query " + std::to_string(q);
    Particles::Hit in1, out1, in2, out2;
    one.nearest_weighted(x, in1, out1);
    tiered.nearest_weighted(x, in2, out2);
    ASSERT_EQ(in1.value, in2.value) << where;
    ASSERT_EQ(out1.value, out2.value) << where;
    ASSERT_EQ(in2.value, (c.positions[in2.index] - x).norm() - c.radii[in2.index]) << where;
    ASSERT_EQ(out2.value, (c.positions[out2.index] - x).norm() - kRatio * c.radii[out2.index]) << where;

    const Vec3 n = q % 2 == 0 ? dir : Vec3(random_unit(rng));
    const double cell = q % 3 == 0 ? 0.0 : kR * (0.2 + 0.8 * u(rng));
    const std::optional<Particles::LineBand> l1 = one.band_on_line(x, n, reach, cell, a);
    const std::optional<Particles::LineBand> l2 = tiered.band_on_line(x, n, reach, cell, b);
    ASSERT_EQ(l1.has_value(), l2.has_value()) << where;
    if (l1) {
      ASSERT_EQ(l1->at, l2->at) << where;
      ASSERT_EQ(l1->band.lo, l2->band.lo) << where;
      ASSERT_EQ(l1->band.hi, l2->band.hi) << where;
      wide += l1->band.hi - l1->band.lo > first_window;
    }
    if (cell > 0.0) {
      ASSERT_EQ(sorted(a.spheres), sorted(b.spheres)) << where;
      ASSERT_EQ(sorted(a.deeper), sorted(b.deeper)) << where;
    }
  }
}

TEST(ParticleTiers, AnswerEveryQueryAsOneHashDoes) {
  std::mt19937 rng(7);
  int wide = 0;
  // Radii within a tier's spread: one tier, as before tiers.
  Cloud narrow = droplets(rng, 0.8, 1.5);
  narrow.name = "narrow droplets";
  expect_same_answers(narrow, rng, 1, wide);
  EXPECT_EQ(index_of(narrow, kTierSpread).tiers.size(), 1u);

  Cloud spread = droplets(rng, 0.6, 1.5);
  spread.name = "droplets 0.6-1.5";
  expect_same_answers(spread, rng, 2, wide);

  for (const double factor : {5.0, 20.0, 100.0}) {
    Cloud c = droplets(rng, 0.6, 1.0);
    c.name = "droplets with particles " + std::to_string(factor) + "x";
    for (int k = 0; k < 4; ++k) {  // in the clusters and beside them
      c.positions.push_back(c.positions[k * 150] + (k % 2 == 0 ? 0.0 : 0.05) * Vec3::UnitX());
      c.radii.push_back(factor * kR);
    }
    expect_same_answers(c, rng, 2, wide);
    EXPECT_GT(wide, 0) << c.name << ": no band reached past the first window";
  }

  Cloud tiny = droplets(rng, 0.9, 1.1);
  tiny.name = "droplets with particles 0.01x and 1e-12x";
  for (int k = 0; k < 10; ++k) {  // the last ones' own cells would be too many to count: coarser ones serve them
    tiny.positions.push_back(tiny.positions[k * 80] + Vec3(0.003, 0.0, 0.0));
    tiny.radii.push_back((k < 5 ? 0.01 : 1e-12) * kR);
  }
  expect_same_answers(tiny, rng, 2, wide);

  Cloud decades{"radii over two and a half decades", {}, {}};
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int i = 0; i < 400; ++i) {
    decades.positions.emplace_back(20.0 * u(rng), 20.0 * u(rng), 20.0 * u(rng));
    decades.radii.push_back(kR * std::pow(10.0, 2.5 * u(rng)));
  }
  expect_same_answers(decades, rng, 7, wide);

  Cloud lattice{"lattice", {}, {}};
  for (int i = 0; i < 8; ++i) {
    for (int j = 0; j < 8; ++j) {
      for (int k = 0; k < 8; ++k) {
        lattice.positions.emplace_back(i * kR, j * kR, k * kR);
        lattice.radii.push_back((i * 64 + j * 8 + k) % 37 == 0 ? 4.0 * kR : 0.6 * kR);
      }
    }
  }
  expect_same_answers(lattice, rng, 2, wide);
}

TEST(ParticleTiers, FindCoincidentParticlesAcrossTiers) {
  std::mt19937 rng(3);
  Cloud c = droplets(rng, 0.9, 1.0);
  Particles apart = index_of(c, kTierSpread);
  const double tolerance = 1e-6 * kR;
  ASSERT_FALSE(apart.any_pair_within(tolerance, {}));
  // A large particle at a small one's place: the two are in different tiers.
  c.positions.push_back(c.positions[10] + Vec3(0.5 * tolerance, 0.0, 0.0));
  c.radii.push_back(50.0 * kR);
  const Particles together = index_of(c, kTierSpread);
  ASSERT_EQ(together.tiers.size(), 2u);
  EXPECT_TRUE(together.any_pair_within(tolerance, {}));
  c.positions.back() += Vec3(2.0 * tolerance, 0.0, 0.0);
  EXPECT_FALSE(index_of(c, kTierSpread).any_pair_within(tolerance, {}));
}

TEST(ParticleTiers, AreBoundedInNumber) {
  Cloud c{"radii over 30 octaves", {}, {}};
  for (int i = 0; i < 40; ++i) {
    c.positions.emplace_back(i * 1.0, 0.0, 0.0);
    c.radii.push_back(kR * std::ldexp(1.0, i));
  }
  const Particles P = index_of(c, kTierSpread);
  EXPECT_EQ(P.tiers.size(), kMaxTiers);
  EXPECT_EQ(P.tiers.back().max_outer, kRatio * c.radii.back());
}

}  // namespace
}  // namespace surfacer::particle_index
