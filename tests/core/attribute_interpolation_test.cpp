#include "core/particles/attribute_interpolation.h"

#include <gtest/gtest.h>

#include <random>
#include <string>

#include "core/particles/particle_surfacer.h"
#include "core/util/errors.h"

namespace surfacer {
namespace {

struct ParticleSet {
  std::string name;
  std::vector<Vec3> positions;
  std::vector<double> radii;  // empty: uniform r_inner
  double r_inner = 0.5;
};

// A jittered lattice ball (a droplet), a thin sheet of two layers, scattered spray with per-particle radii.
std::vector<ParticleSet> particle_sets() {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> jitter(-0.15, 0.15), u(-4.0, 4.0), r(0.4, 0.7);
  std::vector<ParticleSet> sets;
  ParticleSet droplet{"droplet", {}, {}, 0.5};
  for (int k = -4; k <= 4; ++k) {
    for (int j = -4; j <= 4; ++j) {
      for (int i = -4; i <= 4; ++i) {
        const Vec3 q(i, j, k);
        if (q.norm() <= 4.0) droplet.positions.push_back(q + Vec3(jitter(rng), jitter(rng), jitter(rng)));
      }
    }
  }
  sets.push_back(droplet);
  ParticleSet sheet{"sheet", {}, {}, 0.5};
  for (int k = 0; k < 2; ++k) {
    for (int j = 0; j < 12; ++j) {
      for (int i = 0; i < 12; ++i) sheet.positions.emplace_back(i, j, 0.8 * k);
    }
  }
  sets.push_back(sheet);
  ParticleSet spray{"spray with radii", {}, {}, 0.5};
  for (int n = 0; n < 60; ++n) {
    spray.positions.emplace_back(u(rng), u(rng), u(rng));
    spray.radii.push_back(r(rng));
  }
  sets.push_back(spray);
  return sets;
}

struct Surfaced {
  Mesh mesh;
  ParticleSurfacingStats stats;
};

Surfaced surface(const ParticleSet& set) {
  ParticleSurfacingOptions options;
  options.r_inner = set.r_inner;
  Surfaced s;
  s.mesh = surface_particles(set.positions, set.radii, options, {}, &s.stats);
  return s;
}

TEST(AttributeInterpolation, ConstantFieldComesBackExactly) {
  for (const ParticleSet& set : particle_sets()) {
    const Surfaced s = surface(set);
    ASSERT_FALSE(s.mesh.vertices.empty()) << set.name;
    const std::vector<float> value = {1013.25f, -0.1f, 3.0e-7f};
    Attribute density{"density", 1, std::vector<float>(set.positions.size(), value[0])};
    Attribute velocity{"velocity", 3, {}};
    for (std::size_t i = 0; i < set.positions.size(); ++i)
      velocity.values.insert(velocity.values.end(), value.begin(), value.end());
    const std::vector<Attribute> out = interpolate_attributes(
        set.positions, std::vector<Attribute>{density, velocity}, s.mesh.vertices,
        AttributeInterpolationOptions::particle_support(s.stats.r_inner, s.stats.r_outer, set.radii));
    ASSERT_EQ(out.size(), 2u);
    EXPECT_EQ(out[0].name, "density");
    EXPECT_EQ(out[1].name, "velocity");
    ASSERT_EQ(out[0].count(), s.mesh.vertices.size());
    ASSERT_EQ(out[1].count(), s.mesh.vertices.size());
    for (std::size_t v = 0; v < s.mesh.vertices.size(); ++v) {
      ASSERT_EQ(out[0].values[v], value[0]) << set.name << " vertex " << v;
      for (int c = 0; c < 3; ++c) ASSERT_EQ(out[1].values[3 * v + c], value[c]) << set.name << " vertex " << v;
    }
  }
}

TEST(AttributeInterpolation, LinearFieldWithinSupportTimesGradient) {
  const Vec3 gradient(0.3, -1.7, 0.9);
  const double offset = 5.0;
  for (const ParticleSet& set : particle_sets()) {
    const Surfaced s = surface(set);
    ASSERT_FALSE(s.mesh.vertices.empty()) << set.name;
    Attribute field{"field", 1, {}};
    for (const Vec3& p : set.positions) field.values.push_back(static_cast<float>(offset + gradient.dot(p)));
    const AttributeInterpolationOptions support =
        AttributeInterpolationOptions::particle_support(s.stats.r_inner, s.stats.r_outer, set.radii);
    const std::vector<Attribute> out =
        interpolate_attributes(set.positions, std::vector<Attribute>{field}, s.mesh.vertices, support);
    double worst = 0.0, sum = 0.0;
    for (std::size_t v = 0; v < s.mesh.vertices.size(); ++v) {
      const double error = std::abs(out[0].values[v] - (offset + gradient.dot(s.mesh.vertices[v])));
      worst = std::max(worst, error);
      sum += error;
    }
    // A convex combination of values within R of the vertex (float32 values: a small absolute slack).
    EXPECT_LE(worst, support.radius * gradient.norm() + 1e-4) << set.name;
    // And far better on average than the bound (the kernel centres on the vertex).
    EXPECT_LT(sum / static_cast<double>(s.mesh.vertices.size()), 0.75 * support.radius * gradient.norm()) << set.name;
  }
}

TEST(AttributeInterpolation, NoOvershootAndNearestFallback) {
  // Two particles with values 0 and 1: every vertex between them gets a value in [0, 1]; a vertex beyond every
  // particle's reach takes its nearest particle's value.
  const std::vector<Vec3> particles = {Vec3(0, 0, 0), Vec3(1, 0, 0)};
  const Attribute mask{"foam", 1, {0.0f, 1.0f}};
  AttributeInterpolationOptions options;
  options.radius = 1.5;
  const std::vector<Vec3> vertices = {Vec3(0.5, 0.3, 0), Vec3(0.1, 1.0, 0), Vec3(9, 0, 0), Vec3(-9, 0, 0)};
  const std::vector<Attribute> out = interpolate_attributes(particles, std::vector<Attribute>{mask}, vertices, options);
  EXPECT_NEAR(out[0].values[0], 0.5f, 1e-6);
  EXPECT_GT(out[0].values[1], 0.0f);
  EXPECT_LT(out[0].values[1], 0.5f);
  EXPECT_EQ(out[0].values[2], 1.0f);
  EXPECT_EQ(out[0].values[3], 0.0f);
}

TEST(AttributeInterpolation, RefusesAMismatchedAttribute) {
  const std::vector<Vec3> particles = {Vec3(0, 0, 0), Vec3(1, 0, 0)};
  const Attribute short_one{"density", 1, {1.0f}};
  EXPECT_THROW(interpolate_attributes(particles, std::vector<Attribute>{short_one}, particles, {}), Error);
}

}  // namespace
}  // namespace surfacer
