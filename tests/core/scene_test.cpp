// Tests for core/scene/scene.h: known values and signs, exact gradients against central differences, bounds that
// contain the solid, exact distances under rigid/uniform-scale transforms, and argument validation.
#include "core/scene/scene.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <functional>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "core/util/errors.h"
#include "tests/support/error_expectations.h"

namespace surfacer {
namespace {

constexpr double kPi = std::numbers::pi;

Vec3 random_point(std::mt19937& rng, const Aabb& box) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Vec3 p;
  for (int i = 0; i < 3; ++i) p[i] = box.min[i] + u(rng) * (box.max[i] - box.min[i]);
  return p;
}

Aabb cube(double h) { return Aabb{Vec3::Constant(-h), Vec3::Constant(h)}; }

Vec3 central_difference(const Field& f, const Vec3& p, double h) {
  Vec3 g;
  for (int i = 0; i < 3; ++i) {
    Vec3 a = p, b = p;
    a[i] += h;
    b[i] -= h;
    g[i] = (f.value(a) - f.value(b)) / (2.0 * h);
  }
  return g;
}

// value_and_gradient agrees with value(), and its gradient with central differences, at random points of `region`.
// Points near a seam (where central differences with steps h and 2h disagree, judged from value() alone) are
// skipped; at least 80% of the points must be checked.
void expect_exact_gradient(const Field& f, const Aabb& region, unsigned seed, int samples = 400) {
  std::mt19937 rng(seed);
  const double h = 1e-6 * std::max(1.0, region.size().maxCoeff());
  int checked = 0;
  for (int s = 0; s < samples; ++s) {
    const Vec3 p = random_point(rng, region);
    Vec3 g;
    const double v = f.value_and_gradient(p, g);
    const double v0 = f.value(p);
    ASSERT_NEAR(v, v0, 1e-12 * (1.0 + std::abs(v0))) << "at " << p.transpose();
    const Vec3 fd = central_difference(f, p, h);
    const Vec3 fd2 = central_difference(f, p, 2.0 * h);
    const double scale = 1.0 + fd.norm();
    if ((fd - fd2).norm() > 1e-5 * scale) continue;  // a seam within 2h
    ++checked;
    EXPECT_LT((g - fd).norm(), 2e-5 * scale)
        << "at " << p.transpose() << " gradient " << g.transpose() << " differences " << fd.transpose();
  }
  EXPECT_GE(checked, samples * 8 / 10) << "too many points near seams";
}

// Every sampled point with value <= 0 lies inside bounds().
void expect_bounds_contain_solid(const Field& f, const Aabb& region, unsigned seed, int samples = 20000) {
  const std::optional<Aabb> b = f.bounds();
  ASSERT_TRUE(b.has_value());
  std::mt19937 rng(seed);
  int inside = 0;
  for (int s = 0; s < samples; ++s) {
    const Vec3 p = random_point(rng, region);
    if (f.value(p) > 0.0) continue;
    ++inside;
    EXPECT_TRUE(b->contains(p)) << "solid point " << p.transpose() << " outside bounds [" << b->min.transpose()
                                << "] - [" << b->max.transpose() << "]";
  }
  EXPECT_GT(inside, 0) << "no solid point sampled; widen the region";
}

// |grad f| == 1 wherever an exact signed distance is differentiable (skip seams as above).
void expect_unit_gradient(const Field& f, const Aabb& region, unsigned seed, int samples = 400) {
  std::mt19937 rng(seed);
  int checked = 0;
  for (int s = 0; s < samples; ++s) {
    const Vec3 p = random_point(rng, region);
    const Vec3 fd = central_difference(f, p, 1e-6), fd2 = central_difference(f, p, 2e-6);
    if ((fd - fd2).norm() > 1e-5) continue;
    Vec3 g;
    f.value_and_gradient(p, g);
    ++checked;
    EXPECT_NEAR(g.norm(), 1.0, 1e-9) << "at " << p.transpose();
  }
  EXPECT_GE(checked, samples * 8 / 10);
}

// Runs `fn`, expecting surfacer::Error of kind kInvalidInput naming `field`, in its message too (up to any '[').
void expect_invalid(const std::function<void()>& fn, const std::string& field) {
  EXPECT_TRUE(testing::throws_error(fn, ErrorKind::kInvalidInput, field, field.substr(0, field.find('['))));
}

double nan() { return std::numeric_limits<double>::quiet_NaN(); }

// Quilez's sdCappedCone, as an independent reference for make_cone.
double iq_capped_cone(const Vec3& p, const Vec3& a, const Vec3& b, double ra, double rb) {
  const double rba = rb - ra;
  const double baba = (b - a).dot(b - a);
  const double papa = (p - a).dot(p - a);
  const double paba = (p - a).dot(b - a) / baba;
  const double x = std::sqrt(std::max(0.0, papa - paba * paba * baba));
  const double cax = std::max(0.0, x - ((paba < 0.5) ? ra : rb));
  const double cay = std::abs(paba - 0.5) - 0.5;
  const double k = rba * rba + baba;
  const double f = std::clamp((rba * (x - ra) + paba * baba) / k, 0.0, 1.0);
  const double cbx = x - ra - f * rba;
  const double cby = paba - f;
  const double s = (cbx < 0.0 && cay < 0.0) ? -1.0 : 1.0;
  return s * std::sqrt(std::min(cax * cax + cay * cay * baba, cbx * cbx + cby * cby * baba));
}

// --- Known values --------------------------------------------------------------------------------------------
TEST(SceneTest, SphereKnownValues) {
  const FieldPtr f = make_sphere(Vec3(1, 2, 3), 2.0);
  EXPECT_DOUBLE_EQ(f->value(Vec3(1, 2, 3)), -2.0);
  EXPECT_DOUBLE_EQ(f->value(Vec3(4, 2, 3)), 1.0);
  EXPECT_DOUBLE_EQ(f->value(Vec3(1, 0, 3)), 0.0);
  Vec3 g;
  EXPECT_DOUBLE_EQ(f->value_and_gradient(Vec3(1, 2, 6), g), 1.0);
  EXPECT_TRUE(g.isApprox(Vec3(0, 0, 1)));
  // On the surface itself the gradient is the outward normal.
  f->value_and_gradient(Vec3(-1, 2, 3), g);
  EXPECT_TRUE(g.isApprox(Vec3(-1, 0, 0)));
}

TEST(SceneTest, BoxKnownValues) {
  const FieldPtr f = make_box(Vec3::Zero(), Vec3(1, 2, 3));
  EXPECT_DOUBLE_EQ(f->value(Vec3::Zero()), -1.0);
  EXPECT_NEAR(f->value(Vec3(2, 3, 4)), std::sqrt(3.0), 1e-15);  // corner distance
  EXPECT_DOUBLE_EQ(f->value(Vec3(1.5, 0, 0)), 0.5);
  EXPECT_DOUBLE_EQ(f->value(Vec3(0, -2.5, 0)), 0.5);
  EXPECT_DOUBLE_EQ(f->value(Vec3(0.5, 0, 2.75)), -0.25);
  Vec3 g;
  EXPECT_DOUBLE_EQ(f->value_and_gradient(Vec3(1, 0.5, 0.5), g), 0.0);  // on a face
  EXPECT_TRUE(g.isApprox(Vec3(1, 0, 0)));
  f->value_and_gradient(Vec3(0.2, 0.1, -2.9), g);
  EXPECT_TRUE(g.isApprox(Vec3(0, 0, -1)));
}

TEST(SceneTest, RoundedBoxKnownValues) {
  const FieldPtr f = make_rounded_box(Vec3(1, 0, 0), Vec3(1, 1, 1), 0.25);
  EXPECT_DOUBLE_EQ(f->value(Vec3(2.5, 0, 0)), 0.5);
  EXPECT_DOUBLE_EQ(f->value(Vec3(1, 0, 0)), -1.0);
  EXPECT_NEAR(f->value(Vec3(3, 2, 2)), std::sqrt(3.0) * 1.25 - 0.25, 1e-14);
  // The rounded corner is inset from the sharp corner by r (sqrt(3) - 1).
  EXPECT_NEAR(f->value(Vec3(2, 1, 1)), 0.25 * (std::sqrt(3.0) - 1.0), 1e-14);
  // radius equal to the smallest half size: a capsule-like rounded shape, allowed.
  EXPECT_NO_THROW(make_rounded_box(Vec3::Zero(), Vec3(1, 2, 3), 1.0));
}

TEST(SceneTest, CylinderKnownValues) {
  const FieldPtr f = make_cylinder(Vec3(0, 0, 0), Vec3(0, 0, 2), 1.0);
  EXPECT_DOUBLE_EQ(f->value(Vec3(2, 0, 1)), 1.0);
  EXPECT_DOUBLE_EQ(f->value(Vec3(0, 0, 3)), 1.0);
  EXPECT_DOUBLE_EQ(f->value(Vec3(0, 0, -0.5)), 0.5);
  EXPECT_NEAR(f->value(Vec3(2, 0, 3)), std::sqrt(2.0), 1e-15);
  EXPECT_DOUBLE_EQ(f->value(Vec3(0.5, 0, 1)), -0.5);
  EXPECT_NEAR(f->value(Vec3(0, 0.25, 1.9)), -0.1, 1e-15);
  // Arbitrary axis: agrees with the same cylinder rotated.
  const Vec3 a(1, -1, 0.5), b(2, 1, 2.5);
  const FieldPtr g = make_cylinder(a, b, 0.7);
  const Vec3 u = (b - a).normalized();
  const Vec3 perp = u.unitOrthogonal();
  EXPECT_NEAR(g->value(a + 0.3 * (b - a) + 0.7 * perp), 0.0, 1e-14);
  EXPECT_NEAR(g->value(b + 0.5 * u + 0.2 * perp), 0.5, 1e-14);
  EXPECT_NEAR(g->value(0.5 * (a + b)), -0.7, 1e-14);
}

TEST(SceneTest, ConeKnownValues) {
  const FieldPtr f = make_cone(Vec3(0, 0, 0), Vec3(0, 0, 1), 1.0, 0.0);
  EXPECT_DOUBLE_EQ(f->value(Vec3(0, 0, -1)), 1.0);
  EXPECT_DOUBLE_EQ(f->value(Vec3(0, 0, 2)), 1.0);  // above the apex
  EXPECT_NEAR(f->value(Vec3(0, 0, 0.1)), -0.1, 1e-15);
  EXPECT_NEAR(f->value(Vec3(1, 0, 1)), std::sqrt(0.5), 1e-15);   // facing the side
  EXPECT_NEAR(f->value(Vec3(2, 0, -1)), std::sqrt(2.0), 1e-15);  // the rim is nearest
  // Truncated cone, arbitrary axis, against Quilez's formula.
  const Vec3 a(0.5, -0.2, 0.1), b(-0.4, 0.8, 1.3);
  const FieldPtr c = make_cone(a, b, 0.9, 0.3);
  std::mt19937 rng(7);
  for (int i = 0; i < 2000; ++i) {
    const Vec3 p = random_point(rng, cube(2.5));
    EXPECT_NEAR(c->value(p), iq_capped_cone(p, a, b, 0.9, 0.3), 1e-12) << p.transpose();
  }
  // Equal radii: the same as the cylinder.
  const FieldPtr cone = make_cone(a, b, 0.6, 0.6);
  const FieldPtr cyl = make_cylinder(a, b, 0.6);
  for (int i = 0; i < 500; ++i) {
    const Vec3 p = random_point(rng, cube(2.5));
    EXPECT_NEAR(cone->value(p), cyl->value(p), 1e-12);
  }
}

TEST(SceneTest, TorusKnownValues) {
  const FieldPtr f = make_torus(Vec3::Zero(), Vec3(0, 0, 1), 2.0, 0.5);
  EXPECT_DOUBLE_EQ(f->value(Vec3(2.5, 0, 0)), 0.0);
  EXPECT_DOUBLE_EQ(f->value(Vec3(2, 0, 0)), -0.5);
  EXPECT_DOUBLE_EQ(f->value(Vec3(0, 0, 0)), 1.5);
  EXPECT_DOUBLE_EQ(f->value(Vec3(0, 2, 1)), 0.5);
  // Arbitrary axis and centre: points on the tube are on the surface.
  const Vec3 c(1, 2, -1);
  const Vec3 n = Vec3(1, 1, 0.5).normalized();
  const FieldPtr t = make_torus(c, Vec3(2, 2, 1), 1.5, 0.4);
  const Vec3 e1 = n.unitOrthogonal(), e2 = n.cross(e1);
  for (int i = 0; i < 12; ++i) {
    const double phi = 2.0 * kPi * i / 12.0;
    const Vec3 radial = std::cos(phi) * e1 + std::sin(phi) * e2;
    for (int j = 0; j < 8; ++j) {
      const double theta = 2.0 * kPi * j / 8.0;
      const Vec3 p = c + 1.5 * radial + 0.4 * (std::cos(theta) * radial + std::sin(theta) * n);
      EXPECT_NEAR(t->value(p), 0.0, 1e-14);
    }
    EXPECT_NEAR(t->value(c + 1.5 * radial), -0.4, 1e-14);
  }
}

TEST(SceneTest, PlaneKnownValues) {
  const FieldPtr f = make_plane(Vec3(0, 0, 2), 2.0);  // solid z <= 1
  EXPECT_DOUBLE_EQ(f->value(Vec3(5, -3, 3)), 2.0);
  EXPECT_DOUBLE_EQ(f->value(Vec3(0, 0, 1)), 0.0);
  EXPECT_DOUBLE_EQ(f->value(Vec3(0, 0, -1)), -2.0);
  Vec3 g;
  f->value_and_gradient(Vec3(1, 1, 1), g);
  EXPECT_TRUE(g.isApprox(Vec3(0, 0, 1)));
  EXPECT_FALSE(f->bounds().has_value());
  const FieldPtr diag = make_plane(Vec3(1, 1, 0), std::sqrt(2.0));  // x + y <= sqrt(2): distance 1 from origin
  EXPECT_NEAR(diag->value(Vec3::Zero()), -1.0, 1e-15);
}

TEST(SceneTest, CapsuleKnownValues) {
  const FieldPtr f = make_capsule(Vec3(0, 0, 0), Vec3(2, 0, 0), 0.5);
  EXPECT_DOUBLE_EQ(f->value(Vec3(1, 1, 0)), 0.5);
  EXPECT_DOUBLE_EQ(f->value(Vec3(-1, 0, 0)), 0.5);
  EXPECT_DOUBLE_EQ(f->value(Vec3(3, 0, 0)), 0.5);
  EXPECT_DOUBLE_EQ(f->value(Vec3(1, 0, 0)), -0.5);
  // Degenerate segment: a sphere.
  const FieldPtr s = make_capsule(Vec3(1, 1, 1), Vec3(1, 1, 1), 0.5);
  EXPECT_DOUBLE_EQ(s->value(Vec3(1, 1, 2)), 0.5);
}

TEST(SceneTest, GyroidKnownValues) {
  const FieldPtr f = make_gyroid(2.0, 0.2);
  EXPECT_DOUBLE_EQ(f->value(Vec3::Zero()), -0.1);  // g(0) = 0: mid-sheet
  // At (period/4, 0, 0): g = sin(pi/2) cos 0 + 0 + sin 0 cos(pi/2) = 1; k = pi.
  EXPECT_NEAR(f->value(Vec3(0.5, 0, 0)), 1.0 / kPi - 0.1, 1e-15);
  EXPECT_FALSE(f->bounds().has_value());
  // Periodic.
  EXPECT_NEAR(f->value(Vec3(0.3, 0.7, -0.2)), f->value(Vec3(2.3, -1.3, 3.8)), 1e-14);
}

TEST(SceneTest, WyvillBlobKnownValues) {
  const PointSkeleton p{Vec3(1, 0, 0), 2.0, 1.0};
  const FieldPtr f = make_blobs(std::span(&p, 1), {}, BlobOptions{BlobKernel::kWyvill, 0.5, 1.0});
  EXPECT_DOUBLE_EQ(f->value(Vec3(1, 0, 0)), -0.5);
  const double r = 1.0, x = r * r / 4.0;
  EXPECT_NEAR(f->value(Vec3(1, 1, 0)), 0.5 - std::pow(1.0 - x, 3), 1e-15);
  EXPECT_DOUBLE_EQ(f->value(Vec3(1, 0, 2.5)), 0.5);  // beyond R: no potential
  Vec3 g;
  f->value_and_gradient(Vec3(1, 0, 2.5), g);
  EXPECT_EQ(g, Vec3::Zero());
  // The iso-surface of one skeleton: (1 - r^2/R^2)^3 = iso.
  const double r_iso = 2.0 * std::sqrt(1.0 - std::cbrt(0.5));
  EXPECT_NEAR(f->value(Vec3(1, r_iso, 0)), 0.0, 1e-14);

  const SegmentSkeleton s{Vec3(0, 0, 0), Vec3(0, 0, 4), 1.0, 2.0};
  const FieldPtr seg = make_blobs({}, std::span(&s, 1), BlobOptions{BlobKernel::kWyvill, 0.5, 1.0});
  EXPECT_NEAR(seg->value(Vec3(0.5, 0, 2)), 0.5 - 2.0 * std::pow(0.75, 3), 1e-15);  // beside the segment
  EXPECT_NEAR(seg->value(Vec3(0, 0, 4.5)), 0.5 - 2.0 * std::pow(0.75, 3), 1e-15);  // past its end
}

TEST(SceneTest, BlinnBlobKnownValues) {
  const PointSkeleton p{Vec3::Zero(), 1.5, 2.0};
  const FieldPtr f = make_blobs(std::span(&p, 1), {}, BlobOptions{BlobKernel::kBlinn, 0.5, 3.0});
  EXPECT_NEAR(f->value(Vec3(1.5, 0, 0)), 0.5 - 2.0, 1e-15);  // strength at r = R
  EXPECT_NEAR(f->value(Vec3::Zero()), 0.5 - 2.0 * std::exp(3.0), 1e-12);
  EXPECT_NEAR(f->value(Vec3(0, 3, 0)), 0.5 - 2.0 * std::exp(-3.0 * 3.0), 1e-15);
}

// The uniform grid used beyond 64 Wyvill skeletons gives the same sums as adding the skeletons one by one.
TEST(SceneTest, WyvillGridMatchesBruteForce) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> radius(0.3, 0.9), strength(0.5, 1.5);
  std::vector<PointSkeleton> points;
  std::vector<SegmentSkeleton> segments;
  for (int i = 0; i < 150; ++i) points.push_back({random_point(rng, cube(3)), radius(rng), strength(rng)});
  for (int i = 0; i < 30; ++i) {
    const Vec3 a = random_point(rng, cube(3));
    segments.push_back({a, a + random_point(rng, cube(1)), radius(rng), strength(rng)});
  }
  const BlobOptions options{BlobKernel::kWyvill, 0.4, 1.0};
  const FieldPtr all = make_blobs(points, segments, options);
  std::vector<FieldPtr> singles;
  for (const auto& p : points) singles.push_back(make_blobs(std::span(&p, 1), {}, options));
  for (const auto& s : segments) singles.push_back(make_blobs({}, std::span(&s, 1), options));
  for (int i = 0; i < 3000; ++i) {
    const Vec3 p = random_point(rng, cube(4.5));
    double sum = 0.0;
    Vec3 grad = Vec3::Zero();
    for (const FieldPtr& f : singles) {
      Vec3 g;
      sum += options.iso - f->value_and_gradient(p, g);
      grad += g;
    }
    Vec3 g;
    const double v = all->value_and_gradient(p, g);
    ASSERT_NEAR(v, options.iso - sum, 1e-12) << p.transpose();
    ASSERT_LT((g - grad).norm(), 1e-10) << p.transpose();
  }
  expect_exact_gradient(*all, cube(3.5), 11);
  expect_bounds_contain_solid(*all, cube(5), 12);
}

