#include "core/mesh/mesh_io.h"

#include <gtest/gtest.h>

#include <bit>
#include <cstring>
#include <filesystem>
#include <random>

#include "core/mesh/mesh_checks.h"
#include "core/mesh/mesh_codec.h"
#include "core/util/allocation_budget.h"
#include "core/util/errors.h"
#include "core/util/text.h"
#include "tests/support/error_expectations.h"
#include "tests/support/files.h"
#include "tests/support/test_meshes.h"

namespace surfacer {
namespace {

Mesh test_mesh(bool normals) {
  Mesh m = testing::icosphere(2, 1.7, Vec3(0.1, -3.2, 1e3));
  if (normals) {
    for (const Vec3& p : m.vertices) m.normals.push_back((p - Vec3(0.1, -3.2, 1e3)).normalized());
  }
  return m;
}

void expect_close(const std::vector<Vec3>& a, const std::vector<Vec3>& b, double tolerance) {
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t i = 0; i < a.size(); ++i) EXPECT_LE((a[i] - b[i]).cwiseAbs().maxCoeff(), tolerance) << i;
}

// Expects InvalidInput whose message names the file and contains `fragment`.
void expect_parse_error(std::string_view bytes, MeshFormat format, const std::string& name,
                        const std::string& fragment = "") {
  try {
    const Mesh m = parse_mesh(bytes, format, name);
    ADD_FAILURE() << "parsed without error: " << m.vertices.size() << " vertices";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kInvalidInput);
    const std::string what = e.what();
    EXPECT_EQ(what.rfind(name + ": ", 0), 0u) << what;
    EXPECT_NE(what.find(fragment), std::string::npos) << what;
  }
}

TEST(MeshIo, BinaryPlyFloatRoundTrip) {
  const Mesh m = test_mesh(true);
  const Mesh r = parse_mesh(write_ply(m), MeshFormat::kPly, "m.ply");
  EXPECT_EQ(r.triangles, m.triangles);
  expect_close(r.vertices, m.vertices, 1e3 * 1.2e-7);  // float32
  expect_close(r.normals, m.normals, 1e-7);
}

TEST(MeshIo, BinaryPlyDoubleRoundTripIsExact) {
  const Mesh m = test_mesh(false);
  const Mesh r = parse_mesh(write_ply(m, true), MeshFormat::kPly, "m.ply");
  EXPECT_EQ(r.triangles, m.triangles);
  EXPECT_EQ(r.vertices, m.vertices);
  EXPECT_TRUE(r.normals.empty());
}

TEST(MeshIo, ObjRoundTrip) {
  for (bool normals : {false, true}) {
    const Mesh m = test_mesh(normals);
    const Mesh r = parse_mesh(write_obj(m), MeshFormat::kObj, "m.obj");
    EXPECT_EQ(r.triangles, m.triangles);
    expect_close(r.vertices, m.vertices, 1e3 * 1e-8);  // %.9g
    EXPECT_EQ(r.normals.size(), m.normals.size());
    if (normals) expect_close(r.normals, m.normals, 1e-8);
  }
}

TEST(MeshIo, AsciiPlyWithExtrasAndPolygons) {
  const std::string ply =
      "ply\r\n"
      "format ascii 1.0\n"
      "comment made by hand\n"
      "element vertex 5\n"
      "property float x\n"
      "property float y\n"
      "property uchar red\n"
      "property float z\n"
      "element face 2\n"
      "property uchar flags\n"
      "property list uchar int vertex_indices\n"
      "property list uchar float texcoord\n"
      "element edge 1\n"
      "property int vertex1\n"
      "property int vertex2\n"
      "end_header\n"
      "0 0 255 0\n"
      "1 0 0 0\n"
      "1 1 0 0\n"
      "0 1 0 0\n"
      "0.5 0.5 7 1e0\n"
      "1 4 0 1 2 3 0\n"
      "0 3 0 1 4 2 0.5 0.5\n"
      "0 1\n";
  const Mesh m = parse_mesh(ply, MeshFormat::kPly, "hand.ply");
  ASSERT_EQ(m.vertices.size(), 5u);
  EXPECT_EQ(m.vertices[4], Vec3(0.5, 0.5, 1.0));
  ASSERT_EQ(m.triangles.size(), 3u);  // quad fanned into 2 + 1 triangle
  EXPECT_EQ(m.triangles[0], (Triangle{0, 1, 2}));
  EXPECT_EQ(m.triangles[1], (Triangle{0, 2, 3}));
  EXPECT_EQ(m.triangles[2], (Triangle{0, 1, 4}));
}

