#include "core/mesh/mesh_gltf.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

#include "core/mesh/frame_codec.h"
#include "core/mesh/mesh_io.h"
#include "core/polygonize/polygonize.h"
#include "core/util/errors.h"
#include "tests/support/files.h"
#include "tests/support/mesh_expectations.h"
#include "tests/support/test_meshes.h"

namespace surfacer {
namespace {

using testing::kClosedManifold;
using testing::kPositiveVolume;
using testing::mesh_has;
using testing::plain_glb;
using testing::polygonized;
using testing::quantized_triangles;

// The .glb the CLI writes for a frame (to_gltf) reads back as the frame's mesh: the same triangles on the job's
// grid, and as many vertices (the pieces' copies of a seam vertex weld into one, distinct vertices on one grid point
// stay apart), whatever the codec, the pieces and the grid.
TEST(MeshGltf, TheCliGlbOfAFrameReadsBackAsItsMesh) {
  const int two = 2;
  const FieldPtr gyroid = make_csg(CsgOp::kIntersection, {make_gyroid(1.0, 0.12), make_sphere(Vec3::Zero(), 1.5)});
  const FieldPtr sphere = make_sphere(Vec3(0.1, -0.2, 0.05), 1.0);
  const Aabb box{Vec3::Constant(-2), Vec3::Constant(2)};
  struct Case {
    const char* name;
    Mesh mesh;
  };
  const Case cases[] = {
      {"gyroid cubes 48", polygonized(gyroid, Polygonizer::kCubes, 48, false)},
      {"gyroid tiles 40", polygonized(gyroid, Polygonizer::kTiles, 40, false)},
      {"sphere tiles 32 with normals", polygonized(sphere, Polygonizer::kTiles, 32, true)},
  };
  for (const Case& c : cases) {
    for (FrameCodec codec : {FrameCodec::kDracoPieces, FrameCodec::kMeshopt, FrameCodec::kDraco}) {
      for (int bits : {8, 14}) {
        SCOPED_TRACE(std::string(c.name) + ", " + std::string(frame_codec_name(codec)) + ", " + std::to_string(bits) +
                     " bits");
        FrameCodecOptions o;
        o.codec = codec;
        o.draco.quantization_bits = bits;
        o.draco.quantization_bounds = box;
        o.draco.normals = !c.mesh.normals.empty();
        o.max_piece_triangles = 2048;
        const std::string bytes = encode_frame(c.mesh, o, two);
        const Mesh frame = decode_frame(bytes, codec, two);
        const Mesh read = parse_glb(to_gltf(
                                        bytes, codec, [&]() -> const Mesh& { return frame; }, two),
                                    "frame.glb");
        // A one-mesh Draco frame goes into glTF on the mesh's own box at the default bits: compare on that grid.
        const QuantizationGrid grid = codec == FrameCodec::kDraco ? quantization_grid(frame, DracoOptions{}, two)
                                                                  : QuantizationGrid::of(box, bits);
        EXPECT_EQ(read.vertices.size(), frame.vertices.size());
        EXPECT_EQ(quantized_triangles(read, grid), quantized_triangles(frame, grid));
        testing::expect_same_topology(check_mesh(read), check_mesh(frame), "the .glb read back and the frame");
        if (c.mesh.normals.empty()) {
          EXPECT_TRUE(read.normals.empty());
          continue;
        }
        // The sphere's normals come back unit and outward (within Draco's normal quantization).
        ASSERT_EQ(read.normals.size(), read.vertices.size());
        double worst = 1.0;
        for (std::size_t v = 0; v < read.vertices.size(); ++v) {
          EXPECT_NEAR(read.normals[v].norm(), 1.0, 1e-6);
          worst = std::min(worst, read.normals[v].dot((read.vertices[v] - Vec3(0.1, -0.2, 0.05)).normalized()));
        }
        EXPECT_GT(worst, 0.95);
      }
    }
  }
}

// write_mesh and read_mesh round-trip a .glb file on disk (as the CLI's --start-mesh reads it).
TEST(MeshGltf, WriteMeshAndReadMeshRoundTrip) {
  const std::filesystem::path dir = testing::fresh_temp_dir("mesh_gltf");
  for (const Mesh& mesh : {testing::icosphere(4), testing::torus_mesh(1.0, 0.3, 48, 24)}) {
    const std::filesystem::path file = dir / "mesh.glb";
    write_mesh(file, mesh);
    const Mesh read = read_mesh(file);
    EXPECT_EQ(read.vertices.size(), mesh.vertices.size());
    EXPECT_EQ(read.triangles.size(), mesh.triangles.size());
    const MeshReport a = check_mesh(read), b = check_mesh(mesh);
    EXPECT_TRUE(mesh_has(a, kClosedManifold | kPositiveVolume));
    EXPECT_EQ(a.euler_characteristic, b.euler_characteristic);
    EXPECT_NEAR(a.volume, b.volume, 1e-3 * b.volume);
  }
}

// A plain .gltf (JSON with its buffer as a data URI) and a plain .glb (write_glb: the buffer in the BIN chunk) read
// back as the mesh: the same triangles, the vertices rounded to float, unit normals along the mesh's own; an empty mesh
// is an empty scene.
TEST(MeshGltf, PlainGltfRoundTripsThroughWriteMeshAndReadMesh) {
  const std::filesystem::path dir = testing::fresh_temp_dir("mesh_gltf_plain");
  const FieldPtr sphere = make_sphere(Vec3(0.3, -0.2, 0.1), 1.0);
  const Mesh with_normals = polygonized(sphere, Polygonizer::kTiles, 24, true);
  ASSERT_FALSE(with_normals.normals.empty());
  for (const Mesh& mesh : {testing::icosphere(3), testing::torus_mesh(1.0, 0.3, 48, 24), with_normals, Mesh{}}) {
    for (const bool binary : {false, true}) {
      const std::filesystem::path file = dir / (binary ? "mesh.glb" : "mesh.gltf");
      if (binary) {
        const std::string bytes = write_glb(mesh);
        ASSERT_EQ(bytes.find("extensionsUsed"), std::string::npos);
        std::ofstream(file, std::ios::binary) << bytes;
      } else {
        write_mesh(file, mesh);
      }
      const Mesh read = read_mesh(file);
      // The reader numbers vertices in the order the triangles use them: compare corner by corner.
      ASSERT_EQ(read.vertices.size(), mesh.triangles.empty() ? 0 : mesh.vertices.size());
      ASSERT_EQ(read.triangles.size(), mesh.triangles.size());
      ASSERT_EQ(read.normals.empty(), mesh.normals.empty() || mesh.triangles.empty());
      for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
        for (int k = 0; k < 3; ++k) {
          const std::uint32_t a = read.triangles[t][k], b = mesh.triangles[t][k];
          ASSERT_EQ(read.vertices[a], mesh.vertices[b].cast<float>().cast<double>()) << t;
          if (read.normals.empty()) continue;
          EXPECT_NEAR(read.normals[a].norm(), 1.0, 1e-6);
          EXPECT_GT(read.normals[a].dot(mesh.normals[b].normalized()), 1.0 - 1e-6);
        }
      }
      if (!mesh.triangles.empty())
        testing::expect_same_topology(check_mesh(read), check_mesh(mesh), binary ? "the .glb" : "the .gltf");
    }
  }
  // What a .gltf reader must not take: a buffer in another file, a data URI that is not base64.
  const std::string good = write_gltf(testing::unit_cube());
  ASSERT_NO_THROW(parse_glb(good, "good.gltf"));
  auto refused = [&](const std::string& from, const std::string& to, const std::string& words) {
    std::string bad = good;
    bad.replace(bad.find(from), from.size(), to);
    try {
      parse_glb(bad, "bad.gltf");
      ADD_FAILURE() << "read: " << words;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
      EXPECT_EQ(std::string(e.what()).rfind("bad.gltf: ", 0), 0u) << e.what();
    }
  };
  refused("data:application/octet-stream;base64,", "cube.bin#", "buffer 0 is not a base64 data URI");
  refused("base64,", "base64,*", "buffer 0's data URI is not valid base64");
  refused("\"byteLength\": 96", "\"byteLength\": 960", "(bufferView 0) runs past the binary chunk");
}

// Application attributes named by our extras read back under their names; without the extras (another writer's
// file) a _NAME reads as NAME; two semantics the extras give one name stay distinct (the second keeps its semantic).
TEST(MeshGltf, ApplicationAttributesKeepDistinctNames) {
  Mesh cube = testing::unit_cube();
  for (const char* name : {"a", "b"}) {
    cube.attributes.push_back(
        Attribute{name, 1, std::vector<float>(cube.vertices.size(), name[0] == 'a' ? 1.5f : 2.5f)});
  }
  const std::string good = write_gltf(cube);
  auto names = [](const Mesh& mesh) {
    std::vector<std::string> out;
    for (const Attribute& a : mesh.attributes) out.push_back(a.name);
    return out;
  };
  EXPECT_EQ(names(parse_glb(good, "good.gltf")), (std::vector<std::string>{"a", "b"}));
  auto edited = [&](const std::string& from, const std::string& to) {
    std::string text = good;
    const std::size_t at = text.find(from);
    EXPECT_NE(at, std::string::npos) << from;
    if (at != std::string::npos) text.replace(at, from.size(), to);
    return parse_glb(text, "edited.gltf");
  };
  EXPECT_EQ(names(edited("\"extras\"", "\"other\"")), (std::vector<std::string>{"A", "B"}));
  const Mesh clash = edited("\"_B\":\"b\"", "\"_B\":\"a\"");
  ASSERT_EQ(names(clash), (std::vector<std::string>{"a", "_B"}));
  EXPECT_EQ(clash.attributes[1].values, std::vector<float>(clash.vertices.size(), 2.5f));
}

// Another exporter's file: plain accessors (strided float positions, indices of every unsigned type), triangles or
// fans, and nodes whose transforms (translation, rotation, scale, matrix, nesting, a mirror) place the instances.
TEST(MeshGltf, PlainAccessorsModesAndNodeTransforms) {
  const Mesh cube = testing::unit_cube();
  const double kHalf = std::sqrt(0.5);
  // Node 0: the cube moved by (10, 0, 0); node 1: rotated 90 degrees about z, its child node 2 scaled by 2 and
  // mirrored in x; node 3: a matrix moving the cube by (0, 0, -5).
  const std::string nodes = R"([{"mesh":0,"translation":[10,0,0]},{"rotation":[0,0,)" + std::to_string(kHalf) + "," +
                            std::to_string(kHalf) + R"(],"children":[2]},{"mesh":0,"scale":[-2,2,2]},)" +
                            R"({"mesh":0,"matrix":[1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,-5,1]}])";
  for (int index_type : {5121, 5123, 5125}) {
    for (int mode : {4, 6}) {
      SCOPED_TRACE("indices " + std::to_string(index_type) + ", mode " + std::to_string(mode));
      const Mesh read = parse_glb(plain_glb(cube, nodes, "[0,1,3]", index_type, mode), "plain.glb");
      ASSERT_EQ(read.triangles.size(), 3 * cube.triangles.size());
      ASSERT_EQ(read.vertices.size(), 3 * cube.vertices.size());  // three cubes apart: nothing welds
      const MeshReport r = check_mesh(read);
      EXPECT_TRUE(mesh_has(r, kClosedManifold | kPositiveVolume)) << "a mirrored instance must stay outward";
      EXPECT_EQ(r.components, 3);
      EXPECT_NEAR(r.volume, 1.0 + 8.0 + 1.0, 1e-6);
      Aabb box = Aabb::empty();
      for (const Vec3& p : read.vertices) box.merge(p);
      // Cube 1 is [0,1]^3 mirrored to [-2,0] x [0,2] x [0,2], then rotated: x' = -y, y' = x -> [-2,0] x [-2,0].
      EXPECT_TRUE(box.min.isApprox(Vec3(-2, -2, -5), 1e-6)) << box.min.transpose();
      EXPECT_TRUE(box.max.isApprox(Vec3(11, 1, 2), 1e-6)) << box.max.transpose();
    }
  }
  // Without scenes every root node is read; a copy of a vertex (a split at a texture seam) welds.
  Mesh split = cube;
  split.vertices.push_back(split.vertices[split.triangles[0][0]]);
  split.triangles[0][0] = static_cast<std::uint32_t>(split.vertices.size() - 1);
  std::string file = plain_glb(split, R"([{"mesh":0}])", "[0]");
  const Mesh welded = parse_glb(file, "split.glb");
  EXPECT_EQ(welded.vertices.size(), cube.vertices.size());
  EXPECT_TRUE(mesh_has(check_mesh(welded), kClosedManifold));
}

// Normals go through each node's inverse transpose: a unit sphere with radial normals, scaled by (2, 1, -0.5) (a
// mirror) and moved, is an ellipsoid whose normal at p is along (x / 4, y, z / 0.25) from its centre, outward.
TEST(MeshGltf, NormalsGoThroughTheInverseTranspose) {
  Mesh sphere = testing::icosphere(3);
  for (const Vec3& p : sphere.vertices) sphere.normals.push_back(p.normalized());
  const Vec3 centre(1, 2, 3);
  for (int mode : {4, 6}) {
    const Mesh read = parse_glb(
        plain_glb(sphere, R"([{"mesh":0,"translation":[1,2,3],"scale":[2,1,-0.5]}])", "[0]", 5125, mode), "e.glb");
    ASSERT_EQ(read.normals.size(), read.vertices.size());
    for (std::size_t v = 0; v < read.vertices.size(); ++v) {
      const Vec3 p = read.vertices[v] - centre;
      const Vec3 expected = Vec3(p.x() / 4, p.y(), p.z() / 0.25).normalized();
      EXPECT_GT(read.normals[v].dot(expected), 1.0 - 1e-6) << v;
    }
    EXPECT_TRUE(mesh_has(check_mesh(read), kClosedManifold | kPositiveVolume));
  }
}

void expect_refused(const std::string& bytes, const std::string& words, const MeshReadLimits& limits = {}) {
  try {
    parse_glb(bytes, "bad.glb", limits);
    ADD_FAILURE() << "read: " << words;
  } catch (const Error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("bad.glb"), std::string::npos) << what;
    EXPECT_NE(what.find(words), std::string::npos) << what;
  }
}

