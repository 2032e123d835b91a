#include "core/mesh/frame_codec.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <limits>
#include <map>
#include <random>

#include "core/mesh/mesh_checks.h"
#include "core/mesh/mesh_gltf.h"
#include "core/polygonize/polygonize.h"
#include "core/util/errors.h"
#include "tests/support/mesh_expectations.h"
#include "tests/support/test_meshes.h"

namespace surfacer {
namespace {

using GridPoint = std::array<std::uint32_t, 3>;
using testing::polygonized;
using testing::quantized_triangles;

std::size_t referenced_vertices(const Mesh& m) {
  std::vector<bool> used(m.vertices.size(), false);
  for (const Triangle& t : m.triangles) {
    if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) continue;
    for (std::uint32_t v : t) used[v] = true;
  }
  return static_cast<std::size_t>(std::count(used.begin(), used.end(), true));
}

struct Case {
  std::string name;
  Mesh mesh;
  Aabb box;
};

// Polygonizer output of several shapes and sizes (one to many pieces), meshes with normals, and meshes with holes.
std::vector<Case> cases() {
  std::vector<Case> out;
  const FieldPtr sphere = make_sphere(Vec3(0.1, -0.2, 0.05), 1.0);
  const FieldPtr gyroid = make_csg(CsgOp::kIntersection, {make_gyroid(1.0, 0.12), make_sphere(Vec3::Zero(), 1.5)});
  for (int cells : {12, 40, 72}) {
    for (Polygonizer method : {Polygonizer::kCubes, Polygonizer::kTiles}) {
      const std::string tag = std::string(polygonizer_name(method)) + " " + std::to_string(cells);
      out.push_back(
          {"sphere " + tag, polygonized(sphere, method, cells), Aabb{Vec3::Constant(-1.5), Vec3::Constant(1.5)}});
      out.push_back({"gyroid " + tag, polygonized(gyroid, method, cells), Aabb{Vec3::Constant(-2), Vec3::Constant(2)}});
    }
  }
  out.push_back({"sphere with normals", polygonized(sphere, Polygonizer::kTiles, 48, true),
                 Aabb{Vec3::Constant(-1.5), Vec3::Constant(1.5)}});
  // Holes: scattered triangles removed (a boundary), and with them pairs that share a vertex (bowties: not manifold).
  Mesh holes = testing::icosphere(5);
  std::mt19937 rng(3);
  std::erase_if(holes.triangles, [&](const Triangle&) { return rng() % 50 == 0; });
  out.push_back({"icosphere with holes", holes, Aabb{Vec3::Constant(-1), Vec3::Constant(1)}});
  out.push_back({"empty", Mesh{}, Aabb{Vec3::Zero(), Vec3::Ones()}});
  return out;
}

FrameCodecOptions options_for(FrameCodec codec, const Aabb& box, std::size_t piece_triangles, int bits = 14) {
  FrameCodecOptions o;
  o.codec = codec;
  o.draco.quantization_bounds = box;
  o.draco.quantization_bits = bits;
  o.max_piece_triangles = piece_triangles;
  return o;
}

TEST(QuantizationGrid, IsDracosGrid) {
  // Draco's own decode of a standard frame lands exactly on the grid points our quantize/dequantize give.
  std::mt19937 rng(11);
  for (int bits : {6, 11, 14, 20, 26}) {  // (30 bits works alike but takes Draco seconds on random points)
    for (const Aabb& box : {Aabb{Vec3::Constant(-1), Vec3::Constant(1)}, Aabb{Vec3(100, 200, -3), Vec3(101, 200.5, -2)},
                            Aabb{Vec3(-1e-3, 0, 0), Vec3(0, 2e-3, 1e-3)}}) {
      Mesh m = testing::icosphere(2);
      std::uniform_real_distribution<double> u(0.0, 1.0);
      for (Vec3& p : m.vertices) p = box.min + (box.max - box.min).cwiseProduct(Vec3(u(rng), u(rng), u(rng)));
      m.vertices[0] = box.min;
      m.vertices[1] = box.max;
      DracoOptions o;
      o.quantization_bits = bits;
      o.quantization_bounds = box;
      const QuantizationGrid grid = QuantizationGrid::of(box, bits);
      std::vector<std::array<double, 3>> expected, decoded;
      for (const Vec3& p : m.vertices) {
        const Vec3 q = grid.dequantize(grid.quantize(p));
        expected.push_back({q.x(), q.y(), q.z()});
      }
      for (const Vec3& p : decode_draco(encode_draco(m, o)).vertices) decoded.push_back({p.x(), p.y(), p.z()});
      std::sort(expected.begin(), expected.end());
      std::sort(decoded.begin(), decoded.end());
      EXPECT_EQ(decoded, expected) << bits << " bits";
    }
  }
}

TEST(FrameCodec, PiecesWeldIntoTheSameSurfaceAsOneDracoMesh) {
  for (const Case& c : cases()) {
    const MeshReport original = check_mesh(c.mesh);
    for (FrameCodec codec : {FrameCodec::kDracoPieces, FrameCodec::kMeshopt}) {
      for (std::size_t piece : {std::size_t{1024}, std::size_t{5000}, std::size_t{1} << 20}) {
        SCOPED_TRACE(c.name + ", " + std::string(frame_codec_name(codec)) + ", pieces of " + std::to_string(piece));
        const FrameCodecOptions o = options_for(codec, c.box, piece);
        const QuantizationGrid grid = QuantizationGrid::of(c.box, 14);
        const Mesh decoded = decode_frame(encode_frame(c.mesh, o, 2), codec, 3);
        const Mesh reference = decode_draco(encode_draco(c.mesh, o.draco));
        EXPECT_EQ(quantized_triangles(decoded, grid), quantized_triangles(reference, grid));
        // Welded exactly: the topology of the original mesh (no seam left open, no vertex merged wrongly). Draco
        // splits a non-manifold vertex into one point per fan (as it does in a one-piece frame): exact on manifolds.
        if (codec == FrameCodec::kMeshopt || original.vertex_manifold) {
          const MeshReport r = check_mesh(decoded);
          EXPECT_EQ(decoded.vertices.size(), referenced_vertices(c.mesh));
          EXPECT_EQ(r.boundary_edges, original.boundary_edges);
          EXPECT_EQ(r.euler_characteristic, original.euler_characteristic);
          EXPECT_EQ(r.components, original.components);
          EXPECT_EQ(r.valence_histogram, original.valence_histogram);
          EXPECT_EQ(r.oriented, original.oriented);
        }
        EXPECT_EQ(decoded.normals.size(), c.mesh.normals.empty() ? 0 : decoded.vertices.size());
        for (std::size_t v = 0; v < decoded.normals.size(); ++v) EXPECT_NEAR(decoded.normals[v].norm(), 1.0, 1e-9);
      }
    }
  }
}

// The container's directory (README "Container"): pieces of at most max_piece_triangles, of equal size (within one
// triangle), one piece for a frame that fits in one, else a multiple of 4 pieces (an even share on 2 and 4 cores).
TEST(FrameCodec, PiecesAreEvenAndShareOutOverCores) {
  auto u32_at = [](const std::string& bytes, std::size_t at) {
    std::uint32_t v = 0;
    std::memcpy(&v, bytes.data() + at, 4);
    return v;
  };
  for (const Case& c : cases()) {
    const std::size_t triangles = c.mesh.triangles.size();
    for (std::size_t piece : {std::size_t{1024}, std::size_t{5000}, std::size_t{30000}, std::size_t{1} << 20}) {
      SCOPED_TRACE(c.name + ", pieces of " + std::to_string(piece));
      const std::string bytes = encode_frame(c.mesh, options_for(FrameCodec::kMeshopt, c.box, piece), 2);
      const std::uint32_t count = u32_at(bytes, 24);
      if (triangles <= piece) {
        EXPECT_EQ(count, 1u);
        continue;
      }
      EXPECT_EQ(count % 4, 0u);
      EXPECT_LT(count, (triangles + piece - 1) / piece + 4);  // no more than the rounding needs
      std::size_t smallest = triangles, largest = 0;
      for (std::uint32_t p = 0; p < count; ++p) {
        const std::size_t t = u32_at(bytes, 44 + 44 * p + 8);  // header, then 44 bytes per piece
        smallest = std::min(smallest, t);
        largest = std::max(largest, t);
      }
      EXPECT_LE(largest, piece);
      EXPECT_LE(largest - smallest, 1u);  // the cases have no repeated-index triangles
    }
  }
}

TEST(FrameCodec, BytesDoNotDependOnTheThreads) {
  for (const Case& c : cases()) {
    for (FrameCodec codec : {FrameCodec::kDracoPieces, FrameCodec::kMeshopt}) {
      const FrameCodecOptions o = options_for(codec, c.box, 2048);
      const std::string one = encode_frame(c.mesh, o, 1);
      for (int threads : {2, 5}) {
        EXPECT_EQ(encode_frame(c.mesh, o, threads), one)
            << c.name << ", " << frame_codec_name(codec) << ", " << threads << " threads";
      }
    }
  }
}

// A bad mesh is refused naming the field and its lowest bad vertex or triangle, whatever the threads, also when the
// problems lie in several blocks of the parallel check (blocks of 65536), and in the order: non-finite vertices,
// indices out of range, vertices outside the quantization box.
TEST(FrameCodec, BadMeshNamesItsFirstProblemWhateverTheThreads) {
  const Mesh sphere = testing::icosphere(7);  // 163842 vertices, 327680 triangles: 3 and 5 blocks
  const Aabb box{Vec3::Constant(-1.0), Vec3::Constant(1.0)};
  auto message = [&](const Mesh& m, int threads) {
    try {
      encode_frame(m, options_for(FrameCodec::kMeshopt, box, 1 << 18), threads);
    } catch (const Error& e) {
      return std::string(e.field()) + ": " + e.what();
    }
    return std::string("no error");
  };
  auto expect = [&](const Mesh& m, const std::string& field, const std::string& what) {
    for (int threads : {1, 2, 4}) {
      const std::string text = message(m, threads);
      EXPECT_EQ(text.rfind(field + ": ", 0), 0u) << text;
      EXPECT_NE(text.find(what), std::string::npos) << threads << " threads: " << text;
    }
  };
  Mesh outside = sphere;
  outside.vertices[150000] = Vec3(0.0, 0.0, 3.0);
  outside.vertices[70000] = Vec3(0.0, 2.0, 0.0);
  expect(outside, "quantization_bounds", "vertex 70000 ");
  Mesh bad_index = outside;
  bad_index.triangles[300000][1] = 999999;
  bad_index.triangles[100000][2] = 888888;
  expect(bad_index, "triangles", "triangle 100000 uses vertex 888888");
  Mesh non_finite = bad_index;
  non_finite.vertices[160000].x() = std::numeric_limits<double>::quiet_NaN();
  non_finite.vertices[66000].y() = std::numeric_limits<double>::infinity();
  expect(non_finite, "vertices", "vertex 66000 ");
}

TEST(FrameCodec, StandardDracoOfPiecesIsOnTheJobGrid) {
  for (const Case& c : cases()) {
    for (int bits : {10, 14, 18}) {
      const FrameCodecOptions o = options_for(FrameCodec::kMeshopt, c.box, 2048, bits);
      const std::string bytes = encode_frame(c.mesh, o, 2);
      const Mesh decoded = decode_frame(bytes, o.codec, 2);
      const Mesh standard = decode_draco(to_standard_draco(bytes, o.codec, decoded));
      const Mesh reference = decode_draco(encode_draco(c.mesh, o.draco));
      const QuantizationGrid grid = QuantizationGrid::of(c.box, bits);
      EXPECT_EQ(quantized_triangles(standard, grid), quantized_triangles(reference, grid)) << c.name << " " << bits;
    }
  }
}

// to_gltf's edges (the end-to-end test reads full files): an empty frame is a scene with one empty node (glTF has no
// empty accessors); a grid of more than 16 bits is refused naming quantization_bits, whatever the frame's codec.
TEST(FrameCodec, GltfOfAnEmptyFrameAndOfADeepGrid) {
  const int two = 2;
  for (FrameCodec codec : {FrameCodec::kDracoPieces, FrameCodec::kMeshopt, FrameCodec::kDraco, FrameCodec::kPly}) {
    SCOPED_TRACE(std::string(frame_codec_name(codec)));
    const Mesh empty;
    const FrameCodecOptions o = options_for(codec, Aabb{Vec3::Zero(), Vec3::Ones()}, 1024);
    const std::string bytes = encode_frame(empty, o, two);
    const std::string glb = to_gltf(
        bytes, codec, [&]() -> const Mesh& { return empty; }, two);
    ASSERT_GE(glb.size(), 20u);
    EXPECT_EQ(glb.substr(0, 4), "glTF");
    EXPECT_EQ(glb.find("\"meshes\""), std::string::npos);
    EXPECT_NE(glb.find("\"nodes\":[{"), std::string::npos);
    if (codec == FrameCodec::kDraco || codec == FrameCodec::kPly) continue;  // encoded again on their own 14 bits
    const Mesh sphere = testing::icosphere(3);
    const FrameCodecOptions deep = options_for(codec, Aabb{Vec3::Constant(-1), Vec3::Constant(1)}, 1024, 18);
    const std::string deep_bytes = encode_frame(sphere, deep, two);
    const Mesh decoded = decode_frame(deep_bytes, codec, two);
    try {
      to_gltf(
          deep_bytes, codec, [&]() -> const Mesh& { return decoded; }, two);
      ADD_FAILURE() << "an 18-bit grid was written to glTF";
    } catch (const Error& e) {
      EXPECT_EQ(e.field(), "quantization_bits");
      EXPECT_NE(std::string(e.what()).find("16"), std::string::npos) << e.what();
    }
  }
}

// The same frame in the version 1 container an earlier server wrote (and a job store may still hold): per piece
// only bytes, vertices and triangles.
std::string as_version_1(const std::string& v2) {
  constexpr std::size_t kHeader = 44, kEntry = 44, kOldEntry = 12;
  std::uint32_t count = 0;
  std::memcpy(&count, v2.data() + 24, 4);
  std::string v1 = v2.substr(0, kHeader);
  v1[4] = 1;
  for (std::uint32_t p = 0; p < count; ++p) v1 += v2.substr(kHeader + kEntry * p, kOldEntry);
  return v1 + v2.substr(kHeader + kEntry * count);
}

// A meshopt frame's .glb holds its streams as received (EXT_meshopt_compression): written without decoding anything,
// it reads back as the frame's mesh, vertex for vertex, normals included (through the extension's OCTAHEDRAL filter).
// A version 1 meshopt frame (no bounds in its directory) becomes Draco pieces of its decoded mesh, which read back
// as the same triangles.
TEST(FrameCodec, MeshoptGltfHoldsTheFramesStreams) {
  const int two = 2;
  for (const Case& c : cases()) {
    // 3-bit normals are below the OCTAHEDRAL filter's least 4 bits: rounded onto them.
    for (const auto& [piece, normal_bits] :
         {std::pair{std::size_t{1024}, 10}, std::pair{std::size_t{1} << 20, 10}, std::pair{std::size_t{1024}, 3}}) {
      if (normal_bits != 10 && c.mesh.normals.empty()) continue;
      SCOPED_TRACE(c.name + ", pieces of " + std::to_string(piece) + ", normals of " + std::to_string(normal_bits) +
                   " bits");
      FrameCodecOptions o = options_for(FrameCodec::kMeshopt, c.box, piece, 12);
      o.draco.normals = !c.mesh.normals.empty();
      o.draco.normal_bits = normal_bits;
      const std::string bytes = encode_frame(c.mesh, o, two);
      const Mesh frame = decode_frame(bytes, o.codec, two);
      const std::string glb = to_gltf(
          bytes, o.codec,
          [&]() -> const Mesh& {
            ADD_FAILURE() << "a version 2 meshopt frame was decoded to write its .glb";
            return frame;
          },
          two);
      const bool has_mesh = !frame.triangles.empty();
      EXPECT_EQ(glb.find("EXT_meshopt_compression") != std::string::npos, has_mesh);
      EXPECT_EQ(glb.find("KHR_draco_mesh_compression"), std::string::npos);
      const std::string old_glb = to_gltf(
          as_version_1(bytes), o.codec, [&]() -> const Mesh& { return frame; }, two);
      EXPECT_EQ(old_glb.find("KHR_draco_mesh_compression") != std::string::npos, has_mesh);
      const QuantizationGrid grid = QuantizationGrid::of(c.box, 12);
      for (const std::string* file : {&glb, &old_glb}) {
        SCOPED_TRACE(file == &glb ? "meshopt .glb" : "Draco .glb of a version 1 frame");
        const Mesh read = parse_glb(*file, "frame.glb");
        // Draco writes a vertex whose triangles form several fans (the bowties) as one point per fan.
        if (file == &glb) {
          EXPECT_EQ(read.vertices.size(), frame.vertices.size());
        } else {
          EXPECT_GE(read.vertices.size(), frame.vertices.size());
        }
        EXPECT_EQ(quantized_triangles(read, grid), quantized_triangles(frame, grid));
        ASSERT_EQ(read.normals.size(), frame.normals.size());
        if (frame.normals.empty()) continue;
        // Each vertex's normal, found by its grid point where only one vertex lies there.
        std::map<GridPoint, std::vector<Vec3>> at;
        for (std::size_t v = 0; v < frame.vertices.size(); ++v)
          at[grid.quantize(frame.vertices[v])].push_back(frame.normals[v]);
        double worst = 0.0;
        for (std::size_t v = 0; v < read.vertices.size(); ++v) {
          const auto& n = at[grid.quantize(read.vertices[v])];
          if (n.size() == 1) worst = std::max(worst, (read.normals[v] - n[0]).norm());
        }
        // The meshopt .glb holds the frame's own octahedral values (decoded in float32 rather than double), but 3-bit
        // ones move by up to 1/14 per coordinate onto 4 bits; Draco encodes the decoded normals again on 10 bits.
        EXPECT_LT(worst, file != &glb ? 5e-3 : normal_bits == 3 ? 0.25 : 1e-4);
      }
    }
  }
}

// The directory says what decoding the pieces finds (points, bounds, attribute ids), so to_gltf writes from it alone
// the same file it writes for a version 1 frame by decoding every piece; and version 1 frames still decode.
TEST(FrameCodec, GltfFromTheDirectoryIsTheFileDecodingGives) {
  const int two = 2;
  std::vector<Case> all = cases();
  for (const Case& c : all) {
    for (std::size_t piece : {std::size_t{1024}, std::size_t{1} << 20}) {
      SCOPED_TRACE(c.name + ", pieces of " + std::to_string(piece));
      for (int bits : {10, 16}) {
        FrameCodecOptions o = options_for(FrameCodec::kDracoPieces, c.box, piece, bits);
        o.draco.normals = !c.mesh.normals.empty();
        const std::string bytes = encode_frame(c.mesh, o, two);
        ASSERT_EQ(bytes[4], 2);
        const std::string old = as_version_1(bytes);
        EXPECT_EQ(to_gltf(bytes, o.codec, {}, two), to_gltf(old, o.codec, {}, two)) << bits << " bits";
        const Mesh decoded = decode_frame(bytes, o.codec, two);
        const Mesh decoded_old = decode_frame(old, o.codec, two);
        EXPECT_EQ(decoded.vertices, decoded_old.vertices);
        EXPECT_EQ(decoded.triangles, decoded_old.triangles);
      }
    }
  }
}

// A mesh's attributes as a frame carries them: an id per vertex (its index, exact in float32) to find the original
// vertex after a codec reorders, splits or welds them, a constant, a velocity linear in the position, and names that
// glTF cannot take as they are (a dot; "seam", whose semantic _SEAM our pieces use already), with 1 to 4 components.
Mesh with_attributes(Mesh mesh) {
  const std::size_t n = mesh.vertices.size();
  Attribute id{"id", 1, {}}, density{"density", 1, {}}, velocity{"velocity", 3, {}}, foam{"foam.mask", 2, {}},
      seam{"seam", 4, {}};
  for (std::size_t v = 0; v < n; ++v) {
    const Vec3& p = mesh.vertices[v];
    id.values.push_back(static_cast<float>(v));
    density.values.push_back(998.25f);
    for (const double x : {0.5 * p.x() - p.y() + 2.0 * p.z(), 2.0 * p.x(), -0.5}) {
      velocity.values.push_back(static_cast<float>(x));
    }
    foam.values.insert(foam.values.end(), {static_cast<float>(p.z()), 1.0f / 3.0f});
    seam.values.insert(seam.values.end(),
                       {1e-30f, -0.0f, std::numeric_limits<float>::max(), static_cast<float>(v % 7)});
  }
  mesh.attributes = {id, density, velocity, foam, seam};
  return mesh;
}

// `read` holds `original`'s attributes, by name, in order, with their components, and each vertex the values of the
// original vertex its id names, bit for bit, at a point within `error` of that vertex.
void expect_attributes_of(const Mesh& read, const Mesh& original, double error) {
  ASSERT_EQ(read.attributes.size(), original.attributes.size());
  for (std::size_t a = 0; a < original.attributes.size(); ++a) {
    EXPECT_EQ(read.attributes[a].name, original.attributes[a].name);
    ASSERT_EQ(read.attributes[a].components, original.attributes[a].components) << original.attributes[a].name;
    ASSERT_EQ(read.attributes[a].count(), read.vertices.size()) << original.attributes[a].name;
  }
  if (read.attributes.empty()) return;
  const std::vector<float>& ids = read.attributes[0].values;
  for (std::size_t v = 0; v < read.vertices.size(); ++v) {
    const auto id = static_cast<std::size_t>(ids[v]);
    ASSERT_LT(id, original.vertices.size());
    ASSERT_LE((read.vertices[v] - original.vertices[id]).norm(), error) << "vertex " << v << " (id " << id << ")";
    for (std::size_t a = 1; a < original.attributes.size(); ++a) {
      const auto k = static_cast<std::size_t>(original.attributes[a].components);
      for (std::size_t c = 0; c < k; ++c) {
        const float got = read.attributes[a].values[v * k + c], want = original.attributes[a].values[id * k + c];
        ASSERT_EQ(std::memcmp(&got, &want, sizeof got), 0)
            << original.attributes[a].name << "[" << c << "] of vertex " << v << ": " << got << " for " << want;
      }
    }
  }
}

// Every codec carries Mesh::attributes (Draco and meshopt pieces as unquantized float32 streams, named once per frame)
// and gives them back bit for bit on the decoded vertices; so do the .glb files of every codec (_NAME application
// attributes in KHR_draco_mesh_compression and EXT_meshopt_compression primitives, and in plain glTF), read back by
// parse_glb with their names. Frames without attributes stay version 2.
TEST(FrameCodec, AttributesComeBackFromEveryCodecAndGltf) {
  const int two = 2;
  std::vector<Case> all = cases();
  for (const std::size_t pick : {std::size_t{4}, std::size_t{12}, std::size_t{13}, std::size_t{14}}) {
    const Case& c = all.at(pick);  // a sphere of several pieces, normals, holes with bowties, empty
    const Mesh mesh = with_attributes(c.mesh);
    for (FrameCodec codec : {FrameCodec::kDraco, FrameCodec::kDracoPieces, FrameCodec::kMeshopt, FrameCodec::kPly}) {
      for (const std::size_t piece : {std::size_t{1024}, std::size_t{1} << 20}) {
        SCOPED_TRACE(c.name + ", " + std::string(frame_codec_name(codec)) + ", pieces of " + std::to_string(piece));
        FrameCodecOptions o = options_for(codec, c.box, piece, 16);
        o.draco.normals = !c.mesh.normals.empty();
        const std::string bytes = encode_frame(mesh, o, two);
        if (codec == FrameCodec::kDracoPieces || codec == FrameCodec::kMeshopt) {
          EXPECT_EQ(bytes[4], 3);
          EXPECT_EQ(encode_frame(c.mesh, o, two)[4], 2);
        }
        const Mesh frame = decode_frame(bytes, codec, two);
        if (mesh.triangles.empty()) {  // nothing to carry (a one-mesh Draco frame keeps no names either)
          EXPECT_TRUE(frame.vertices.empty());
          EXPECT_TRUE(parse_glb(to_gltf(
                                    bytes, codec, [&]() -> const Mesh& { return frame; }, two),
                                "frame.glb")
                          .attributes.empty());
          continue;
        }
        const double error = codec == FrameCodec::kPly ? 0.0 : draco_max_error(c.box, 16);
        expect_attributes_of(frame, mesh, error);
        EXPECT_EQ(frame.triangles.size(), decode_frame(encode_frame(c.mesh, o, two), codec, two).triangles.size());
        EXPECT_EQ(decode_draco(to_standard_draco(bytes, codec, frame)).attributes.size(), mesh.attributes.size());
        const std::string glb = to_gltf(
            bytes, codec, [&]() -> const Mesh& { return frame; }, two);
        EXPECT_NE(glb.find("\"_FOAM_MASK\""), std::string::npos);
        EXPECT_NE(glb.find("\"_SEAM_2\":"), std::string::npos);
        for (const auto& [file, name] : {std::pair{glb, "frame.glb"}, std::pair{write_glb(frame), "plain.glb"},
                                         std::pair{write_gltf(frame), "plain.gltf"}}) {
          SCOPED_TRACE(name);
          const Mesh read = parse_glb(file, name);
          // The .glb of a pieced frame is on its grid; of a one-mesh frame, on the mesh's own box with 14 bits.
          expect_attributes_of(read, mesh, error + draco_max_error(c.box, 14) + 1e-6);
        }
      }
    }
  }
}

TEST(FrameCodec, GltfAttributeSemanticsAreUpperCaseUnderscoredAndDistinct) {
  std::vector<Attribute> attributes;
  for (const char* name : {"velocity", "foam mask", "seam", "Velocity", "v\xc3\xa9lo", "_x", "TEXCOORD_0"}) {
    attributes.push_back(Attribute{name, 1, {}});
  }
  EXPECT_EQ(
      gltf_attribute_semantics(attributes),
      (std::vector<std::string>{"_VELOCITY", "_FOAM_MASK", "_SEAM_2", "_VELOCITY_2", "_V__LO", "__X", "_TEXCOORD_0"}));
}

// A version 3 frame whose attribute names are cut short, or that names more attributes than its pieces hold, is
// refused.
TEST(FrameCodec, AttributeTableThatDisagreesWithThePiecesIsInvalidInput) {
  const Case c = cases()[2];
  const Mesh mesh = with_attributes(c.mesh);
  for (FrameCodec codec : {FrameCodec::kDracoPieces, FrameCodec::kMeshopt}) {
    const std::string bytes = encode_frame(mesh, options_for(codec, c.box, 1024), 2);
    std::uint32_t count = 0;
    std::memcpy(&count, bytes.data() + 24, 4);
    const std::size_t table = 44 + 44 * std::size_t{count};
    ASSERT_EQ(static_cast<std::uint8_t>(bytes[table]), mesh.attributes.size());
    std::string fewer = bytes;
    fewer[table] = static_cast<char>(mesh.attributes.size() - 1);
    std::string more = bytes;
    more[table] = static_cast<char>(mesh.attributes.size() + 1);
    std::string components = bytes;
    components[table + 1] = 2;  // "id" is a scalar
    for (const std::string* damaged : {&fewer, &more, &components}) {
      try {
        decode_frame(*damaged, codec, 2);
        ADD_FAILURE() << frame_codec_name(codec) << ": a damaged attribute table decoded";
      } catch (const Error& e) {
        EXPECT_EQ(e.kind(), ErrorKind::kInvalidInput);
        EXPECT_EQ(e.field(), "frame");
      }
    }
  }
}

// A directory that does not say what the pieces hold is refused when they are decoded.
TEST(FrameCodec, DirectoryThatDisagreesWithItsPiecesIsInvalidInput) {
  const Case c = cases()[2];  // sphere, cubes, 40 cells: several pieces of 1024
  for (FrameCodec codec : {FrameCodec::kDracoPieces, FrameCodec::kMeshopt}) {
    const std::string bytes = encode_frame(c.mesh, options_for(codec, c.box, 1024), 2);
    ASSERT_NO_THROW(decode_frame(bytes, codec, 2));
    // Piece 1's points (entry offset 12) and its max x (offset 28), each one higher or lower.
    for (std::size_t field : {std::size_t{12}, std::size_t{28}}) {
      for (int delta : {-1, 1}) {
        std::string damaged = bytes;
        std::uint32_t value = 0;
        const std::size_t at = 44 + 44 + field;
        std::memcpy(&value, damaged.data() + at, 4);
        value += static_cast<std::uint32_t>(delta);
        std::memcpy(damaged.data() + at, &value, 4);
        try {
          decode_frame(damaged, codec, 2);
          ADD_FAILURE() << frame_codec_name(codec) << ": field at " << field << " off by " << delta << " decoded";
        } catch (const Error& e) {
          EXPECT_EQ(e.kind(), ErrorKind::kInvalidInput);
          EXPECT_EQ(e.field(), "frame");
        }
      }
    }
  }
}

TEST(FrameCodec, CorruptedPiecedFramesAreInvalidInput) {
  const Case c = cases()[2];  // sphere, cubes, 40 cells: several pieces of 1024
  std::mt19937 rng(5);
  for (FrameCodec codec : {FrameCodec::kDracoPieces, FrameCodec::kMeshopt}) {
    const std::string bytes = encode_frame(c.mesh, options_for(codec, c.box, 1024), 2);
    auto expect_rejected_or_decoded = [&](const std::string& damaged) {
      try {
        decode_frame(damaged, codec, 2);  // a flip inside a coordinate may still decode
      } catch (const Error& e) {
        EXPECT_EQ(e.kind(), ErrorKind::kInvalidInput);
        EXPECT_EQ(e.field(), "frame");
      }
    };
    for (std::size_t size : {std::size_t{0}, std::size_t{3}, std::size_t{40}, bytes.size() / 2, bytes.size() - 1}) {
      EXPECT_THROW(decode_frame(bytes.substr(0, size), codec, 1), Error) << size;
    }
    for (int i = 0; i < 200; ++i) {
      std::string damaged = bytes;
      damaged[rng() % damaged.size()] ^= static_cast<char>(1u << (rng() % 8));
      expect_rejected_or_decoded(damaged);
    }
    EXPECT_THROW(
        decode_frame(bytes, codec == FrameCodec::kMeshopt ? FrameCodec::kDracoPieces : FrameCodec::kMeshopt, 1), Error);
  }
}

TEST(FrameCodec, CancelStopsBetweenPieces) {
  const Case c = cases()[8];  // sphere, cubes, 72 cells
  CancelToken token;
  token.cancel();
  RunControl control;
  control.cancel = &token;
  EXPECT_THROW(encode_frame(c.mesh, options_for(FrameCodec::kDracoPieces, c.box, 1024), 2, control), Error);
}

}  // namespace
}  // namespace surfacer