// --- Exact gradients -----------------------------------------------------------------------------------------
TEST(SceneTest, PrimitiveGradientsMatchDifferences) {
  const std::vector<FieldPtr> fields = {
      make_sphere(Vec3(0.1, -0.2, 0.3), 1.2),
      make_box(Vec3(0.2, 0, -0.1), Vec3(1, 0.7, 1.3)),
      make_rounded_box(Vec3(0, 0.1, 0), Vec3(1.1, 0.8, 0.9), 0.3),
      make_cylinder(Vec3(-0.5, -0.4, -1), Vec3(0.6, 0.5, 1.2), 0.7),
      make_cone(Vec3(-0.5, -0.4, -1), Vec3(0.6, 0.5, 1.2), 1.0, 0.2),
      make_cone(Vec3(0, 0, -1), Vec3(0, 0, 1), 0.0, 1.0),
      make_torus(Vec3(0.1, 0, 0), Vec3(1, 2, 3), 1.4, 0.5),
      make_plane(Vec3(1, -2, 0.5), 0.3),
      make_capsule(Vec3(-1, 0.5, 0), Vec3(1, -0.5, 0.4), 0.6),
      make_gyroid(1.7, 0.3),
  };
  unsigned seed = 100;
  for (const FieldPtr& f : fields) {
    SCOPED_TRACE(seed);
    expect_exact_gradient(*f, cube(2.5), seed++);
  }
}

