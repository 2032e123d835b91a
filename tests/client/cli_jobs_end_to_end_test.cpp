// End to end for the job types beyond isosurface: a `surfacer-server` child on a loopback port and the `surfacer`
// binary, with inputs generated here (particle files, scenes), checked through exit codes, files and mesh checks.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>

#include "core/mesh_checks.h"
#include "core/mesh_io.h"
#include "tests/client/cli_process.h"

namespace surfacer::client {
namespace {

using namespace e2e;

constexpr const char* kSphere = R"({"name": "sphere", "root": {"sphere": {"radius": 0.5}}})";

// A jittered cubic lattice of spacing `d` filling a ball: "x y z" lines.
std::string particle_ball(Vec3 center, double radius, double d, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> jitter(-0.1 * d, 0.1 * d);
  std::string text = "# x y z\n";
  const int n = static_cast<int>(std::ceil(radius / d));
  char line[96];
  for (int k = -n; k <= n; ++k) {
    for (int j = -n; j <= n; ++j) {
      for (int i = -n; i <= n; ++i) {
        const Vec3 p(i * d, j * d, k * d);
        if (p.norm() > radius) continue;
        const Vec3 q = center + p + Vec3(jitter(rng), jitter(rng), jitter(rng));
        std::snprintf(line, sizeof line, "%.6f %.6f %.6f\n", q.x(), q.y(), q.z());
        text += line;
      }
    }
  }
  return text;
}

MeshReport expect_closed(const fs::path& file) {
  const Mesh mesh = read_mesh(file);
  EXPECT_FALSE(mesh.triangles.empty()) << file;
  const MeshReport report = check_mesh(mesh);
  EXPECT_TRUE(report.closed) << file << ": " << report.boundary_edges << " boundary edges";
  EXPECT_TRUE(report.edge_manifold && report.vertex_manifold) << file;
  return report;
}

class CliJobsEndToEnd : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    root_ = fs::temp_directory_path() / ("surfacer_cli_jobs_e2e_" + std::to_string(::getpid()));
    fs::remove_all(root_);
    fs::create_directories(root_);
    write_file(root_ / "sphere.json", kSphere);
    server_ = new ServerProcess(root_ / "server", 2);
    ASSERT_FALSE(server_->address().empty()) << "surfacer-server did not start:\n" << server_->log();
  }
  static void TearDownTestSuite() {
    if (server_ != nullptr) {
      EXPECT_EQ(server_->stop(), 0) << server_->log();
      delete server_;
      server_ = nullptr;
    }
    fs::remove_all(root_);
  }
  void SetUp() override {
    ASSERT_NE(server_, nullptr);
    dir_ = root_ / ::testing::UnitTest::GetInstance()->current_test_info()->name();
    fs::create_directories(dir_);
  }

  Result cli(std::vector<std::string> args, std::chrono::seconds timeout = 60s) {
    args.insert(args.begin(), {kCli.string(), "--server", server_->address()});
    const std::string tag = "cli" + std::to_string(counter_++);
    Child child(args, dir_ / (tag + ".out"), dir_ / (tag + ".err"), false);
    Result r;
    r.code = child.wait(timeout);
    r.out = read_file(dir_ / (tag + ".out"));
    r.err = read_file(dir_ / (tag + ".err"));
    return r;
  }

  static fs::path root_;
  static ServerProcess* server_;
  fs::path dir_;
  int counter_ = 0;
};

fs::path CliJobsEndToEnd::root_;
ServerProcess* CliJobsEndToEnd::server_ = nullptr;

TEST_F(CliJobsEndToEnd, IsosurfaceTilesGivesAClosedMeshWithoutLowValence) {
  Result r = cli({"run", "isosurface", "--scene", (root_ / "sphere.json").string(), "--method", "tiles", "--cells",
                  "32", "-o", (dir_ / "tiles").string(), "--format", "ply"});
  ASSERT_EQ(r.code, 0) << r;
  const MeshReport tiles = expect_closed(dir_ / "tiles" / "frame_0000.ply");
  EXPECT_GE(tiles.min_valence, 5);
  EXPECT_NEAR(tiles.volume, 4.0 / 3.0 * M_PI * 0.125, 0.05 * 4.0 / 3.0 * M_PI * 0.125);

  r = cli({"run", "isosurface", "--scene", (root_ / "sphere.json").string(), "--method", "cubes", "--cells", "32", "-o",
           (dir_ / "cubes").string(), "--format", "ply"});
  ASSERT_EQ(r.code, 0) << r;
  EXPECT_LT(expect_closed(dir_ / "cubes" / "frame_0000.ply").min_valence, 5);  // Marching Cubes' valence-3/4
}

TEST_F(CliJobsEndToEnd, BadParticleFileExitsTwoNamingFileAndLineAndQueuesNoJob) {
  write_file(dir_ / "drop_0.xyz", particle_ball(Vec3(0, 0, 0), 0.2, 0.05, 3));
  write_file(dir_ / "drop_1.xyz", "0 0 0\n0.1 0.1 0.1\n0.2 zero 0.2\n");
  Result r = cli({"run", "particles", "--input", (dir_ / "drop_{}.xyz").string(), "--r-inner", "0.03", "--name",
                  "must-not-exist", "-o", (dir_ / "bad").string()});
  EXPECT_EQ(r.code, 2) << r;
  EXPECT_NE(r.err.find("surfacer: error: "), std::string::npos) << r;
  EXPECT_NE(r.err.find("drop_1.xyz"), std::string::npos) << r;
  EXPECT_NE(r.err.find("line 3"), std::string::npos) << r;
  Result list = cli({"list"});
  ASSERT_EQ(list.code, 0) << list;
  EXPECT_EQ(list.out.find("must-not-exist"), std::string::npos) << list;
  EXPECT_FALSE(fs::exists(dir_ / "bad" / "frame_0000.drc"));
}

}  // namespace
}  // namespace surfacer::client
