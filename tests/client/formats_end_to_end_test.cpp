// End to end for the file formats pipelines use: the `surfacer` binary with its in-process server (--local), VTK
// output, output names that keep the input frame numbers or follow a pattern, and the new particle inputs.
#include <google/protobuf/struct.pb.h>
#include <google/protobuf/util/json_util.h>
#include <gtest/gtest.h>
#include <meshoptimizer.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <map>
#include <random>

#include "core/mesh/mesh_checks.h"
#include "core/mesh/mesh_codec.h"
#include "core/mesh/mesh_io.h"
#include "core/mesh/mesh_vtk.h"
#include "core/particles/particle_io.h"
#include "tests/support/files.h"
#include "tests/support/mesh_expectations.h"
#include "tests/support/process.h"

namespace surfacer::client {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using namespace surfacer::testing;

// A jittered lattice of spacing `d` filling a ball, as [[x, y, z], ...] (splashsurf's JSON).
std::vector<Vec3> ball(Vec3 center, double radius, double d, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> jitter(-0.1 * d, 0.1 * d);
  std::vector<Vec3> points;
  const int n = static_cast<int>(std::ceil(radius / d));
  for (int k = -n; k <= n; ++k) {
    for (int j = -n; j <= n; ++j) {
      for (int i = -n; i <= n; ++i) {
        const Vec3 p(i * d, j * d, k * d);
        if (p.norm() <= radius) points.push_back(center + p + Vec3(jitter(rng), jitter(rng), jitter(rng)));
      }
    }
  }
  return points;
}

std::string as_json(const std::vector<Vec3>& points) {
  std::string json = "[";
  char item[96];
  for (std::size_t i = 0; i < points.size(); ++i) {
    std::snprintf(item, sizeof item, "%s[%.6f, %.6f, %.6f]", i == 0 ? "" : ",\n ", points[i].x(), points[i].y(),
                  points[i].z());
    json += item;
  }
  return json + "]\n";
}

// A .glb read as a glTF reader does, from the spec (glTF 2.0, KHR_draco_mesh_compression, EXT_meshopt_compression,
// KHR_mesh_quantization): header and chunks, the JSON, every primitive's Draco stream decoded by Draco's own decoder
// into the accessors it names, or its meshopt buffer views by meshoptimizer's (the accessors' counts and bounds must
// agree with what they hold), positions mapped by the node's scale and translation. The primitives are concatenated,
// then vertices at the same position welded (pieces repeat their seam vertices).
struct Gltf {
  Mesh welded;
  int primitives = 0;
  std::vector<std::string> required;  // extensionsRequired
};

using JsonFields = google::protobuf::Map<std::string, google::protobuf::Value>;
using JsonList = google::protobuf::RepeatedPtrField<google::protobuf::Value>;

std::size_t as_size(const google::protobuf::Value& v) { return static_cast<std::size_t>(v.number_value()); }

// A KHR_draco_mesh_compression primitive by Draco's decoder: POSITION as the integer grid coordinates.
Mesh draco_primitive(const JsonFields& p, const JsonList& views, const std::string& bin) {
  const auto& draco =
      p.at("extensions").struct_value().fields().at("KHR_draco_mesh_compression").struct_value().fields();
  const auto& view = views.at(static_cast<int>(draco.at("bufferView").number_value())).struct_value().fields();
  return decode_draco(bin.substr(as_size(view.at("byteOffset")), as_size(view.at("byteLength"))));
}

// A buffer view compressed by EXT_meshopt_compression, decoded by meshoptimizer as its mode and filter say.
std::string meshopt_view(const JsonFields& view, const std::string& bin) {
  const auto& m = view.at("extensions").struct_value().fields().at("EXT_meshopt_compression").struct_value().fields();
  EXPECT_EQ(m.at("buffer").number_value(), 0);
  const std::string stream = bin.substr(as_size(m.at("byteOffset")), as_size(m.at("byteLength")));
  const std::size_t count = as_size(m.at("count")), stride = as_size(m.at("byteStride"));
  EXPECT_EQ(as_size(view.at("byteLength")), count * stride);
  std::string out(count * stride, '\0');
  const auto* in = reinterpret_cast<const unsigned char*>(stream.data());
  const std::string mode = m.at("mode").string_value();
  const int failed = mode == "ATTRIBUTES" ? meshopt_decodeVertexBuffer(out.data(), count, stride, in, stream.size())
                                          : meshopt_decodeIndexBuffer(out.data(), count, stride, in, stream.size());
  EXPECT_EQ(failed, 0) << mode;
  if (m.contains("filter") && m.at("filter").string_value() == "OCTAHEDRAL") {
    meshopt_decodeFilterOct(out.data(), count, stride);
  }
  return out;
}

// An EXT_meshopt_compression primitive: POSITION (unsigned short grid coordinates, strided), its indices and, when
// it has them, normals (normalized shorts); the Mesh's normals are only counted.
template <class Accessor>
Mesh meshopt_primitive(const JsonFields& p, Accessor accessor, const JsonList& views, const std::string& bin) {
  auto data = [&](const auto& a, std::size_t* stride) {
    const auto& view = views.at(static_cast<int>(a.at("bufferView").number_value())).struct_value().fields();
    *stride = view.contains("byteStride") ? as_size(view.at("byteStride")) : 4;
    return meshopt_view(view, bin);
  };
  const auto& attributes = p.at("attributes").struct_value().fields();
  const auto& position = accessor(attributes.at("POSITION").number_value());
  EXPECT_EQ(position.at("componentType").number_value(), 5123);
  std::size_t stride = 0;
  const std::string points = data(position, &stride);
  Mesh piece;
  for (std::size_t v = 0; v < as_size(position.at("count")); ++v) {
    std::uint16_t q[3];
    std::memcpy(q, points.data() + v * stride, sizeof q);
    piece.vertices.emplace_back(q[0], q[1], q[2]);
  }
  const std::string indices = data(accessor(p.at("indices").number_value()), &stride);
  piece.triangles.resize(indices.size() / 12);
  std::memcpy(piece.triangles.data(), indices.data(), 12 * piece.triangles.size());
  if (attributes.contains("NORMAL")) {
    const auto& normal = accessor(attributes.at("NORMAL").number_value());
    EXPECT_EQ(normal.at("componentType").number_value(), 5122);  // SHORT, normalized
    const std::string normals = data(normal, &stride);
    for (std::size_t v = 0; v < as_size(normal.at("count")); ++v) {
      std::int16_t n[3];
      std::memcpy(n, normals.data() + v * stride, sizeof n);
      piece.normals.push_back(Vec3(n[0], n[1], n[2]) / 32767.0);
      EXPECT_NEAR(piece.normals.back().norm(), 1.0, 1e-3);
    }
  }
  return piece;
}

Gltf read_glb(const fs::path& path) {
  const std::string bytes = read_file(path);
  auto u32 = [&](std::size_t at) {
    std::uint32_t v = 0;
    if (at + 4 <= bytes.size()) std::memcpy(&v, bytes.data() + at, 4);
    return v;
  };
  Gltf out;
  EXPECT_EQ(u32(0), 0x46546C67u) << "magic";
  EXPECT_EQ(u32(4), 2u) << "version";
  EXPECT_EQ(u32(8), bytes.size()) << "length";
  const std::uint32_t json_length = u32(12);
  EXPECT_EQ(u32(16), 0x4E4F534Au) << "JSON chunk";
  EXPECT_EQ(json_length % 4, 0u);
  const std::string json = bytes.substr(20, json_length);
  const std::size_t bin_at = 20 + json_length + 8;
  const std::string bin = bin_at <= bytes.size() ? bytes.substr(bin_at, u32(20 + json_length)) : std::string();
  google::protobuf::Struct doc;
  EXPECT_TRUE(google::protobuf::util::JsonStringToMessage(json, &doc).ok()) << json;
  const auto& f = doc.fields();
  EXPECT_EQ(f.at("asset").struct_value().fields().at("version").string_value(), "2.0");
  if (f.contains("extensionsRequired")) {
    for (const auto& e : f.at("extensionsRequired").list_value().values()) out.required.push_back(e.string_value());
  }
  const auto& node = f.at("nodes").list_value().values(0).struct_value().fields();
  Vec3 scale = Vec3::Ones(), translation = Vec3::Zero();
  for (int a = 0; a < 3; ++a) {
    scale[a] = node.at("scale").list_value().values(a).number_value();
    translation[a] = node.at("translation").list_value().values(a).number_value();
  }
  if (!node.contains("mesh")) return out;
  const auto& accessors = f.at("accessors").list_value().values();
  const auto& views = f.at("bufferViews").list_value().values();
  std::map<std::array<double, 3>, std::uint32_t> index;  // welding by position
  auto accessor = [&](double i) -> const auto& { return accessors.at(static_cast<int>(i)).struct_value().fields(); };
  for (const auto& prim : f.at("meshes")
                              .list_value()
                              .values(static_cast<int>(node.at("mesh").number_value()))
                              .struct_value()
                              .fields()
                              .at("primitives")
                              .list_value()
                              .values()) {
    ++out.primitives;
    const auto& p = prim.struct_value().fields();
    const auto& position = accessor(p.at("attributes").struct_value().fields().at("POSITION").number_value());
    const Mesh piece =
        p.contains("extensions") ? draco_primitive(p, views, bin) : meshopt_primitive(p, accessor, views, bin);
    EXPECT_EQ(position.at("componentType").number_value(), 5123);  // UNSIGNED_SHORT (KHR_mesh_quantization)
    EXPECT_EQ(position.at("count").number_value(), static_cast<double>(piece.vertices.size()));
    EXPECT_EQ(accessor(p.at("indices").number_value()).at("count").number_value(), 3.0 * piece.triangles.size());
    for (int a = 0; a < 3; ++a) {
      double lo = 1e300, hi = -1e300;
      for (const Vec3& q : piece.vertices) {
        lo = std::min(lo, q[a]);
        hi = std::max(hi, q[a]);
      }
      EXPECT_EQ(position.at("min").list_value().values(a).number_value(), lo);
      EXPECT_EQ(position.at("max").list_value().values(a).number_value(), hi);
    }
    if (p.at("attributes").struct_value().fields().contains("NORMAL")) {
      EXPECT_EQ(piece.normals.size(), piece.vertices.size());
    }
    std::vector<std::uint32_t> ids(piece.vertices.size());
    for (std::size_t v = 0; v < piece.vertices.size(); ++v) {
      const Vec3 w = piece.vertices[v].cwiseProduct(scale) + translation;
      const auto [it, fresh] = index.try_emplace({w.x(), w.y(), w.z()}, static_cast<std::uint32_t>(index.size()));
      if (fresh) out.welded.vertices.push_back(w);
      ids[v] = it->second;
    }
    for (const Triangle& t : piece.triangles) out.welded.triangles.push_back({ids[t[0]], ids[t[1]], ids[t[2]]});
  }
  return out;
}

class FormatsEndToEnd : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { root_ = fresh_temp_dir("formats_e2e"); }
  static void TearDownTestSuite() { fs::remove_all(root_); }
  void SetUp() override { dir_ = current_test_dir(root_); }

