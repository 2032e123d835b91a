#include "core/mesh/mesh_codec.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <random>
#include <string>
#include <vector>

#include "core/mesh/mesh_checks.h"
#include "core/mesh/mesh_io.h"
#include "core/polygonize/marching_cubes.h"
#include "core/util/allocation_budget.h"
#include "core/util/errors.h"
#include "tests/support/error_expectations.h"
#include "tests/support/mesh_expectations.h"
#include "tests/support/test_meshes.h"

namespace surfacer {
namespace {

// Draco may reorder and deduplicate vertices: compare geometry and topology, never indices.
void expect_same_shape(const Mesh& original, const Mesh& decoded, double tolerance) {
  EXPECT_EQ(decoded.triangles.size(), original.triangles.size());
  EXPECT_LE(testing::max_nearest_vertex_distance(decoded, original), tolerance);
  EXPECT_LE(testing::max_nearest_vertex_distance(original, decoded), tolerance);
  const MeshReport a = check_mesh(original), b = check_mesh(decoded);
  EXPECT_EQ(b.closed, a.closed);
  EXPECT_EQ(b.edge_manifold, a.edge_manifold);
  EXPECT_EQ(b.vertex_manifold, a.vertex_manifold);
  EXPECT_EQ(b.oriented, a.oriented);
  EXPECT_EQ(b.euler_characteristic, a.euler_characteristic);
  EXPECT_NEAR(b.volume, a.volume, a.area * tolerance);  // each vertex moves by at most `tolerance`
}

Mesh mc_sphere(bool normals) {
  testing::SphereField sphere(Vec3(0.05, -0.02, 0.01), 0.7);
  MarchingCubesOptions o;
  o.bounds = Aabb{Vec3::Constant(-1), Vec3::Constant(1)};
  o.cells = {40, 40, 40};
  o.normals = normals;
  return marching_cubes(sphere, o);
}

TEST(MeshCodec, RoundTripWithinQuantizationError) {
  const Mesh m = testing::icosphere(4, 1.3, Vec3(0.2, -0.1, 0.4));
  for (int bits : {8, 11, 14, 20}) {
    DracoOptions options;
    options.quantization_bits = bits;
    const std::string bytes = encode_draco(m, options);
    const Mesh d = decode_draco(bytes);
    SCOPED_TRACE(bits);
    expect_same_shape(m, d, draco_max_error(Aabb::of(m.vertices), bits));
    EXPECT_TRUE(d.normals.empty());
  }
}

TEST(MeshCodec, MarchingCubesMeshKeepsTopologyAtEverySpeed) {
  const Mesh m = mc_sphere(false);
  for (int speed : {0, 5, 7, 10}) {
    DracoOptions options;
    options.speed = speed;
    options.quantization_bounds = Aabb{Vec3::Constant(-1), Vec3::Constant(1)};
    const Mesh d = decode_draco(encode_draco(m, options));
    SCOPED_TRACE(speed);
    expect_same_shape(m, d, draco_max_error(*options.quantization_bounds, options.quantization_bits));
    const MeshReport r = check_mesh(d);
    EXPECT_TRUE(testing::mesh_has(r, testing::kClosedManifold));
    EXPECT_EQ(r.euler_characteristic, 2);
  }
}

TEST(MeshCodec, SharedQuantizationBoxPutsFramesOnOneGrid) {
  // icosphere(2)'s vertices are a prefix of icosphere(3)'s: the common vertices must decode identically.
  const Mesh coarse = testing::icosphere(2, 0.9);
  const Mesh fine = testing::icosphere(3, 0.9);
  DracoOptions options;
  options.quantization_bits = 10;
  options.quantization_bounds = Aabb{Vec3::Constant(-1.5), Vec3(1.5, 2.0, 1.0)};
  const Mesh a = decode_draco(encode_draco(coarse, options));
  const Mesh b = decode_draco(encode_draco(fine, options));
  const double step = 3.5 / 1023;
  for (const Vec3& p : coarse.vertices) {
    const Vec3 qa = a.vertices[*testing::nearest_vertex(a, p)];
    const Vec3 qb = b.vertices[*testing::nearest_vertex(b, p)];
    EXPECT_EQ(qa, qb);
    // On the grid origin + k * step.
    for (int c = 0; c < 3; ++c) {
      const double k = (qa[c] - options.quantization_bounds->min[c]) / step;
      EXPECT_NEAR(k, std::round(k), 1e-3);
    }
  }
}

// The decoded positions are exactly the job grid's points (quantization_grid): Draco would keep an explicit origin and
// range rounded to 6 decimals, off the grid the frames' stats and the pieced codecs use, and a range under 5e-7 would
// become 0. Boxes with origins that 6 decimals do not hold, at scene scales from 1e-6 to 1e4.
TEST(MeshCodec, DecodedPositionsAreTheJobGridsPointsExactly) {
  for (const double scale : {1e-6, 1e-3, 1.0, 7.3, 1e4}) {
    const Vec3 centre = Vec3(0.1234567, -0.7510416, 0.3333333) * scale;
    const Mesh m = testing::icosphere(3, 0.9 * scale, centre);
    for (const int bits : {10, 14, 16}) {
      SCOPED_TRACE(std::to_string(scale) + " scale, " + std::to_string(bits) + " bits");
      DracoOptions options;
      options.quantization_bits = bits;
      options.quantization_bounds = Aabb{centre - Vec3(1.0000001, 1.3, 0.97) * scale, centre + Vec3::Constant(scale)};
      const QuantizationGrid grid = quantization_grid(m, options);
      const Mesh d = decode_draco(encode_draco(m, options));
      ASSERT_EQ(d.vertices.size(), m.vertices.size());
      std::vector<std::array<double, 3>> expected, decoded;
      for (const Vec3& p : m.vertices) {
        const Vec3 q = grid.dequantize(grid.quantize(p));
        expected.push_back({q[0], q[1], q[2]});
      }
      for (const Vec3& p : d.vertices) decoded.push_back({p[0], p[1], p[2]});
      std::sort(expected.begin(), expected.end());
      std::sort(decoded.begin(), decoded.end());
      EXPECT_EQ(decoded, expected);
    }
  }
}

TEST(MeshCodec, VertexOutsideBoxIsInvalid) {
  const Mesh m = testing::icosphere(1);
  DracoOptions options;
  options.quantization_bounds = Aabb{Vec3::Constant(-0.5), Vec3::Constant(2)};
  try {
    encode_draco(m, options);
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kInvalidInput);
    EXPECT_EQ(e.field(), "quantization_bounds");
  }
  // A vertex on the box is fine.
  options.quantization_bounds = Aabb{Vec3::Constant(-1), Vec3::Constant(1)};
  EXPECT_NO_THROW(encode_draco(m, options));
}

TEST(MeshCodec, GarbageIsInvalidInput) {
  std::mt19937 rng(7);
  std::vector<std::string> inputs = {"", "DRACO", std::string(100, '\0'), "not a draco file at all"};
  for (int i = 0; i < 20; ++i) {
    std::string s(1 + rng() % 300, '\0');
    for (char& c : s) c = static_cast<char>(rng());
    if (i % 2 == 0) s.replace(0, std::min<std::size_t>(5, s.size()), "DRACO");
    inputs.push_back(s);
  }
  // Truncations and bit flips of a valid frame.
  const std::string valid = encode_draco(testing::icosphere(2), DracoOptions{});
  for (std::size_t n : {std::size_t{5}, std::size_t{10}, std::size_t{20}, valid.size() / 2, valid.size() - 1}) {
    inputs.push_back(valid.substr(0, n));
  }
  for (const std::string& s : inputs) {
    try {
      decode_draco(s);
      // Some bit patterns may decode to a (nonsense) mesh; that is acceptable, a crash is not.
    } catch (const Error& e) {
      EXPECT_EQ(e.kind(), ErrorKind::kInvalidInput) << e.what();
      EXPECT_EQ(e.field(), "frame");
    }
  }
  EXPECT_THROW(decode_draco(""), Error);
  EXPECT_THROW(decode_draco(valid.substr(0, 10)), Error);
}

// Found by fuzz/fuzz_mesh (fuzz/corpus/mesh/crash-draco-bool-attribute): a Draco mesh whose NORMAL (or POSITION)
// attribute has Draco's DT_BOOL type holding bytes other than 0/1. Converting it loaded those bytes as `bool`
// (undefined behaviour) and produced a mesh; it must be rejected.
TEST(MeshCodec, BooleanAttributeIsInvalidInput) {
  const unsigned char kFile[] = {0x44, 0x52, 0x41, 0x43, 0x4f, 0x02, 0x02, 0x01, 0x00, 0x01, 0x04, 0x01,
                                 0x03, 0x03, 0x04, 0x03, 0x05, 0x01, 0x02, 0x00, 0x09, 0x03, 0x00, 0x00,
                                 0x01, 0x0b, 0x03, 0x05, 0x09, 0x03, 0x00, 0x00, 0x01, 0x00, 0x00, 0x01,
                                 0x09, 0x09, 0x09, 0x09, 0x03, 0x00, 0x00, 0x01, 0x09};
  try {
    decode_draco(std::string(reinterpret_cast<const char*>(kFile), sizeof kFile));
    ADD_FAILURE() << "a boolean attribute was decoded";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kInvalidInput);
    EXPECT_EQ(e.field(), "frame");
    EXPECT_NE(std::string(e.what()).find("attribute is not numeric"), std::string::npos) << e.what();
  }
}