TEST(SceneTest, DistancePrimitivesHaveUnitGradient) {
  const std::vector<FieldPtr> fields = {
      make_sphere(Vec3(0.1, -0.2, 0.3), 1.2),
      make_box(Vec3(0.2, 0, -0.1), Vec3(1, 0.7, 1.3)),
      make_rounded_box(Vec3(0, 0.1, 0), Vec3(1.1, 0.8, 0.9), 0.3),
      make_cylinder(Vec3(-0.5, -0.4, -1), Vec3(0.6, 0.5, 1.2), 0.7),
      make_cone(Vec3(-0.5, -0.4, -1), Vec3(0.6, 0.5, 1.2), 1.0, 0.2),
      make_torus(Vec3(0.1, 0, 0), Vec3(1, 2, 3), 1.4, 0.5),
      make_plane(Vec3(1, -2, 0.5), 0.3),
      make_capsule(Vec3(-1, 0.5, 0), Vec3(1, -0.5, 0.4), 0.6),
  };
  unsigned seed = 200;
  for (const FieldPtr& f : fields) {
    SCOPED_TRACE(seed);
    expect_unit_gradient(*f, cube(2.5), seed++);
  }
}

TEST(SceneTest, BlobGradientsMatchDifferences) {
  const std::vector<PointSkeleton> points = {
      {Vec3(0, 0, 0), 1.2, 1.0}, {Vec3(0.9, 0.2, 0), 0.8, 1.5}, {Vec3(-0.5, 0.7, 0.3), 1.0, -0.4}};
  const std::vector<SegmentSkeleton> segments = {{Vec3(-1, -1, 0), Vec3(1, -0.8, 0.5), 0.6, 1.0},
                                                 {Vec3(0, 0, -1), Vec3(0, 0, 1), 0.5, 0.7}};
  unsigned seed = 300;
  for (BlobKernel kernel : {BlobKernel::kWyvill, BlobKernel::kBlinn}) {
    const FieldPtr f = make_blobs(points, segments, BlobOptions{kernel, 0.5, 2.0});
    SCOPED_TRACE(seed);
    expect_exact_gradient(*f, cube(2), seed++);
    expect_bounds_contain_solid(*f, cube(4), seed++);
    // Points only / segments only.
    expect_exact_gradient(*make_blobs(points, {}, BlobOptions{kernel, 0.3, 1.0}), cube(2), seed++);
    expect_exact_gradient(*make_blobs({}, segments, BlobOptions{kernel, 0.3, 1.0}), cube(2), seed++);
  }
}