  ProcessResult cli(std::vector<std::string> args) {
    args.insert(args.begin(), {cli_binary().string(), "--local", "--workers", "2"});
    const std::string tag = "cli" + std::to_string(counter_++);
    return run_process(args, dir_ / (tag + ".out"), dir_ / (tag + ".err"), 120s);
  }

  static inline fs::path root_;
  fs::path dir_;
  int counter_ = 0;
};

TEST_F(FormatsEndToEnd, IsosurfaceWritesVtkAndVtuWithThePlyFramesVertices) {
  write_file(dir_ / "sphere.json", R"({"root": {"sphere": {"radius": 0.5}}})");
  const ProcessResult r = cli({"run", "isosurface", "--scene", (dir_ / "sphere.json").string(), "--cells", "24", "-o",
                               (dir_ / "out").string(), "--format", "ply,vtk,vtu"});
  ASSERT_EQ(r.code, 0) << r;
  const Mesh ply = read_mesh(dir_ / "out" / "frame_0000.ply");
  ASSERT_FALSE(ply.empty());
  EXPECT_TRUE(mesh_file_has(dir_ / "out" / "frame_0000.ply", kClosed | kEdgeManifold));
  for (const char* name : {"frame_0000.vtk", "frame_0000.vtu"}) {
    SCOPED_TRACE(name);
    EXPECT_EQ(read_particles(dir_ / "out" / name).positions, ply.vertices);  // the same float positions
  }
  // The writers' own bytes for that mesh (the cells are checked by core's round trips).
  EXPECT_EQ(read_file(dir_ / "out" / "frame_0000.vtk"), write_vtk(ply));
  EXPECT_EQ(read_file(dir_ / "out" / "frame_0000.vtu"), write_vtu(ply));
}

