// End to end for the file formats pipelines use: the `surfacer` binary with its in-process server (--local), VTK
// output, output names that keep the input frame numbers or follow a pattern, and the new particle inputs.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <random>

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