TEST(SceneTest, CsgGradientsMatchDifferences) {
  const FieldPtr a = make_sphere(Vec3(-0.3, 0, 0), 1.0);
  const FieldPtr b = make_box(Vec3(0.4, 0.1, 0), Vec3(0.8, 0.6, 0.7));
  const FieldPtr c = make_torus(Vec3(0, 0, 0.2), Vec3(0, 1, 1), 1.0, 0.3);
  unsigned seed = 400;
  for (CsgOp op : {CsgOp::kUnion, CsgOp::kIntersection, CsgOp::kDifference}) {
    for (CsgBlend blend : {CsgBlend::kMinMax, CsgBlend::kRFunction, CsgBlend::kSmooth}) {
      const FieldPtr f = make_csg(op, {a, b, c}, CsgOptions{blend, 0.3});
      SCOPED_TRACE(::testing::Message() << "op " << static_cast<int>(op) << " blend " << static_cast<int>(blend));
      expect_exact_gradient(*f, cube(2), seed++);
      if (op != CsgOp::kIntersection) expect_bounds_contain_solid(*f, cube(3), seed++);
    }
  }
}

TEST(SceneTest, CsgKnownValues) {
  const FieldPtr a = make_sphere(Vec3(-1, 0, 0), 1.5);
  const FieldPtr b = make_sphere(Vec3(1, 0, 0), 1.5);
  const Vec3 p(0.3, 0.2, 0.1);
  const double fa = a->value(p), fb = b->value(p);
  EXPECT_DOUBLE_EQ(make_csg(CsgOp::kUnion, {a, b})->value(p), std::min(fa, fb));
  EXPECT_DOUBLE_EQ(make_csg(CsgOp::kIntersection, {a, b})->value(p), std::max(fa, fb));
  EXPECT_DOUBLE_EQ(make_csg(CsgOp::kDifference, {a, b})->value(p), std::max(fa, -fb));
  const CsgOptions r{CsgBlend::kRFunction, 0.0};
  EXPECT_DOUBLE_EQ(make_csg(CsgOp::kUnion, {a, b}, r)->value(p), fa + fb - std::hypot(fa, fb));
  EXPECT_DOUBLE_EQ(make_csg(CsgOp::kIntersection, {a, b}, r)->value(p), fa + fb + std::hypot(fa, fb));
  EXPECT_DOUBLE_EQ(make_csg(CsgOp::kDifference, {a, b}, r)->value(p), fa - fb + std::hypot(fa, fb));
  // Smooth: on the bisector (a == b) the union dips k/4 below min and the intersection rises k/4 above max.
  const CsgOptions s{CsgBlend::kSmooth, 0.4};
  const Vec3 q(0, 0.5, 0.3);
  EXPECT_NEAR(make_csg(CsgOp::kUnion, {a, b}, s)->value(q), a->value(q) - 0.1, 1e-15);
  EXPECT_NEAR(make_csg(CsgOp::kIntersection, {a, b}, s)->value(q), a->value(q) + 0.1, 1e-15);
  // Far from the blend the smooth operations are exact.
  const Vec3 far(-2.4, 0, 0);
  EXPECT_DOUBLE_EQ(make_csg(CsgOp::kUnion, {a, b}, s)->value(far), a->value(far));
  // The R-function union has the same sign as min(a, b) everywhere; the intersection as max(a, b).
  std::mt19937 rng(5);
  const FieldPtr ru = make_csg(CsgOp::kUnion, {a, b}, r), ri = make_csg(CsgOp::kIntersection, {a, b}, r);
  for (int i = 0; i < 2000; ++i) {
    const Vec3 x = random_point(rng, cube(3));
    EXPECT_EQ(ru->value(x) < 0.0, std::min(a->value(x), b->value(x)) < 0.0);
    EXPECT_EQ(ri->value(x) < 0.0, std::max(a->value(x), b->value(x)) < 0.0);
  }
  // R-function gradient at f1 = f2 = 0 is guarded (finite): the two spheres' intersection circle.
  Vec3 g;
  const double h = std::sqrt(1.5 * 1.5 - 1.0);
  ru->value_and_gradient(Vec3(0, h, 0), g);
  EXPECT_TRUE(g.allFinite());
  EXPECT_GT(g.norm(), 0.0);
}

TEST(SceneTest, CsgBounds) {
  const FieldPtr a = make_sphere(Vec3(-1, 0, 0), 1.0);
  const FieldPtr b = make_box(Vec3(1, 0, 0), Vec3(1, 1, 1));
  const FieldPtr plane = make_plane(Vec3(0, 0, 1), 0.0);
  const Aabb u = *make_csg(CsgOp::kUnion, {a, b})->bounds();
  EXPECT_TRUE(u.min.isApprox(Vec3(-2, -1, -1)));
  EXPECT_TRUE(u.max.isApprox(Vec3(2, 1, 1)));
  EXPECT_FALSE(make_csg(CsgOp::kUnion, {a, plane})->bounds().has_value());
  const Aabb i = *make_csg(CsgOp::kIntersection, {a, b, plane})->bounds();
  EXPECT_TRUE(i.min.isApprox(Vec3(0, -1, -1)));
  EXPECT_TRUE(i.max.isApprox(Vec3(0, 1, 1)) || i.max.x() == 0.0);
  EXPECT_FALSE(make_csg(CsgOp::kIntersection, {plane, make_gyroid(1, 0.1)})->bounds().has_value());
  const Aabb d = *make_csg(CsgOp::kDifference, {b, a})->bounds();
  EXPECT_TRUE(d.min.isApprox(Vec3(0, -1, -1)));
  EXPECT_FALSE(make_csg(CsgOp::kDifference, {plane, a})->bounds().has_value());
  // The smooth union dips at most radius / 4 below min: distance children's boxes grow by that much.
  const Aabb s = *make_csg(CsgOp::kUnion, {a, b}, CsgOptions{CsgBlend::kSmooth, 0.5})->bounds();
  EXPECT_DOUBLE_EQ(s.min.x(), -2.125);
  expect_bounds_contain_solid(*make_csg(CsgOp::kUnion, {a, b}, CsgOptions{CsgBlend::kSmooth, 2.0}), cube(4), 33);
  // Gyroid sheet inside a sphere: bounded by the sphere.
  const FieldPtr g = make_csg(CsgOp::kIntersection, {make_gyroid(1.0, 0.1), make_sphere(Vec3::Zero(), 2.0)});
  EXPECT_TRUE(g->bounds()->max.isApprox(Vec3(2, 2, 2)));
  expect_bounds_contain_solid(*g, cube(3), 31);
  // Smooth union of many children stays inside its padded bounds.
  std::vector<FieldPtr> many;
  for (int k = 0; k < 6; ++k) many.push_back(make_sphere(Vec3(0.5 * k, 0, 0), 0.4));
  expect_bounds_contain_solid(*make_csg(CsgOp::kUnion, many, CsgOptions{CsgBlend::kSmooth, 0.6}), cube(5), 32);
}