// --format glb: the pieces as received (Draco's or meshoptimizer's streams), in a file any glTF reader with those
// extensions takes, or for raw frames plain glTF that every reader takes; the same surface as the .ply of the same
// frame, whatever encoding the frames came in.
TEST_F(FormatsEndToEnd, GlbHoldsTheFramesSurfaceWhateverTheEncoding) {
  write_file(dir_ / "gyroid.json",
             R"({"root": {"intersection": {"children": [{"gyroid": {"period": 1, "thickness": 0.12}},
                 {"sphere": {"radius": 1.5}}]}}})");
  int run = 0;
  for (const std::vector<std::string>& extra :
       std::vector<std::vector<std::string>>{{},
                                             {"--encoding", "meshopt"},
                                             {"--raw"},
                                             {"--normals", "--quantization-bits", "12"},
                                             {"--encoding", "meshopt", "--normals"}}) {
    for (int cells : {40, 150}) {  // one piece; several
      const fs::path out = dir_ / ("out" + std::to_string(run++));
      std::vector<std::string> args = {"run",     "isosurface",          "--scene",  (dir_ / "gyroid.json").string(),
                                       "--cells", std::to_string(cells), "--method", "cubes",
                                       "-o",      out.string(),          "--format", "glb,ply"};
      args.insert(args.end(), extra.begin(), extra.end());
      SCOPED_TRACE(::testing::PrintToString(args));
      const ProcessResult r = cli(args);
      ASSERT_EQ(r.code, 0) << r;
      const Mesh ply = read_mesh(out / "frame_0000.ply");
      if (extra == std::vector<std::string>{"--raw"}) {
        // Raw frames: plain binary glTF, no compression extension, the frame's triangles with float positions.
        EXPECT_EQ(read_file(out / "frame_0000.glb").find("extensionsRequired"), std::string::npos);
        const Mesh plain = read_mesh(out / "frame_0000.glb");
        ASSERT_EQ(plain.triangles.size(), ply.triangles.size());
        for (std::size_t t = 0; t < ply.triangles.size(); ++t) {
          for (int k = 0; k < 3; ++k) {
            ASSERT_EQ(plain.vertices[plain.triangles[t][k]],
                      ply.vertices[ply.triangles[t][k]].cast<float>().cast<double>());
          }
        }
        continue;
      }
      const Gltf glb = read_glb(out / "frame_0000.glb");
      const bool meshopt = extra.size() >= 2 && extra[1] == "meshopt";
      EXPECT_EQ(glb.required,
                (std::vector<std::string>{meshopt ? "EXT_meshopt_compression" : "KHR_draco_mesh_compression",
                                          "KHR_mesh_quantization"}));
      EXPECT_EQ(glb.primitives == 1, cells == 40);
      const MeshReport a = check_mesh(ply), b = check_mesh(glb.welded);
      EXPECT_EQ(glb.welded.triangles.size(), ply.triangles.size());
      EXPECT_TRUE(b.closed && b.oriented && b.vertex_manifold);
      EXPECT_EQ(b.euler_characteristic, a.euler_characteristic);
      EXPECT_EQ(b.components, a.components);
      EXPECT_NEAR(b.area, a.area, 1e-3 * a.area);
      EXPECT_NEAR(b.volume, a.volume, 1e-3 * std::abs(a.volume));
    }
  }
  // glTF positions are at most 16 bits: refused before the job runs, naming both flags.
  const ProcessResult r = cli({"run", "isosurface", "--scene", (dir_ / "gyroid.json").string(), "--cells", "20", "-o",
                               (dir_ / "deep").string(), "--format", "glb", "--quantization-bits", "18"});
  EXPECT_EQ(r.code, 2) << r;
  EXPECT_NE(r.err.find("--format glb"), std::string::npos) << r;
  EXPECT_NE(r.err.find("--quantization-bits 18"), std::string::npos) << r;
  EXPECT_FALSE(fs::exists(dir_ / "deep" / "frame_0000.glb"));
}