// The class fuzz/fuzz_mesh found (fuzz/corpus/mesh/crash-draco-edgebreaker-declares-200m-faces): an edgebreaker
// stream whose header declares 200 M triangles made Draco allocate its corner table (2.4 GB) before reading a symbol.
TEST(MeshCodec, DecompressionBombIsRefusedWithinTheBudget) {
  const std::string bomb = testing::draco_bomb(200'000'000);
  ASSERT_LT(bomb.size(), 400u);
  // Held to the decoder's own budget: 64 MiB plus 4 KiB per input byte.
  AllocationBudget outer(std::size_t{80} << 20);
  EXPECT_TRUE(testing::throws_error([&] { decode_draco(bomb); }, ErrorKind::kInvalidInput, "frame",
                                    "bytes per input byte are allowed"));
  EXPECT_FALSE(outer.exhausted());
  EXPECT_LT(outer.allocated(), std::size_t{66} << 20);
  // Through parse_mesh the file's name comes first.
  EXPECT_TRUE(testing::throws_error([&] { parse_mesh(bomb, MeshFormat::kDraco, "bomb.drc"); }, ErrorKind::kInvalidInput,
                                    "file", "bomb.drc: decoding this"));
}

TEST(MeshCodec, TriangleLimitBoundsTheDecoder) {
  const Mesh sphere = testing::icosphere(6);  // 81920 triangles
  const std::string bytes = encode_draco(sphere, DracoOptions{});
  EXPECT_EQ(decode_draco(bytes).triangles.size(), sphere.triangles.size());
  // With a tight triangle limit the budget is 64 MiB plus 256 bytes per allowed triangle: the limit binds.
  MeshReadLimits limits;
  limits.max_triangles = 1000;
  EXPECT_TRUE(testing::throws_error([&] { decode_draco(testing::draco_bomb(300'000'000), limits); },
                                    ErrorKind::kResourceLimit, "max_triangles", "max_triangles (1000)"));
  EXPECT_TRUE(
      testing::throws_error([&] { parse_mesh(testing::draco_bomb(300'000'000), MeshFormat::kDraco, "b.drc", limits); },
                            ErrorKind::kResourceLimit, "max_triangles", "b.drc: decoding this"));
}