// Every primitive's bounds() holds its solid.
TEST(SceneTest, PrimitiveBoundsContainSolid) {
  const std::vector<FieldPtr> fields = {
      make_sphere(Vec3(0.1, -0.2, 0.3), 1.2),
      make_box(Vec3(0.2, 0, -0.1), Vec3(1, 0.7, 1.3)),
      make_rounded_box(Vec3(0, 0.1, 0), Vec3(1.1, 0.8, 0.9), 0.3),
      make_cylinder(Vec3(-0.5, -0.4, -1), Vec3(0.6, 0.5, 1.2), 0.7),
      make_cone(Vec3(-0.5, -0.4, -1), Vec3(0.6, 0.5, 1.2), 1.0, 0.2),
      make_torus(Vec3(0.1, 0, 0), Vec3(1, 2, 3), 1.4, 0.5),
      make_capsule(Vec3(-1, 0.5, 0), Vec3(1, -0.5, 0.4), 0.6),
  };
  unsigned seed = 500;
  for (const FieldPtr& f : fields) {
    SCOPED_TRACE(seed);
    expect_bounds_contain_solid(*f, cube(3), seed++);
    // And the boxes are reasonably tight: not more than the solid's extent plus a little.
    EXPECT_LT(f->bounds()->size().maxCoeff(), 4.0);
  }
}

// --- Transforms ----------------------------------------------------------------------------------------------
TEST(SceneTest, RigidAndUniformScaleKeepDistances) {
  const Eigen::Matrix3d rot = Eigen::AngleAxisd(0.7, Vec3(1, 2, -1).normalized()).toRotationMatrix();
  const Vec3 t(0.5, -1, 2);
  const double s = 2.5;
  // A scaled, rotated, moved sphere is the sphere of radius s r at the moved centre.
  const FieldPtr sphere = make_transform(make_sphere(Vec3(0.2, 0.1, 0), 0.8), s * rot, t);
  const FieldPtr expected = make_sphere(s * rot * Vec3(0.2, 0.1, 0) + t, s * 0.8);
  std::mt19937 rng(9);
  for (int i = 0; i < 500; ++i) {
    const Vec3 p = t + random_point(rng, cube(4));
    EXPECT_NEAR(sphere->value(p), expected->value(p), 1e-12);
  }
  const std::vector<FieldPtr> children = {
      make_box(Vec3(0.2, 0, -0.1), Vec3(1, 0.7, 1.3)),
      make_cylinder(Vec3(-0.5, -0.4, -1), Vec3(0.6, 0.5, 1.2), 0.7),
      make_cone(Vec3(-0.5, -0.4, -1), Vec3(0.6, 0.5, 1.2), 1.0, 0.2),
      make_torus(Vec3(0.1, 0, 0), Vec3(1, 2, 3), 1.4, 0.5),
  };
  unsigned seed = 600;
  for (const FieldPtr& c : children) {
    const FieldPtr f = make_transform(c, s * rot, t);
    const Aabb region{t.array() - 6.0, t.array() + 6.0};
    SCOPED_TRACE(seed);
    expect_unit_gradient(*f, region, seed++);
    expect_exact_gradient(*f, region, seed++);
    expect_bounds_contain_solid(*f, region, seed++);
  }
  // Reflections keep distances too.
  const Eigen::Matrix3d mirror = Eigen::Vector3d(-1, 1, 1).asDiagonal();
  const FieldPtr m = make_transform(make_sphere(Vec3(1, 0, 0), 0.5), mirror, Vec3::Zero());
  EXPECT_DOUBLE_EQ(m->value(Vec3(-1, 0, 0)), -0.5);
  EXPECT_DOUBLE_EQ(m->value(Vec3(-1, 0, 1)), 0.5);
}

TEST(SceneTest, GeneralAffineKeepsSignAndZeroSet) {
  Eigen::Matrix3d a;
  a << 2.0, 0.3, 0.0, -0.2, 0.7, 0.4, 0.1, 0.0, 1.5;
  const Vec3 t(1, 2, 3);
  const FieldPtr child = make_torus(Vec3::Zero(), Vec3(0, 0, 1), 1.0, 0.3);
  const FieldPtr f = make_transform(child, a, t);
  std::mt19937 rng(13);
  for (int i = 0; i < 1000; ++i) {
    const Vec3 x = random_point(rng, cube(1.6));
    EXPECT_NEAR(f->value(a * x + t), child->value(x), 1e-12);
  }
  const Aabb region{t.array() - 4.0, t.array() + 4.0};
  expect_exact_gradient(*f, region, 14);
  expect_bounds_contain_solid(*f, region, 15);
  // Nested transforms compose.
  const FieldPtr nested = make_transform(make_transform(child, a, t), a.inverse(), -a.inverse() * t);
  for (int i = 0; i < 100; ++i) {
    const Vec3 x = random_point(rng, cube(2));
    EXPECT_NEAR(nested->value(x), child->value(x), 1e-12);
  }
}

// --- Sampled grids -------------------------------------------------------------------------------------------
struct SampledSphere {
  SampledGridDesc desc;
  std::vector<float> values;
};

// Signed distance to a sphere of radius r at c, sampled on n^3 points over [-1.5, 1.5]^3.
SampledSphere sample_sphere(int n, const Vec3& c, double r, bool potential = false) {
  SampledSphere s;
  s.desc.origin = Vec3::Constant(-1.5);
  s.desc.spacing = Vec3::Constant(3.0 / (n - 1));
  s.desc.nx = s.desc.ny = s.desc.nz = n;
  s.desc.potential = potential;
  s.desc.iso = potential ? 0.25 : 0.0;
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        const Vec3 p = s.desc.origin + s.desc.spacing.cwiseProduct(Vec3(i, j, k));
        const double d = (p - c).norm() - r;
        s.values.push_back(static_cast<float>(potential ? 0.25 - d : d));
      }
  return s;
}

TEST(SceneTest, SampledGridInterpolates) {
  const SampledSphere s = sample_sphere(25, Vec3(0.1, 0, -0.1), 1.0);
  const FieldPtr f = make_sampled_grid(s.desc, s.values);
  // Exact at the samples.
  const int n = s.desc.nx;
  for (int idx : {0, 7, 312, n * n * n - 1}) {
    const int i = idx % n, j = (idx / n) % n, k = idx / (n * n);
    const Vec3 p = s.desc.origin + s.desc.spacing.cwiseProduct(Vec3(i, j, k));
    EXPECT_NEAR(f->value(p), s.values[idx], 1e-7);
  }
  // Close to the analytic sphere inside the grid.
  const FieldPtr exact = make_sphere(Vec3(0.1, 0, -0.1), 1.0);
  std::mt19937 rng(17);
  for (int i = 0; i < 500; ++i) {
    const Vec3 p = random_point(rng, cube(1.4));
    EXPECT_NEAR(f->value(p), exact->value(p), 0.03);  // trilinear error, largest at the centre's cusp
  }
  // Outside: the boundary value plus the distance to the grid box.
  EXPECT_NEAR(f->value(Vec3(2.5, 0, 0)), f->value(Vec3(1.5, 0, 0)) + 1.0, 1e-12);
  EXPECT_NEAR(f->value(Vec3(2.5, 1.5, -3.5)), f->value(Vec3(1.5, 1.5, -1.5)) + std::sqrt(1.0 + 4.0), 1e-12);
  // Potential grids: inside where value > iso.
  const SampledSphere sp = sample_sphere(25, Vec3(0.1, 0, -0.1), 1.0, true);
  const FieldPtr pot = make_sampled_grid(sp.desc, sp.values);
  for (int i = 0; i < 200; ++i) {
    const Vec3 p = random_point(rng, cube(2));
    EXPECT_NEAR(pot->value(p), f->value(p), 1e-6);
  }
}