// `glb` with the first `from` in its JSON replaced by `to`.
std::string json_replaced(const std::string& glb, const std::string& from, const std::string& to) {
  const std::size_t json_size = (glb[12] & 0xff) + ((glb[13] & 0xff) << 8) + ((glb[14] & 0xff) << 16);
  std::string json = glb.substr(20, json_size);
  const std::size_t at = json.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  if (at != std::string::npos) json.replace(at, from.size(), to);
  return pack_glb(json, glb.size() > 20 + json_size ? glb.substr(20 + json_size + 8) : std::string());
}

TEST(MeshGltf, RefusesWhatItDoesNotReadNamingWhy) {
  const Mesh cube = testing::unit_cube();
  const std::string good = plain_glb(cube, R"([{"mesh":0}])", "[0]");
  ASSERT_NO_THROW(parse_glb(good, "good.glb"));
  auto replaced = [&](const std::string& from, const std::string& to) { return json_replaced(good, from, to); };
  expect_refused("solid cube\n", "neither glTF JSON nor a glTF binary header");
  expect_refused(good.substr(0, good.size() / 2), "more bytes than the file has");
  std::string v1 = good;
  v1[4] = 1;
  expect_refused(v1, "version 1");
  expect_refused(replaced(R"("asset":)", R"("asset" )"), "not JSON: expected ':'");
  expect_refused(replaced(R"("version":"2.0")", R"("version":"1.0")"), "asset.version is not 2.x");
  expect_refused(replaced(R"({"mesh":0})", R"({"mesh":0,"children":[0]})"), "reached twice");
  expect_refused(replaced(R"("indices":1)", R"("indices":1,"mode":1)"), "mode 1");
  expect_refused(replaced(R"("buffer":0,"byteOffset")", R"("buffer":1,"byteOffset")"), "missing entry of buffers");
  expect_refused(replaced(R"("buffers":[{)", R"("buffers":[{"uri":"cube.bin",)"), "outside the file");
  expect_refused(replaced(R"("componentType":5126,)", R"("sparse":{},"componentType":5126,)"), "sparse");
  expect_refused(replaced(R"("type":"VEC3","count":8)", R"("type":"VEC3","count":9)"), "runs past its bufferView");
  expect_refused(replaced(R"("asset")", R"("extensionsRequired":["KHR_texture_transform"],"asset")"),
                 "KHR_texture_transform");
  expect_refused(replaced(R"({"mesh":0})", R"({"mesh":0,"matrix":[1,0,0,1]})"), "matrix is not 16 numbers");
  expect_refused(replaced(R"({"mesh":0})", R"({"mesh":0,"scale":[1e308,1e308,1e308],"children":[1]},{"mesh":0,)"
                                           R"("scale":[1e308,1,1]})"),
                 "not finite");
  // An index past the vertices: the cube's first index (0) made 200.
  std::string far = good;
  const std::size_t bin = 20 + (good[12] & 0xff) + ((good[13] & 0xff) << 8) + 8;
  far[bin + 16 * cube.vertices.size() + 4 * 0] = static_cast<char>(200);
  expect_refused(far, "uses vertex 200");
  // Many instances of one mesh past the triangles a caller accepts.
  MeshReadLimits limits;
  limits.max_triangles = 30;
  try {
    parse_glb(plain_glb(cube, R"([{"mesh":0},{"mesh":0},{"mesh":0}])", "[0,1,2]"), "many.glb", limits);
    ADD_FAILURE() << "36 triangles read under a limit of 30";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kResourceLimit);
    EXPECT_EQ(e.field(), "max_triangles");
  }
}

