#include "core/mesh/mesh_vtk.h"

#include <gtest/gtest.h>
#include <zlib.h>

#include <bit>
#include <cstring>
#include <random>

#include "core/particles/particle_io.h"
#include "core/util/errors.h"
#include "tests/support/files.h"
#include "tests/support/test_meshes.h"

namespace surfacer {
namespace {

// --- Readers of what the points reader does not read: cells and normals, independent of the writers --------------

template <class T>
T get(const char* p, bool big_endian) {
  char b[sizeof(T)];
  std::memcpy(b, p, sizeof(T));
  if (big_endian != (std::endian::native == std::endian::big)) std::reverse(b, b + sizeof(T));
  T v;
  std::memcpy(&v, b, sizeof(T));
  return v;
}

// Float32 normals packed x, y, z per vertex from `bytes` on, in the given byte order, equal to the mesh's (as float).
void expect_packed_normals(const char* bytes, const std::vector<Vec3>& normals, bool big_endian) {
  for (std::size_t v = 0; v < normals.size(); ++v) {
    for (int c = 0; c < 3; ++c) {
      EXPECT_EQ(get<float>(bytes + 12 * v + 4 * c, big_endian), static_cast<float>(normals[v][c])) << v << "," << c;
    }
  }
}

// Legacy: the bytes after "KEYWORD ...\n" (the first line that starts with the keyword).
std::string_view after_line(std::string_view vtk, const std::string& keyword) {
  const std::size_t at = vtk.find("\n" + keyword + " ");
  EXPECT_NE(at, std::string_view::npos) << keyword;
  if (at == std::string_view::npos) return {};
  return vtk.substr(vtk.find('\n', at + 1) + 1);
}

std::vector<Triangle> legacy_triangles(std::string_view vtk, std::size_t count) {
  const std::string_view cells = after_line(vtk, "CELLS");
  const std::string_view types = after_line(vtk, "CELL_TYPES");
  std::vector<Triangle> out;
  for (std::size_t t = 0; t < count; ++t) {
    const char* p = cells.data() + 16 * t;
    EXPECT_EQ(get<std::int32_t>(p, true), 3);
    out.push_back({static_cast<std::uint32_t>(get<std::int32_t>(p + 4, true)),
                   static_cast<std::uint32_t>(get<std::int32_t>(p + 8, true)),
                   static_cast<std::uint32_t>(get<std::int32_t>(p + 12, true))});
    EXPECT_EQ(get<std::int32_t>(types.data() + 4 * t, true), 5);
  }
  return out;
}

std::string base64_decode(std::string_view text) {
  std::string out;
  unsigned bits = 0;
  int n = 0;
  for (const char c : text) {
    const char* k = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    if (c == '=') {  // padding closes a group: drop the partial byte
      n = 0;
      bits = 0;
      continue;
    }
    const char* at = std::strchr(k, c);
    if (at == nullptr || c == '\0') continue;  // white space
    bits = bits << 6 | static_cast<unsigned>(at - k);
    n += 6;
    if (n >= 8) {
      n -= 8;
      out.push_back(static_cast<char>((bits >> n) & 0xff));
    }
  }
  return out;
}

// XML: the uncompressed bytes of the DataArray named `name` (its type in *type), from VTK's zlib block layout.
std::string vtu_array(const std::string& vtu, const std::string& name, std::string* type) {
  const std::size_t tag = vtu.rfind("<DataArray", vtu.find("Name=\"" + name + "\""));
  const std::size_t type_at = vtu.find("type=\"", tag) + 6;
  *type = vtu.substr(type_at, vtu.find('"', type_at) - type_at);
  const std::size_t begin = vtu.find('>', tag) + 1;
  const std::string bytes = base64_decode(std::string_view(vtu).substr(begin, vtu.find("</DataArray>", begin) - begin));
  const auto blocks = get<std::uint64_t>(bytes.data(), false);
  const auto block_size = get<std::uint64_t>(bytes.data() + 8, false);
  const auto last = get<std::uint64_t>(bytes.data() + 16, false);
  std::string out;
  std::size_t at = 24 + 8 * blocks;
  for (std::uint64_t b = 0; b < blocks; ++b) {
    const auto compressed = get<std::uint64_t>(bytes.data() + 24 + 8 * b, false);
    std::string block(b + 1 == blocks && last != 0 ? last : block_size, '\0');
    uLongf size = block.size();
    EXPECT_EQ(uncompress(reinterpret_cast<Bytef*>(block.data()), &size,
                         reinterpret_cast<const Bytef*>(bytes.data() + at), compressed),
              Z_OK);
    EXPECT_EQ(size, block.size());
    out += block;
    at += compressed;
  }
  EXPECT_EQ(at, bytes.size());
  return out;
}

std::vector<Triangle> vtu_triangles(const std::string& vtu) {
  std::string type, offsets_type, types_type;
  const std::string connectivity = vtu_array(vtu, "connectivity", &type);
  const std::string offsets = vtu_array(vtu, "offsets", &offsets_type);
  const std::string types = vtu_array(vtu, "types", &types_type);
  EXPECT_EQ(type, "Int32");
  EXPECT_EQ(offsets_type, "Int32");
  EXPECT_EQ(types_type, "UInt8");
  std::vector<Triangle> out;
  for (std::size_t t = 0; t < connectivity.size() / 12; ++t) {
    const char* p = connectivity.data() + 12 * t;
    out.push_back({static_cast<std::uint32_t>(get<std::int32_t>(p, false)),
                   static_cast<std::uint32_t>(get<std::int32_t>(p + 4, false)),
                   static_cast<std::uint32_t>(get<std::int32_t>(p + 8, false))});
    EXPECT_EQ(get<std::int32_t>(offsets.data() + 4 * t, false), static_cast<std::int32_t>(3 * (t + 1)));
    EXPECT_EQ(types[t], 5);
  }
  EXPECT_EQ(offsets.size(), 4 * out.size());
  EXPECT_EQ(types.size(), out.size());
  return out;
}

std::vector<Vec3> as_stored(const std::vector<Vec3>& v, bool double_precision) {
  std::vector<Vec3> out;
  for (const Vec3& p : v) out.push_back(double_precision ? p : p.cast<float>().cast<double>());
  return out;
}

// --- Meshes ------------------------------------------------------------------------------------------------------

// Random positions and triangles whose indices reach 2^18 and the last vertex (past 16-bit and 24-bit-float ranges
// of careless readers), several zlib blocks of 1 MiB per array.
Mesh big_index_mesh() {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1e3, 1e3);
  Mesh m;
  const std::uint32_t n = (1u << 18) + 17;
  for (std::uint32_t i = 0; i < n; ++i) m.vertices.emplace_back(u(rng), u(rng), u(rng));
  for (std::uint32_t t = 0; t < 100000; ++t) m.triangles.push_back({static_cast<std::uint32_t>(rng() % n), n - 1 - t, static_cast<std::uint32_t>(rng() % n)});
  return m;
}

std::vector<std::pair<std::string, Mesh>> meshes() {
  Mesh sphere = testing::icosphere(3, 2.5, Vec3(1, 2, 3));
  for (const Vec3& p : sphere.vertices) sphere.normals.push_back((p - Vec3(1, 2, 3)).normalized());
  return {{"empty", Mesh{}},
          {"cube", testing::unit_cube()},
          {"sphere with normals", sphere},
          {"torus", testing::torus_mesh(3, 1, 48, 24, Vec3(1e3, -1e3, 0.5))},
          {"big indices", big_index_mesh()}};
}

TEST(MeshVtk, LegacyRoundTrip) {
  for (const auto& [name, mesh] : meshes()) {
    for (const bool double_precision : {false, true}) {
      SCOPED_TRACE(name + (double_precision ? " double" : " float"));
      const std::string vtk = write_vtk(mesh, double_precision);
      EXPECT_EQ(vtk.rfind("# vtk DataFile Version 4.2\nsurfacer\nBINARY\nDATASET UNSTRUCTURED_GRID\n", 0), 0u);
      const ParticleFrame points = parse_particles(vtk, ParticleFormat::kVtk, name + ".vtk");
      EXPECT_EQ(points.positions, as_stored(mesh.vertices, double_precision));
      EXPECT_EQ(legacy_triangles(vtk, mesh.triangles.size()), mesh.triangles);
      if (!mesh.normals.empty()) {
        const std::string_view normals = after_line(vtk, "VECTORS");  // VECTORS Normals float
        ASSERT_GE(normals.size(), 12 * mesh.normals.size());
        expect_packed_normals(normals.data(), mesh.normals, true);
      } else {
        EXPECT_EQ(vtk.find("POINT_DATA"), std::string::npos);
      }
    }
  }
}

TEST(MeshVtk, XmlRoundTrip) {
  for (const auto& [name, mesh] : meshes()) {
    for (const bool double_precision : {false, true}) {
      SCOPED_TRACE(name + (double_precision ? " double" : " float"));
      const std::string vtu = write_vtu(mesh, double_precision);
      EXPECT_NE(vtu.find("compressor=\"vtkZLibDataCompressor\""), std::string::npos);
      EXPECT_NE(vtu.find("NumberOfCells=\"" + std::to_string(mesh.triangles.size()) + "\""), std::string::npos);
      const ParticleFrame points = parse_particles(vtu, ParticleFormat::kVtu, name + ".vtu");
      EXPECT_EQ(points.positions, as_stored(mesh.vertices, double_precision));
      EXPECT_EQ(vtu_triangles(vtu), mesh.triangles);
      if (!mesh.normals.empty()) {
        std::string type;
        const std::string normals = vtu_array(vtu, "Normals", &type);
        EXPECT_EQ(type, "Float32");
        ASSERT_EQ(normals.size(), 12 * mesh.normals.size());
        expect_packed_normals(normals.data(), mesh.normals, false);
      } else {
        EXPECT_EQ(vtu.find("PointData"), std::string::npos);
      }
    }
  }
}

// Mesh attributes of 1 to 4 components come back under their names from .vtk, .vtu and .ply (read by the particle
// readers, which keep point arrays, and by the mesh PLY reader).
Mesh mesh_with_attributes() {
  Mesh mesh = testing::torus_mesh(3, 1, 24, 12, Vec3(0, 0, 0));
  const std::size_t n = mesh.vertices.size();
  const std::vector<std::pair<std::string, int>> layout = {
      {"density", 1}, {"uv", 2}, {"velocity", 3}, {"rgba", 4}, {"foam mask", 1}};
  for (const auto& [name, components] : layout) {
    Attribute a{name, components, {}};
    for (std::size_t i = 0; i < n * static_cast<std::size_t>(components); ++i) {
      a.values.push_back(static_cast<float>(i) * 0.25f - 3.0f);
    }
    mesh.attributes.push_back(a);
  }
  return mesh;
}

void expect_attributes(const std::vector<Attribute>& got, const std::vector<Attribute>& want) {
  ASSERT_EQ(got.size(), want.size());
  for (std::size_t i = 0; i < want.size(); ++i) {
    EXPECT_EQ(got[i].name, want[i].name);
    EXPECT_EQ(got[i].components, want[i].components) << want[i].name;
    EXPECT_EQ(got[i].values, want[i].values) << want[i].name;
  }
}

TEST(MeshVtk, AttributesAreNamedPointArrays) {
  const Mesh mesh = mesh_with_attributes();
  expect_attributes(parse_particles(write_vtk(mesh), ParticleFormat::kVtk, "a.vtk").attributes, mesh.attributes);
  expect_attributes(parse_particles(write_vtu(mesh), ParticleFormat::kVtu, "a.vtu").attributes, mesh.attributes);
  const std::string vtu = write_vtu(mesh);
  EXPECT_NE(vtu.find("Name=\"velocity\" NumberOfComponents=\"3\""), std::string::npos);
  EXPECT_NE(write_vtk(mesh).find("SCALARS foam%20mask float 1"), std::string::npos);
  Mesh wrong = mesh;
  wrong.attributes[0].values.pop_back();
  EXPECT_THROW(write_vtu(wrong), Error);
}

TEST(MeshVtk, FilesOnDiskReadBack) {
  const std::filesystem::path dir = testing::fresh_temp_dir("mesh_vtk");
  const Mesh mesh = testing::torus_mesh(2, 0.5);
  testing::write_file(dir / "torus.vtk", write_vtk(mesh));
  testing::write_file(dir / "torus.vtu", write_vtu(mesh));
  for (const char* file : {"torus.vtk", "torus.vtu"}) {
    SCOPED_TRACE(file);
    EXPECT_EQ(read_particles(dir / file).positions, as_stored(mesh.vertices, false));
  }
  EXPECT_EQ(legacy_triangles(testing::read_file(dir / "torus.vtk"), mesh.triangles.size()), mesh.triangles);
  EXPECT_EQ(vtu_triangles(testing::read_file(dir / "torus.vtu")), mesh.triangles);
  std::filesystem::remove_all(dir);
}

TEST(MeshVtk, BadMeshesAreRefused) {
  Mesh bad = testing::unit_cube();
  bad.triangles.push_back({0, 1, 8});
  for (auto* writer : {&write_vtk, &write_vtu}) {
    try {
      writer(bad, false);
      ADD_FAILURE() << "no error";
    } catch (const Error& e) {
      EXPECT_EQ(e.kind(), ErrorKind::kInvalidInput);
      EXPECT_NE(std::string(e.what()).find("uses vertex 8"), std::string::npos) << e.what();
    }
  }
  Mesh normals = testing::unit_cube();
  normals.normals.resize(3);
  EXPECT_THROW(write_vtu(normals), Error);
}

}  // namespace
}  // namespace surfacer