TEST(SceneTest, SampledGridGradientsAndBounds) {
  const SampledSphere s = sample_sphere(17, Vec3(0.2, -0.1, 0), 0.8);
  const FieldPtr f = make_sampled_grid(s.desc, s.values);
  expect_exact_gradient(*f, cube(2.5), 21);  // inside and outside the grid box
  expect_bounds_contain_solid(*f, cube(2.5), 22);
  const Aabb b = *f->bounds();
  EXPECT_LT(b.size().maxCoeff(), 2.0);  // tighter than the grid box (3)
  const SampledSphere sp = sample_sphere(17, Vec3(0.2, -0.1, 0), 0.8, true);
  const FieldPtr pot = make_sampled_grid(sp.desc, sp.values);
  expect_exact_gradient(*pot, cube(2.5), 23);
  expect_bounds_contain_solid(*pot, cube(2.5), 24);
  // A solid cut by the grid boundary reaches past it by at most the boundary's depth, and bounds() says so.
  const SampledSphere big = sample_sphere(9, Vec3(1.2, 0, 0), 1.0);
  const FieldPtr cut = make_sampled_grid(big.desc, big.values);
  expect_bounds_contain_solid(*cut, cube(3), 25);
  EXPECT_GT(cut->bounds()->max.x(), 1.5);
  // The gradient is the exact derivative of the interpolant (compare at a cell interior).
  const Vec3 p(0.13, -0.41, 0.27);
  Vec3 g;
  f->value_and_gradient(p, g);
  EXPECT_LT((g - central_difference(*f, p, 1e-7)).norm(), 1e-6);
}

// No point outside sublevel_bounds(level) has value <= level: random points in the box grown by twice its size
// (outside the box), and points along rays out to a thousand times its size. bounds() is level 0.
void expect_positive_outside_bounds(const Field& f, unsigned seed, double level = 0.0) {
  const std::optional<Aabb> b = f.sublevel_bounds(level);
  ASSERT_TRUE(b.has_value());
  if (level == 0.0) {
    ASSERT_TRUE(f.bounds().has_value());
    EXPECT_TRUE(f.bounds()->min == b->min && f.bounds()->max == b->max);
  }
  const double size = 1.0 + b->size().maxCoeff();
  std::mt19937 rng(seed);
  const Aabb around = b->padded(2.0 * size);
  int outside = 0;
  for (int s = 0; s < 4000; ++s) {
    const Vec3 p = random_point(rng, around);
    if (b->contains(p)) continue;
    ++outside;
    EXPECT_GT(f.value(p), level) << "at " << p.transpose() << ", outside [" << b->min.transpose() << "] - ["
                                 << b->max.transpose() << "]";
  }
  EXPECT_GT(outside, 1000);
  std::normal_distribution<double> n(0.0, 1.0);
  const Vec3 centre = 0.5 * (b->min + b->max);
  for (int r = 0; r < 64; ++r) {
    const Vec3 dir = Vec3(n(rng), n(rng), n(rng)).normalized();
    for (double t : {1.0, 3.0, 10.0, 100.0, 1000.0}) {
      const Vec3 p = centre + t * size * dir;
      EXPECT_GT(f.value(p), level) << "at " << p.transpose();
    }
  }
}

// A smooth blend lowers a union below its children by up to radius / 4 wherever they are within a radius of each
// other. Children that are not distances can stay that close far from their solids: a sphere stretched by a
// non-uniform map (its value shrinks with the stretch), a sampled grid, blobs (their value tends to iso). bounds()
// must still hold the whole solid, for every operation and radius.
TEST(SceneTest, SmoothBlendBoundsHoldTheSolidOfAnyChildren) {
  std::vector<FieldPtr> children;
  for (double stretch : {1e-3, 1.0, 1e3}) {
    const Eigen::Matrix3d a = Eigen::Vector3d(stretch, stretch, 1.001 * stretch).asDiagonal();
    children.push_back(make_transform(make_sphere(Vec3(0.3, 0, 0), 0.5), a, Vec3(0, 0.2 * stretch, 0)));
  }
  const SampledSphere grid = sample_sphere(9, Vec3(0.1, 0, 0.2), 0.7);
  children.push_back(make_sampled_grid(grid.desc, grid.values));
  const PointSkeleton point{Vec3(0, 0.4, 0), 0.8, 1.0};
  children.push_back(make_blobs(std::span(&point, 1), {}, BlobOptions{BlobKernel::kWyvill, 0.5, 1.0}));
  children.push_back(make_blobs(std::span(&point, 1), {}, BlobOptions{BlobKernel::kBlinn, 0.5, 2.0}));
  unsigned seed = 700;
  for (double radius : {0.05, 0.6, 1.9}) {
    for (std::size_t i = 0; i < children.size(); ++i) {
      for (std::size_t j = 0; j < children.size(); ++j) {
        if (i == j) continue;
        for (CsgOp op : {CsgOp::kUnion, CsgOp::kIntersection, CsgOp::kDifference}) {
          SCOPED_TRACE(::testing::Message()
                       << "radius " << radius << " children " << i << ", " << j << " op " << static_cast<int>(op));
          const FieldPtr f = make_csg(op, {children[i], children[j]}, CsgOptions{CsgBlend::kSmooth, radius});
          if (f->bounds()) expect_positive_outside_bounds(*f, seed++);
        }
        // Unions of three, and a union nested in a union.
        const FieldPtr three = make_csg(CsgOp::kUnion, {children[i], children[j], children[(i + j + 1) % 6]},
                                        CsgOptions{CsgBlend::kSmooth, radius});
        if (three->bounds()) expect_positive_outside_bounds(*three, seed++);
        const FieldPtr nested = make_csg(CsgOp::kUnion, {three, children[j]}, CsgOptions{CsgBlend::kSmooth, radius});
        if (nested->bounds()) expect_positive_outside_bounds(*nested, seed++);
      }
    }
  }
  // Two sets of blobs blended wider than 4 iso lie below 0 everywhere far away: unbounded, and bounds() says so.
  const PointSkeleton other{Vec3(2, 0, 0), 0.5, 1.0};
  const FieldPtr far_blobs = make_blobs(std::span(&other, 1), {}, BlobOptions{BlobKernel::kWyvill, 0.5, 1.0});
  const FieldPtr wide = make_csg(CsgOp::kUnion, {children[4], far_blobs}, CsgOptions{CsgBlend::kSmooth, 2.5});
  EXPECT_FALSE(wide->bounds().has_value());
  EXPECT_LT(wide->value(Vec3(1e6, -3e5, 7e5)), 0.0);
  // Narrower than 4 iso it is bounded, and its solid lies within its bounds.
  const FieldPtr narrow = make_csg(CsgOp::kUnion, {children[4], far_blobs}, CsgOptions{CsgBlend::kSmooth, 1.5});
  ASSERT_TRUE(narrow->bounds().has_value());
  expect_positive_outside_bounds(*narrow, seed++);
  // One set of blobs whose iso is far below the blend is bounded when the other children grow away from their
  // solids: the blend only dips where children come within its radius.
  for (double iso : {1e-300, 1e-3, 0.1}) {
    const FieldPtr faint = make_blobs(std::span(&other, 1), {}, BlobOptions{BlobKernel::kWyvill, iso, 1.0});
    for (const FieldPtr& partner : {children[0], children[1], children[3]}) {
      const FieldPtr mixed =
          make_csg(CsgOp::kUnion, {partner, faint, children[3], children[2]}, CsgOptions{CsgBlend::kSmooth, 0.3});
      ASSERT_TRUE(mixed->bounds().has_value()) << "iso " << iso;
      expect_positive_outside_bounds(*mixed, seed++);
    }
  }
}