// Big-endian PLY with double positions, ushort counts, uint indices and an extra int property.
TEST(MeshIo, BigEndianPly) {
  const Mesh cube = testing::unit_cube();
  std::string ply =
      "ply\nformat binary_big_endian 1.0\nelement vertex 8\nproperty double x\nproperty double y\n"
      "property double z\nproperty int id\nelement face 12\nproperty list ushort uint vertex_indices\nend_header\n";
  auto put = [&ply](auto value) {
    unsigned char raw[sizeof(value)];
    std::memcpy(raw, &value, sizeof(value));
    if constexpr (std::endian::native == std::endian::little) std::reverse(raw, raw + sizeof(value));
    ply.append(reinterpret_cast<const char*>(raw), sizeof(value));
  };
  for (std::size_t v = 0; v < 8; ++v) {
    for (int c = 0; c < 3; ++c) put(cube.vertices[v][c] * 0.1);
    put(static_cast<std::int32_t>(v));
  }
  for (const Triangle& t : cube.triangles) {
    put(static_cast<std::uint16_t>(3));
    for (std::uint32_t i : t) put(i);
  }
  const Mesh m = parse_mesh(ply, MeshFormat::kPly, "be.ply");
  EXPECT_EQ(m.triangles, cube.triangles);
  for (std::size_t v = 0; v < 8; ++v) EXPECT_EQ(m.vertices[v], cube.vertices[v] * 0.1);
  const MeshReport r = check_mesh(m);
  EXPECT_NEAR(r.volume, 1e-3, 1e-15);

  // Truncated anywhere in the data: an error naming the byte offset, never a crash.
  for (std::size_t cut = ply.size() - 1; cut > ply.size() - 200; cut -= 7) {
    expect_parse_error(std::string_view(ply).substr(0, cut), MeshFormat::kPly, "be.ply", "byte ");
  }
}

TEST(MeshIo, TruncatedBinaryPlyIsAnError) {
  const std::string bytes = write_ply(test_mesh(true));
  const std::size_t header = bytes.find("end_header\n") + 11;
  for (std::size_t cut : {header, header + 1, header + 100, bytes.size() / 2, bytes.size() - 1}) {
    expect_parse_error(std::string_view(bytes).substr(0, cut), MeshFormat::kPly, "cut.ply", "unexpected end of file");
  }
  for (std::size_t cut : {std::size_t{0}, std::size_t{2}, header / 2, header - 1}) {
    expect_parse_error(std::string_view(bytes).substr(0, cut), MeshFormat::kPly, "cut.ply");
  }
}

TEST(MeshIo, PlyErrorsNameFileAndLine) {
  const std::string head =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
      "element face 1\nproperty list uchar int vertex_indices\nend_header\n";
  expect_parse_error(head + "0 0 0\n1 0 0\n0 1\n3 0 1 2\n", MeshFormat::kPly, "bad.ply",
                     "line 12: expected 3 numbers for vertex 2");
  expect_parse_error(head + "0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n", MeshFormat::kPly, "bad.ply", "line 13: face 0");
  expect_parse_error(head + "0 0 0\n1 0 0\n0 1 0\n3 0 1 -1\n", MeshFormat::kPly, "bad.ply", "line 13");
  expect_parse_error(head + "0 0 0\n1 0 0\n0 1 0\n", MeshFormat::kPly, "bad.ply", "unexpected end of file");
  expect_parse_error(head + "0 0 0\n1 x 0\n0 1 0\n3 0 1 2\n", MeshFormat::kPly, "bad.ply", "line 11");
  expect_parse_error(head + "0 0 0\n1 0 0\n0 1 0\n5 0 1 2\n", MeshFormat::kPly, "bad.ply", "line 13");
  expect_parse_error("ply\nformat ascii 1.0\nelement vertex 1\nproperty float q\nend_header\n1\n", MeshFormat::kPly,
                     "bad.ply", "line 3");
  expect_parse_error("solid stl\n", MeshFormat::kPly, "bad.ply", "line 1");
  expect_parse_error("ply\nformat ascii 1.0\nelement vertex 1\n", MeshFormat::kPly, "bad.ply", "header");
  expect_parse_error(
      "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\n"
      "property float y\nproperty float z\nend_header\n",
      MeshFormat::kPly, "huge.ply", "unexpected end of file");
}