// A meshopt frame's .glb (EXT_meshopt_compression) whose buffer views say something the extension does not allow,
// or whose streams do not decode, is refused naming the place; its decoded size is bounded before it is allocated.
TEST(MeshGltf, RefusesMeshoptBufferViewsNamingWhy) {
  const int two = 2;
  FrameCodecOptions o;
  o.codec = FrameCodec::kMeshopt;
  o.draco.quantization_bounds = Aabb{Vec3::Constant(-1.5), Vec3::Constant(1.5)};
  o.max_piece_triangles = 1024;
  o.draco.normals = true;
  Mesh sphere = testing::icosphere(3);
  sphere.normals = sphere.vertices;  // unit sphere: radial normals
  const std::string good = to_gltf(encode_frame(sphere, o, two), o.codec, {}, two);
  const Mesh read = parse_glb(good, "good.glb");
  EXPECT_EQ(read.triangles.size(), sphere.triangles.size());
  auto refused = [&](const std::string& glb, const std::string& words, const MeshReadLimits& limits = {}) {
    try {
      parse_glb(glb, "bad.glb", limits);
      ADD_FAILURE() << "read: " << words;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("bad.glb"), std::string::npos) << e.what();
    }
  };
  refused(json_replaced(good, R"("filter":"OCTAHEDRAL")", R"("filter":"QUATERNION")"), "filter 'QUATERNION'");
  refused(json_replaced(good, R"("mode":"TRIANGLES")", R"("mode":"LINES")"), "mode 'LINES'");
  refused(json_replaced(good, R"("byteStride":4,"mode":"TRIANGLES")", R"("byteStride":3,"mode":"TRIANGLES")"),
          "byteStride 3");
  refused(json_replaced(good, R"("byteStride":8,"target")", R"("byteStride":12,"target")"), "another byteStride");
  refused(json_replaced(good, R"("buffer":0,"byteOffset")", R"("buffer":1,"byteOffset")"), "outside the file");
  // A count that disagrees with the view's length, and one that claims more than the bytes can hold.
  const std::size_t at = good.find(R"("mode":"TRIANGLES","count":)");
  ASSERT_NE(at, std::string::npos);
  const std::size_t digits = at + std::string(R"("mode":"TRIANGLES","count":)").size();
  const std::string count = good.substr(digits, good.find('}', digits) - digits);
  refused(json_replaced(good, R"("TRIANGLES","count":)" + count, R"("TRIANGLES","count":)" + count + "0"),
          "not byteStride times count");
  const std::string huge =
      json_replaced(json_replaced(good, R"("TRIANGLES","count":)" + count, R"("TRIANGLES","count":300000000)"),
                    R"("byteLength":)" + std::to_string(4 * std::stoul(count)) + ",", R"("byteLength":1200000000,)");
  refused(huge, "claims more data than");
  MeshReadLimits limits;
  limits.max_triangles = 100;
  try {
    parse_glb(good, "small.glb", limits);
    ADD_FAILURE() << "pieces of 320 triangles read under a limit of 100";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kResourceLimit) << e.what();
    EXPECT_EQ(e.field(), "max_triangles");
  }
  // A stream whose bytes are not meshoptimizer's: the first triangle stream's header byte (0xe1) changed.
  const std::size_t offset_at = good.rfind(R"("byteOffset":)", at) + std::string(R"("byteOffset":)").size();
  const std::size_t bin = 20 + ((good[12] & 0xff) | (good[13] & 0xff) << 8) + 8;
  std::string broken = good;
  const std::size_t header = bin + std::stoul(good.substr(offset_at, good.find(',', offset_at) - offset_at));
  ASSERT_EQ(static_cast<unsigned char>(broken[header]), 0xe1);
  broken[header] = 0x00;
  refused(broken, "does not decode");
}

}  // namespace
}  // namespace surfacer