// sublevel_bounds(level) holds {value <= level} for every kind of node and level, nested in each CSG blend and in
// transforms (uniform scale, which scales values, and a general map, which does not).
TEST(SceneTest, SublevelBoundsHoldTheSetBelowEachLevel) {
  const SampledSphere grid = sample_sphere(9, Vec3(0.1, 0, 0.2), 0.7);
  const PointSkeleton point{Vec3(0, 0.4, 0), 0.8, 1.0};
  const SegmentSkeleton segment{Vec3(-0.5, 0, 0), Vec3(0.5, 0.2, 0), 0.6, 1.2};
  std::vector<FieldPtr> leaves = {
      make_sphere(Vec3(0.1, -0.2, 0.3), 1.2),
      make_rounded_box(Vec3(0, 0.1, 0), Vec3(1.1, 0.8, 0.9), 0.3),
      make_cylinder(Vec3(-0.5, -0.4, -1), Vec3(0.6, 0.5, 1.2), 0.7),
      make_cone(Vec3(-0.5, -0.4, -1), Vec3(0.6, 0.5, 1.2), 1.0, 0.2),
      make_torus(Vec3(0.1, 0, 0), Vec3(1, 2, 3), 1.4, 0.5),
      make_capsule(Vec3(-1, 0, 0), Vec3(1, 0.5, 0), 0.4),
      make_sampled_grid(grid.desc, grid.values),
      make_blobs(std::span(&point, 1), std::span(&segment, 1), BlobOptions{BlobKernel::kWyvill, 0.8, 1.0}),
      make_blobs(std::span(&point, 1), {}, BlobOptions{BlobKernel::kBlinn, 0.8, 2.0}),
  };
  const std::size_t primitives = leaves.size();
  for (std::size_t i = 0; i < primitives; ++i) {
    const Eigen::Matrix3d general = (Eigen::Matrix3d() << 2, 0.3, 0, 0, 0.5, 0.1, 0.2, 0, 1.5).finished();
    leaves.push_back(make_transform(leaves[i], 0.5 * Eigen::Matrix3d::Identity(), Vec3(0.3, 0, 0)));
    leaves.push_back(make_transform(leaves[i], general, Vec3(0, -0.2, 0.1)));
  }
  unsigned seed = 900;
  for (double level : {0.0, 0.05, 0.5, 3.0}) {
    for (std::size_t i = 0; i < leaves.size(); ++i) {
      SCOPED_TRACE(::testing::Message() << "level " << level << " leaf " << i);
      if (leaves[i]->sublevel_limit() > level) expect_positive_outside_bounds(*leaves[i], seed++, level);
      for (CsgBlend blend : {CsgBlend::kMinMax, CsgBlend::kRFunction, CsgBlend::kSmooth}) {
        const FieldPtr& other = leaves[(i * 7 + 3) % leaves.size()];
        for (CsgOp op : {CsgOp::kUnion, CsgOp::kIntersection, CsgOp::kDifference}) {
          const FieldPtr f = make_csg(op, {leaves[i], other, leaves[(i + 1) % leaves.size()]}, {blend, 0.4});
          if (f->sublevel_bounds(level)) expect_positive_outside_bounds(*f, seed++, level);
        }
      }
    }
  }
}

// The R-function blends keep their value when one child is many orders of magnitude larger than the other (the
// textbook a + b - sqrt(a^2 + b^2) cancels to 0 there, putting points far outside the solid on its surface).
TEST(SceneTest, RFunctionKeepsItsValueWhenChildrenDifferByManyOrders) {
  const FieldPtr unit = make_sphere(Vec3::Zero(), 1.0);
  const CsgOptions r{CsgBlend::kRFunction, 0.0};
  // A far sphere whose value is multiplied by 1e6 per non-uniform squeeze (the map keeps its sign, not distances).
  FieldPtr amplified = make_sphere(Vec3(0, 50, 0), 1.0);
  const Eigen::Matrix3d squeeze = Eigen::Vector3d(1e-6, 1, 1).asDiagonal();
  for (int level = 0; level <= 4; ++level) {
    SCOPED_TRACE(::testing::Message() << "squeezed " << level << " times");
    const FieldPtr u = make_csg(CsgOp::kUnion, {unit, amplified}, r);
    const FieldPtr d = make_csg(CsgOp::kDifference, {unit, amplified}, r);
    const FieldPtr i = make_csg(CsgOp::kIntersection,
                                {unit, make_csg(CsgOp::kDifference, {make_sphere(Vec3::Zero(), 1e3), amplified})}, r);
    for (const Vec3& p : {Vec3(3, 0, 0), Vec3(0, -7, 2), Vec3(-20, 1, 1)}) {
      const double a = unit->value(p), big = amplified->value(p);
      ASSERT_GT(big / a, 1.0);
      // For 0 < a <= b the union lies in [(2 - sqrt 2) a, a] and tends to a as b / a grows; meet(a, -b) lies in
      // [a, (2 + sqrt 2) a] and also tends to a.
      const double tolerance = big / a > 1e8 ? 1e-6 : 1.0 - (2.0 - std::numbers::sqrt2);
      EXPECT_NEAR(u->value(p) / a, 1.0, tolerance) << "at " << p.transpose() << ", b / a = " << big / a;
      EXPECT_GE(d->value(p), a * (1 - 1e-12)) << "at " << p.transpose();
      EXPECT_NEAR(d->value(p) / a, 1.0, big / a > 1e8 ? 1e-6 : 1.0 + std::numbers::sqrt2);
      EXPECT_GT(i->value(p), 0.0) << "at " << p.transpose();
      Vec3 g;
      EXPECT_NEAR(u->value_and_gradient(p, g), u->value(p), 1e-12 * a);
      EXPECT_TRUE(g.allFinite());
    }
    expect_positive_outside_bounds(*u, 800 + level);
    amplified = make_transform(amplified, squeeze, Vec3::Zero());
  }
}

// --- Validation ----------------------------------------------------------------------------------------------
TEST(SceneTest, PrimitiveValidation) {
  const Vec3 o = Vec3::Zero(), x = Vec3::UnitX();
  expect_invalid([&] { make_sphere(o, -1.0); }, "radius");
  expect_invalid([&] { make_sphere(o, 0.0); }, "radius");
  expect_invalid([&] { make_sphere(o, nan()); }, "radius");
  expect_invalid([&] { make_sphere(Vec3(nan(), 0, 0), 1.0); }, "center.x");
  expect_invalid([&] { make_sphere(Vec3(0, 0, INFINITY), 1.0); }, "center.z");
  expect_invalid([&] { make_box(o, Vec3(1, 0, 1)); }, "half_size.y");
  expect_invalid([&] { make_rounded_box(o, Vec3(1, 1, 1), 1.5); }, "radius");
  expect_invalid([&] { make_rounded_box(o, Vec3(1, 1, 1), 0.0); }, "radius");
  expect_invalid([&] { make_cylinder(o, o, 1.0); }, "b");
  expect_invalid([&] { make_cylinder(o, x, -2.0); }, "radius");
  expect_invalid([&] { make_cone(o, x, 0.0, 0.0); }, "radius_a");
  expect_invalid([&] { make_cone(o, x, 1.0, -0.5); }, "radius_b");
  expect_invalid([&] { make_cone(x, x, 1.0, 0.5); }, "b");
  expect_invalid([&] { make_torus(o, o, 2.0, 0.5); }, "axis");
  expect_invalid([&] { make_torus(o, x, 1.0, 1.5); }, "minor_radius");
  expect_invalid([&] { make_torus(o, x, -1.0, 0.5); }, "major_radius");
  expect_invalid([&] { make_plane(o, 1.0); }, "normal");
  expect_invalid([&] { make_plane(x, nan()); }, "offset");
  expect_invalid([&] { make_capsule(o, Vec3(0, nan(), 0), 1.0); }, "b.y");
  expect_invalid([&] { make_gyroid(0.0, 0.1); }, "period");
  expect_invalid([&] { make_gyroid(1.0, -0.1); }, "thickness");
  // The message says what is wrong.
  try {
    make_sphere(o, -1.0);
  } catch (const Error& e) {
    EXPECT_STREQ(e.what(), "radius (-1) must be > 0");
  }
  try {
    make_sphere(Vec3(nan(), 0, 0), 1.0);
  } catch (const Error& e) {
    EXPECT_STREQ(e.what(), "center.x is NaN; give a finite number");
  }
}