// The most compressible mesh we know, a flat regular grid at speed 0 (about 20 triangles per byte), still decodes.
TEST(MeshCodec, HighlyCompressedMeshDecodesWithinTheBudget) {
  const int n = 1000;
  Mesh grid;
  for (int j = 0; j <= n; ++j)
    for (int i = 0; i <= n; ++i) grid.vertices.emplace_back(double(i) / n, double(j) / n, 0.0);
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      const auto a = static_cast<std::uint32_t>(j * (n + 1) + i), c = a + static_cast<std::uint32_t>(n) + 1;
      grid.triangles.push_back({a, a + 1, c + 1});
      grid.triangles.push_back({a, c + 1, c});
    }
  DracoOptions options;
  options.speed = 0;
  options.quantization_bits = 8;
  const std::string bytes = encode_draco(grid, options);
  EXPECT_GT(static_cast<double>(grid.triangles.size()) / static_cast<double>(bytes.size()), 5.0);
  EXPECT_EQ(decode_draco(bytes).triangles.size(), grid.triangles.size());
}

TEST(MeshCodec, NormalsRoundTripApproximately) {
  const Mesh m = mc_sphere(true);
  ASSERT_EQ(m.normals.size(), m.vertices.size());
  DracoOptions options;
  options.normal_bits = 10;
  const Mesh d = decode_draco(encode_draco(m, options));
  ASSERT_EQ(d.normals.size(), d.vertices.size());
  double worst = 1.0;
  for (std::size_t v = 0; v < d.vertices.size(); ++v) {
    const std::size_t o = *testing::nearest_vertex(m, d.vertices[v]);
    worst = std::min(worst, d.normals[v].dot(m.normals[o]));
  }
  EXPECT_GT(worst, std::cos(1.0 * 3.14159265358979 / 180.0));  // within 1 degree at 10 bits
  options.normals = false;
  EXPECT_TRUE(decode_draco(encode_draco(m, options)).normals.empty());
}