TEST_F(FormatsEndToEnd, JsonSequenceFromFrame100KeepsItsNumbersUnderAnOutputPattern) {
  // {} matches the inputs whatever their padding; the outputs follow -o's pattern with the inputs' numbers.
  write_file(dir_ / "drop_100.json", as_json(ball(Vec3(0, 0, 0), 0.25, 0.05, 1)));
  write_file(dir_ / "drop_0101.json", as_json(ball(Vec3(1, 0, 0), 0.25, 0.05, 2)));
  const ProcessResult r = cli({"run", "particles", "--input", (dir_ / "drop_{}.json").string(), "--start", "100",
                               "--r-inner", "0.03", "-o", (dir_ / "seq" / "surface_{:05d}.vtu").string()});
  ASSERT_EQ(r.code, 0) << r;
  for (int i = 0; i < 2; ++i) {
    const fs::path file = dir_ / "seq" / ("surface_0010" + std::to_string(i) + ".vtu");
    ASSERT_TRUE(fs::exists(file)) << file << "\n" << r;
    const std::vector<Vec3> vertices = read_particles(file).positions;
    ASSERT_GT(vertices.size(), 100u);
    Vec3 mean = Vec3::Zero();
    for (const Vec3& v : vertices) mean += v;
    EXPECT_NEAR(mean.x() / static_cast<double>(vertices.size()), i, 0.05) << "frame " << 100 + i;
  }
  EXPECT_TRUE(fs::exists(dir_ / "seq" / "stats.csv"));
  EXPECT_FALSE(fs::exists(dir_ / "seq" / "surface_00000.vtu"));

  // Into a directory: frame_0100.*, frame_0101.*.
  const ProcessResult d = cli({"run", "particles", "--input", (dir_ / "drop_{}.json").string(), "--r-inner", "0.03",
                               "-o", (dir_ / "dir").string(), "--format", "vtk,ply"});
  ASSERT_EQ(d.code, 0) << d;
  for (const char* name : {"frame_0100.vtk", "frame_0100.ply", "frame_0101.vtk", "frame_0101.ply"}) {
    EXPECT_TRUE(fs::exists(dir_ / "dir" / name)) << name << "\n" << d;
  }
  EXPECT_TRUE(mesh_file_has(dir_ / "dir" / "frame_0101.ply", kClosed | kEdgeManifold | kVertexManifold));
}