// Found by fuzzing scene JSON (fuzz/corpus/scene_json/crash-blobs-*): with more than 64 Wyvill skeletons the
// acceleration grid counted its cells in int64 from the skeletons' extent: skeletons far apart overflowed it
// (undefined behaviour; a huge or negative cell count), and radii whose square underflows gave a zero cell size.
TEST(SceneTest, ManyBlobsFarApartBuildAndEvaluate) {
  std::vector<PointSkeleton> points;
  for (int i = 0; i < 70; ++i) points.push_back({Vec3::Constant(i * 1e7), 1.0, 1.0});
  const FieldPtr f = make_blobs(points, {}, BlobOptions{});
  for (const PointSkeleton& p : points) EXPECT_NEAR(f->value(p.center), 0.5 - 1.0, 1e-12);  // iso - strength
  EXPECT_NEAR(f->value(Vec3::Constant(5e6)), 0.5, 1e-12);  // between skeletons: no potential
  ASSERT_TRUE(f->bounds());
  EXPECT_TRUE(f->bounds()->contains(points.back().center));

  std::vector<PointSkeleton> tiny(70, PointSkeleton{Vec3::Zero(), 1e-200, 1.0});
  expect_invalid([&] { make_blobs(tiny, {}, BlobOptions{}); }, "points[0].radius");
  std::vector<PointSkeleton> huge;
  for (int i = 0; i < 70; ++i) huge.push_back({Vec3((i % 2 ? 1 : -1) * 1e308, 0, 0), 1e308, 1.0});
  expect_invalid([&] { make_blobs(huge, {}, BlobOptions{}); }, "points[0].center.x");
  const SegmentSkeleton wide{Vec3(-1e308, 0, 0), Vec3(1e308, 0, 0), 1.0, 1.0};
  expect_invalid([&] { make_blobs({}, std::span(&wide, 1), BlobOptions{}); }, "segments[0].a.x");
  // Within the range of coordinates, but a Blinn kernel this strong would overflow.
  BlobOptions blinn;
  blinn.kernel = BlobKernel::kBlinn;
  blinn.blobbiness = 1e9;
  expect_invalid([&] { make_blobs(points, {}, blinn); }, "blobbiness");
}

TEST(SceneTest, CoordinatesAndLengthsStayWithinTheirRange) {
  expect_invalid([&] { make_sphere(Vec3::Zero(), 1e308); }, "radius");
  expect_invalid([&] { make_sphere(Vec3(0, 2e12, 0), 1.0); }, "center.y");
  expect_invalid([&] { make_box(Vec3::Zero(), Vec3(1, 1e13, 1)); }, "half_size.y");
  expect_invalid([&] { make_plane(Vec3::UnitZ(), -1e300); }, "offset");
  expect_invalid([&] { make_gyroid(1e200, 0.1); }, "period");
  // Too small is refused too: 2 pi / a denormal period overflows, and the field is garbage.
  expect_invalid([&] { make_gyroid(1.35807730621777e-312, 0.3); }, "period");
  expect_invalid([&] { make_sphere(Vec3::Zero(), 1e-13); }, "radius");
  EXPECT_NO_THROW(make_gyroid(1e-9, 1e-10));
  SampledGridDesc grid;
  grid.nx = grid.ny = grid.nz = 2;
  grid.iso = 1e100;
  const std::vector<float> values(8, 0.0f);
  expect_invalid([&] { make_sampled_grid(grid, values); }, "iso");
  // Each argument in range, but the transform carries the child too far.
  const FieldPtr big = make_sphere(Vec3::Zero(), 1e11);
  EXPECT_NO_THROW(make_transform(big, 5.0 * Eigen::Matrix3d::Identity(), Vec3::Zero()));
  expect_invalid([&] { make_transform(big, 1e3 * Eigen::Matrix3d::Identity(), Vec3::Zero()); }, "linear");
  EXPECT_NO_THROW(make_sphere(Vec3::Constant(1e12 - 1.0), 1.0));
}

TEST(SceneTest, CompositeValidation) {
  const FieldPtr s = make_sphere(Vec3::Zero(), 1.0);
  expect_invalid([&] { make_csg(CsgOp::kUnion, {s}); }, "children");
  expect_invalid([&] { make_csg(CsgOp::kUnion, {s, nullptr}); }, "children[1]");
  expect_invalid([&] { make_csg(CsgOp::kUnion, {s, s}, CsgOptions{CsgBlend::kSmooth, 0.0}); }, "radius");
  expect_invalid([&] { make_csg(CsgOp::kUnion, {s, s}, CsgOptions{CsgBlend::kSmooth, nan()}); }, "radius");
  EXPECT_NO_THROW(make_csg(CsgOp::kUnion, {s, s}, CsgOptions{CsgBlend::kMinMax, 0.0}));

  Eigen::Matrix3d singular;
  singular << 1, 2, 3, 2, 4, 6, 0, 0, 1;
  expect_invalid([&] { make_transform(s, singular, Vec3::Zero()); }, "linear");
  expect_invalid([&] { make_transform(s, Eigen::Matrix3d::Zero(), Vec3::Zero()); }, "linear");
  Eigen::Matrix3d bad = Eigen::Matrix3d::Identity();
  bad(1, 2) = nan();
  expect_invalid([&] { make_transform(s, bad, Vec3::Zero()); }, "linear(1,2)");
  expect_invalid([&] { make_transform(s, Eigen::Matrix3d::Identity(), Vec3(0, nan(), 0)); }, "translation.y");
  expect_invalid([&] { make_transform(nullptr, Eigen::Matrix3d::Identity(), Vec3::Zero()); }, "child");

  const PointSkeleton p{Vec3::Zero(), 1.0, 1.0};
  expect_invalid([&] { make_blobs({}, {}, BlobOptions{}); }, "points");
  expect_invalid([&] { make_blobs(std::span(&p, 1), {}, BlobOptions{BlobKernel::kWyvill, 0.0, 1.0}); }, "iso");
  expect_invalid([&] { make_blobs(std::span(&p, 1), {}, BlobOptions{BlobKernel::kBlinn, 0.5, 0.0}); }, "blobbiness");
  const std::vector<PointSkeleton> points = {p, {Vec3::Zero(), -1.0, 1.0}};
  expect_invalid([&] { make_blobs(points, {}, BlobOptions{}); }, "points[1].radius");
  const SegmentSkeleton seg{Vec3::Zero(), Vec3(0, 0, nan()), 1.0, 1.0};
  expect_invalid([&] { make_blobs({}, std::span(&seg, 1), BlobOptions{}); }, "segments[0].b.z");

  SampledGridDesc desc;
  desc.nx = desc.ny = desc.nz = 2;
  std::vector<float> values(8, 1.0f);
  EXPECT_NO_THROW(make_sampled_grid(desc, values));
  SampledGridDesc d1 = desc;
  d1.ny = 1;
  expect_invalid([&] { make_sampled_grid(d1, std::span(values.data(), 4)); }, "ny");
  expect_invalid([&] { make_sampled_grid(desc, std::span(values.data(), 7)); }, "values");
  SampledGridDesc d2 = desc;
  d2.spacing = Vec3(1, 0, 1);
  expect_invalid([&] { make_sampled_grid(d2, values); }, "spacing.y");
  // Found by fuzzing scene JSON (fuzz/corpus/scene_json/crash-grid-denormal-spacing): 1/spacing overflowed to
  // infinity and evaluation turned NaN into a cell index (undefined behaviour).
  // Found by fuzzing (fuzz/corpus/scene_json/crash-grid-dims-wrap): 2^30 * 16 * 2^30 wrapped to 0 in 64 bits, so a
  // grid with no values passed the count check and evaluation read outside them.
  SampledGridDesc wrap = desc;
  wrap.nx = wrap.nz = 1 << 30;
  wrap.ny = 16;
  expect_invalid([&] { make_sampled_grid(wrap, {}); }, "nx");
  SampledGridDesc d3 = desc;
  d3.spacing = Vec3(1, 1, std::numeric_limits<double>::denorm_min());
  expect_invalid([&] { make_sampled_grid(d3, values); }, "spacing.z");
  values[5] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_TRUE(
      testing::throws_error([&] { make_sampled_grid(desc, values); }, ErrorKind::kInvalidInput, "values", "values[5]"));
}

}  // namespace
}  // namespace surfacer