// Found by fuzz/fuzz_mesh (fuzz/corpus/mesh/crash-ply-two-vertex-elements): with two vertex elements the property
// layout came from the last one and was applied to the values of the first, reading past them (heap overflow).
TEST(MeshIo, PlyWithTwoVertexOrFaceElementsIsAnError) {
  const std::string vertex3 = "element vertex 1\nproperty float x\nproperty float y\nproperty float z\n";
  const std::string vertex6 =
      "element vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
      "property float nx\nproperty float ny\nproperty float nz\n";
  const std::string face = "element face 1\nproperty list uchar int vertex_indices\n";
  for (const char* format : {"ascii", "binary_little_endian"}) {
    const std::string head = std::string("ply\nformat ") + format + " 1.0\n";
    expect_parse_error(head + vertex3 + vertex6 + "end_header\n" + std::string(40, '\0'), MeshFormat::kPly, "two.ply",
                       "line 7: a second 'vertex' element");
    expect_parse_error(head + vertex3 + face + face + "end_header\n" + std::string(40, '\0'), MeshFormat::kPly,
                       "two.ply", "line 9: a second 'face' element");
  }
}

// Found by fuzz/fuzz_mesh (fuzz/corpus/mesh/crash-ply-huge-face-index, crash-ply-face-before-huge-vertex-count):
// the error message for an out-of-range face index converted the index to int64 (undefined for 1.4e52 or NaN),
// and with faces before a vertex element declaring more than 2^32 vertices an index passed the range check
// and was converted to a 32-bit index (undefined, and a wrong triangle).
TEST(MeshIo, PlyHugeFaceIndicesAndVertexCounts) {
  const std::string head =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
      "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n";
  expect_parse_error(head + "3 0 1 14444444444444444444444444444444444444444444444444444\n", MeshFormat::kPly,
                     "big.ply", "face 0 uses vertex index 1.4444444444444444e+52 but there are 3 vertices");
  expect_parse_error(
      "ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int vertex_indices\n"
      "element vertex 5000000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
      "3 0 1 4999999999\n0 0 0\n",
      MeshFormat::kPly, "many.ply", "line 5: the vertex element declares 5000000000 vertices");
}

// PLY allocates in proportion to the bytes present, never for a count its header or a list declares (OBJ declares no
// counts): small hostile files fail as InvalidInput well within a small allocation budget. (The Draco decoder has a
// budget of its own: decode_draco.)
TEST(MeshIo, DeclaredCountsDoNotDriveAllocations) {
  const std::string xyz = "property float x\nproperty float y\nproperty float z\n";
  const std::string huge_counts = "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\n" + xyz +
                                  "element face 4000000000\nproperty list uchar int vertex_indices\nend_header\n" +
                                  std::string(36, '\0');
  std::string huge_list = "ply\nformat binary_little_endian 1.0\nelement vertex 3\n" + xyz +
                          "element face 1\nproperty list uint uchar vertex_indices\nend_header\n" +
                          std::string(36, '\0');
  huge_list += std::string("\xff\xff\xff\xff", 4) + std::string(100, '\0');  // a list of 2^32 - 1 indices
  AllocationBudget budget(std::size_t{4} << 20);
  for (const std::string& bytes : {huge_counts, huge_list}) {
    EXPECT_TRUE(testing::throws_error([&] { parse_mesh(bytes, MeshFormat::kPly, "hostile.ply"); },
                                      ErrorKind::kInvalidInput, "file"));
  }
  EXPECT_FALSE(budget.exhausted());
}

// A list length of any integer type, up to the largest it holds (2^64 - 1 rounds above what a 64-bit index holds),
// in either byte order, is refused as the end of the file inside that face when the bytes for it are not there.
TEST(MeshIo, BinaryPlyListLengthsUpToTheirTypesMaximum) {
  struct CountType {
    const char* name;
    int bytes;
  };
  const CountType types[] = {{"uchar", 1}, {"ushort", 2}, {"uint", 4}, {"uint64", 8},
                             {"char", 1},  {"short", 2},  {"int", 4},  {"int64", 8}};
  for (const bool big : {false, true}) {
    for (const CountType& type : types) {
      const bool is_signed = type.name[0] != 'u';
      std::string bytes = std::string("ply\nformat ") + (big ? "binary_big_endian" : "binary_little_endian") +
                          " 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                          "element face 1\nproperty list " +
                          type.name + " uint vertex_indices\nend_header\n" + std::string(36, '\0');
      // The type's largest value: all ones, with the sign bit clear for signed types.
      std::string count(static_cast<std::size_t>(type.bytes), '\xff');
      if (is_signed) count[big ? 0 : count.size() - 1] = '\x7f';
      bytes += count + std::string(12, '\0');
      SCOPED_TRACE(std::string(type.name) + (big ? " big endian" : " little endian"));
      expect_parse_error(bytes, MeshFormat::kPly, "long_list.ply", "unexpected end of file in face 0 of 1 (list of ");
    }
  }
}