TEST(MeshCodec, EmptyMeshRoundTrips) {
  const std::string bytes = encode_draco(Mesh{}, DracoOptions{});
  EXPECT_FALSE(bytes.empty());
  const Mesh d = decode_draco(bytes);
  EXPECT_TRUE(d.empty());
  EXPECT_TRUE(d.vertices.empty());
  DracoOptions boxed;
  boxed.quantization_bounds = Aabb{Vec3::Zero(), Vec3::Ones()};
  EXPECT_TRUE(decode_draco(encode_draco(Mesh{}, boxed)).empty());
}

TEST(MeshCodec, DegenerateBoundingBox) {
  Mesh m;
  m.vertices = {Vec3(1, 2, 3), Vec3(1, 2, 3), Vec3(1, 2, 3)};
  m.triangles = {{0, 1, 2}};
  const Mesh d = decode_draco(encode_draco(m, DracoOptions{}));
  ASSERT_EQ(d.triangles.size(), 1u);
  for (const Vec3& p : d.vertices) EXPECT_NEAR((p - Vec3(1, 2, 3)).norm(), 0.0, 1e-5);
  // Flat mesh: one axis has zero extent.
  const Mesh square = testing::open_square();
  expect_same_shape(square, decode_draco(encode_draco(square, DracoOptions{})),
                    draco_max_error(Aabb::of(square.vertices), 14));
}

TEST(MeshCodec, InvalidOptions) {
  const Mesh m = testing::unit_cube();
  auto expect_field = [&](DracoOptions o, const std::string& field) {
    EXPECT_TRUE(testing::throws_invalid_input([&] { encode_draco(m, o); }, field));
  };
  DracoOptions o;
  o.quantization_bits = 0;
  expect_field(o, "quantization_bits");
  o.quantization_bits = 31;
  expect_field(o, "quantization_bits");
  o = DracoOptions{};
  o.speed = 11;
  expect_field(o, "speed");
  o = DracoOptions{};
  o.quantization_bounds = Aabb{Vec3::Zero(), Vec3(1, 0, 1)};
  expect_field(o, "quantization_bounds");
  Mesh bad = m;
  bad.triangles.push_back({0, 1, 99});
  EXPECT_THROW(encode_draco(bad, DracoOptions{}), Error);
}

TEST(MeshCodec, MaxErrorFormula) {
  const Aabb box{Vec3::Zero(), Vec3(2, 1, 1)};
  const double step = 2.0 / ((1 << 14) - 1);
  EXPECT_GE(draco_max_error(box, 14), 0.5 * step * std::sqrt(3.0));
  EXPECT_LT(draco_max_error(box, 14), 0.55 * step * std::sqrt(3.0));
}

// Mesh attributes travel as named GENERIC attributes: after Draco's reordering, every decoded vertex carries the
// values of the vertex it came from, bit for bit, under the same name.
TEST(MeshCodec, NamedAttributesSurviveTheReordering) {
  Mesh mesh = testing::icosphere(3, 1.0, Vec3(0, 0, 0));
  const std::size_t n = mesh.vertices.size();
  Attribute density{"density", 1, {}}, velocity{"velocity", 3, {}};
  for (std::size_t v = 0; v < n; ++v) {
    density.values.push_back(1000.0f + static_cast<float>(v) * 0.125f);
    for (int c = 0; c < 3; ++c) velocity.values.push_back(static_cast<float>(mesh.vertices[v][c]) * 3.0f + c);
  }
  mesh.attributes = {density, velocity};
  for (const int speed : {0, 8, 10}) {
    DracoOptions options;
    options.speed = speed;
    const Mesh back = decode_draco(encode_draco(mesh, options));
    ASSERT_EQ(back.vertices.size(), n);
    ASSERT_EQ(back.attributes.size(), 2u);
    EXPECT_EQ(back.attributes[0].name, "density");
    EXPECT_EQ(back.attributes[1].name, "velocity");
    EXPECT_EQ(back.attributes[1].components, 3);
    for (std::size_t v = 0; v < n; ++v) {
      std::size_t from = 0;
      for (std::size_t u = 1; u < n; ++u) {
        if ((mesh.vertices[u] - back.vertices[v]).norm() < (mesh.vertices[from] - back.vertices[v]).norm()) from = u;
      }
      ASSERT_EQ(back.attributes[0].values[v], density.values[from]) << speed << " vertex " << v;
      for (int c = 0; c < 3; ++c) ASSERT_EQ(back.attributes[1].values[3 * v + c], velocity.values[3 * from + c]);
    }
  }
}

}  // namespace
}  // namespace surfacer