TEST_F(FormatsEndToEnd, CompressedVtuParticlesAreSurfaced) {
  // A .vtu as VTK writes it by default is one a surface from this CLI also is: a zlib-compressed mesh file read back as
  // particles (its vertices).
  Mesh points;
  points.vertices = ball(Vec3(0.5, 0.5, 0.5), 0.3, 0.05, 3);
  write_file(dir_ / "cloud.vtu", write_vtu(points));
  const ProcessResult r = cli({"run", "particles", "--input", (dir_ / "cloud.vtu").string(), "--r-inner", "0.03", "-o",
                               (dir_ / "out").string(), "--format", "ply"});
  ASSERT_EQ(r.code, 0) << r;
  EXPECT_TRUE(mesh_file_has(dir_ / "out" / "frame_0000.ply", kClosed | kEdgeManifold | kVertexManifold));
  EXPECT_NE(r.err.find(std::to_string(points.vertices.size())), std::string::npos) << r;
}

TEST_F(FormatsEndToEnd, UsageErrorsExitTwoNamingTheFlagOrFile) {
  write_file(dir_ / "splash.xyz", std::string("\x00\x00\x80\x3f\x00\x00\x00\x40\x00\x00\x40\x40", 12));
  ProcessResult r = cli({"run", "particles", "--input", (dir_ / "splash.xyz").string(), "--r-inner", "0.03", "-o",
                         (dir_ / "out").string()});
  EXPECT_EQ(r.code, 2) << r;
  EXPECT_NE(r.err.find("splash.xyz"), std::string::npos) << r;
  EXPECT_NE(r.err.find("rename it to .bin"), std::string::npos) << r;

  write_file(dir_ / "s.json", R"({"root": {"sphere": {"radius": 0.5}}})");
  r = cli({"run", "isosurface", "--scene", (dir_ / "s.json").string(), "-o", (dir_ / "o_{}.stl").string()});
  EXPECT_EQ(r.code, 2) << r;
  EXPECT_NE(r.err.find("-o "), std::string::npos) << r;
  r = cli({"run", "isosurface", "--scene", (dir_ / "s.json").string(), "-o", (dir_ / "o_{}.ply").string(), "--format",
           "vtk"});
  EXPECT_EQ(r.code, 2) << r;
  EXPECT_NE(r.err.find("drop --format"), std::string::npos) << r;
  EXPECT_FALSE(fs::exists(dir_ / "o_0.ply"));
}

}  // namespace
}  // namespace surfacer::client