TEST(MeshIo, BinaryPlyIndexOutOfRange) {
  Mesh m = testing::unit_cube();
  std::string bytes = write_ply(m);
  // Last index of the last face -> 8.
  const std::int32_t bad = 8;
  std::memcpy(bytes.data() + bytes.size() - 4, &bad, 4);
  expect_parse_error(bytes, MeshFormat::kPly, "idx.ply", "face 11 uses vertex index 8");
}

TEST(MeshIo, ObjFeatures) {
  const std::string obj =
      "# comment\n"
      "mtllib x.mtl\n"
      "o thing\n"
      "v 0 0 0\n"
      "v 1 0 0 1.0\n"
      "v 1 1 0\n"
      "v 0 1 0\n"
      "vt 0 0\n"
      "vn 0 0 1\n"
      "g group\n"
      "usemtl m\n"
      "s off\n"
      "f 1/1/1 2/1/1 3/1/1 4/1/1\n"
      "f -4 -2 -1\n"
      "f 1//1 3//1 4//1\n"
      "l 1 2\n";
  const Mesh m = parse_mesh(obj, MeshFormat::kObj, "x.obj");
  ASSERT_EQ(m.vertices.size(), 4u);
  ASSERT_EQ(m.triangles.size(), 4u);
  EXPECT_EQ(m.triangles[0], (Triangle{0, 1, 2}));
  EXPECT_EQ(m.triangles[1], (Triangle{0, 2, 3}));
  EXPECT_EQ(m.triangles[2], (Triangle{0, 2, 3}));
  EXPECT_EQ(m.triangles[3], (Triangle{0, 2, 3}));
  EXPECT_TRUE(m.normals.empty());  // normals are not one per vertex here
}

TEST(MeshIo, ObjErrors) {
  expect_parse_error("v 0 0 0\nv 1 0 0\nv 1 1\n", MeshFormat::kObj, "bad.obj",
                     "line 3: expected 3 numbers for vertex 3");
  expect_parse_error("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 4\n", MeshFormat::kObj, "bad.obj", "line 4");
  expect_parse_error("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 -4\n", MeshFormat::kObj, "bad.obj", "line 4");
  expect_parse_error("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2\n", MeshFormat::kObj, "bad.obj", "line 4");
  expect_parse_error("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 x\n", MeshFormat::kObj, "bad.obj", "line 4");
  expect_parse_error("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 0 2\n", MeshFormat::kObj, "bad.obj", "line 4");
}

TEST(MeshIo, RandomBytesNeverCrash) {
  std::mt19937 rng(3);
  const std::string valid = write_ply(testing::icosphere(1));
  for (int i = 0; i < 200; ++i) {
    std::string s = valid;
    for (int k = 0; k < 4; ++k) s[rng() % s.size()] = static_cast<char>(rng());
    for (MeshFormat f : {MeshFormat::kPly, MeshFormat::kObj, MeshFormat::kDraco}) {
      try {
        const Mesh m = parse_mesh(s, f, "fuzz");
        for (const Triangle& t : m.triangles) {
          for (std::uint32_t v : t) ASSERT_LT(v, m.vertices.size());
        }
      } catch (const Error& e) {
        EXPECT_EQ(e.kind(), ErrorKind::kInvalidInput);
      }
    }
  }
}

TEST(MeshIo, FilesByExtension) {
  const std::filesystem::path dir = testing::fresh_temp_dir("mesh_io");
  const Mesh m = testing::icosphere(2);
  for (const char* name : {"a.ply", "a.obj", "a.drc", "A.PLY"}) {
    const std::filesystem::path path = dir / name;
    write_mesh(path, m);
    const Mesh r = read_mesh(path);
    EXPECT_EQ(r.triangles.size(), m.triangles.size()) << name;
    EXPECT_LE(testing::max_nearest_vertex_distance(r, m), draco_max_error(Aabb{-Vec3::Ones(), Vec3::Ones()}, 14));
  }
  try {
    read_mesh(dir / "missing.ply");
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kInvalidInput);
    EXPECT_NE(std::string(e.what()).find("missing.ply"), std::string::npos);
  }
  EXPECT_THROW(write_mesh(dir / "a.stl", m), Error);
  EXPECT_THROW(mesh_format_from_path("noext"), Error);
  testing::write_file(dir / "bad.drc", "garbage");
  try {
    read_mesh(dir / "bad.drc");
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::kInvalidInput);
    EXPECT_NE(std::string(e.what()).find("bad.drc"), std::string::npos);
  }
  std::filesystem::remove_all(dir);
}

TEST(MeshIo, EmptyMesh) {
  const Mesh r = parse_mesh(write_ply(Mesh{}), MeshFormat::kPly, "e.ply");
  EXPECT_TRUE(r.vertices.empty() && r.triangles.empty());
  const Mesh o = parse_mesh(write_obj(Mesh{}), MeshFormat::kObj, "e.obj");
  EXPECT_TRUE(o.vertices.empty() && o.triangles.empty());
}

TEST(MeshIo, PlyCarriesVertexAttributes) {
  Mesh mesh = test_mesh(true);
  const std::size_t n = mesh.vertices.size();
  Attribute density{"density", 1, {}}, velocity{"velocity", 3, {}};
  for (std::size_t i = 0; i < n; ++i) density.values.push_back(1000.0f + static_cast<float>(i));
  for (std::size_t i = 0; i < 3 * n; ++i) velocity.values.push_back(0.5f * static_cast<float>(i) - 7.0f);
  mesh.attributes = {density, velocity};
  for (const bool double_precision : {false, true}) {
    const std::string ply = write_ply(mesh, double_precision);
    EXPECT_NE(ply.find("property float velocity_x\nproperty float velocity_y\nproperty float velocity_z\n"),
              std::string::npos);
    const Mesh back = parse_mesh(ply, MeshFormat::kPly, "a.ply");
    EXPECT_EQ(back.triangles, mesh.triangles);
    EXPECT_EQ(back.normals.size(), n);
    ASSERT_EQ(back.attributes.size(), 2u);
    EXPECT_EQ(back.attributes[0].name, "density");
    EXPECT_EQ(back.attributes[0].values, density.values);
    EXPECT_EQ(back.attributes[1].name, "velocity");
    EXPECT_EQ(back.attributes[1].components, 3);
    EXPECT_EQ(back.attributes[1].values, velocity.values);
  }
}

// Names a particle file may carry (a VTU DataArray's Name is free text) are one token in the PLY header, %XX-encoded
// as legacy VTK writes them (core/util/text.h), and come back as they were; other readers see one token per property.
TEST(MeshIo, PlyAttributeNamesWithSpacesAndPercentSurvive) {
  Mesh mesh = test_mesh(false);
  const std::size_t n = mesh.vertices.size();
  const std::vector<std::string> names = {"foam mask", "50% wet", "tab\there", "v\u00e9locit\u00e9 2"};
  for (std::size_t k = 0; k < names.size(); ++k) {
    Attribute a{names[k], k == 0 ? 1 : 3, {}};
    for (std::size_t i = 0; i < n * static_cast<std::size_t>(a.components); ++i) {
      a.values.push_back(static_cast<float>(k) + 0.25f * static_cast<float>(i));
    }
    mesh.attributes.push_back(a);
  }
  for (const bool double_precision : {false, true}) {
    const std::string ply = write_ply(mesh, double_precision);
    EXPECT_NE(ply.find("property float foam%20mask\n"), std::string::npos);
    EXPECT_NE(ply.find("property float 50%25%20wet_x\n"), std::string::npos);
    const Mesh back = parse_mesh(ply, MeshFormat::kPly, "a.ply");
    ASSERT_EQ(back.attributes.size(), names.size());
    for (std::size_t k = 0; k < names.size(); ++k) {
      EXPECT_EQ(back.attributes[k].name, names[k]);
      EXPECT_EQ(back.attributes[k].values, mesh.attributes[k].values);
    }
  }
  EXPECT_EQ(token_name_decoded("a%2"), "a%2");  // not an escape: kept
  EXPECT_EQ(token_name_decoded("a%zz%41"), "a%zzA");
}

}  // namespace
}  // namespace surfacer
