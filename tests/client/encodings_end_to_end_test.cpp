// The frame encodings end to end: the `surfacer` binary against a `surfacer-server` child, files checked with
// Debian's draco_decoder. Whatever travels on the wire (one Draco mesh, Draco pieces, meshopt pieces), the files on
// disk are standard and hold the same surface on the job's quantization grid.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>

#include "core/mesh/mesh_checks.h"
#include "core/mesh/mesh_io.h"
#include "tests/support/files.h"
#include "tests/support/mesh_expectations.h"
#include "tests/support/process.h"
#include "tests/support/server_process.h"

namespace surfacer::client {
namespace {

namespace fs = std::filesystem;
using namespace surfacer::testing;

class Encodings : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    root_ = fresh_temp_dir("encodings_e2e");
    server_ = new ServerProcess(root_ / "server", 2);
    ASSERT_GT(server_->port(), 0) << server_->log();
  }
  static void TearDownTestSuite() {
    if (server_ != nullptr) {
      EXPECT_EQ(server_->stop(), 0);
      delete server_;
      server_ = nullptr;
    }
    fs::remove_all(root_);
  }
  void SetUp() override { dir_ = current_test_dir(root_); }

  ProcessResult cli(std::vector<std::string> args) {
    args.insert(args.begin(), {cli_binary().string(), "--server", server_->address()});
    const std::string tag = "cli" + std::to_string(counter_++);
    ChildProcess child(args, dir_ / (tag + ".out"), dir_ / (tag + ".err"));
    return finish(child, std::chrono::seconds(120));
  }

  static fs::path root_;
  static ServerProcess* server_;
  fs::path dir_;
  int counter_ = 0;
};

fs::path Encodings::root_;
ServerProcess* Encodings::server_ = nullptr;

struct Surface {
  std::size_t vertices = 0, triangles = 0;
  MeshReport report;
};

Surface surface_of(const fs::path& file) {
  const Mesh m = read_mesh(file);
  return {m.vertices.size(), m.triangles.size(), check_mesh(m)};
}

void expect_same_surface(const Surface& a, const Surface& b, const std::string& what) {
  SCOPED_TRACE(what);
  EXPECT_EQ(a.vertices, b.vertices);
  EXPECT_EQ(a.triangles, b.triangles);
  EXPECT_EQ(a.report.euler_characteristic, b.report.euler_characteristic);
  EXPECT_EQ(a.report.components, b.report.components);
  EXPECT_EQ(a.report.valence_histogram, b.report.valence_histogram);
  EXPECT_TRUE(a.report.closed && b.report.closed && a.report.vertex_manifold && b.report.vertex_manifold);
  EXPECT_NEAR(a.report.volume, b.report.volume, 1e-6 * std::abs(b.report.volume));
}

TEST_F(Encodings, EveryEncodingWritesTheSameSurfaceInStandardFiles) {
  const fs::path scenes = fs::path(SURFACER_SOURCE_DIR) / "examples" / "scenes";
  // From one piece to many (a piece holds up to 131072 triangles).
  for (const auto& [scene, cells] : std::vector<std::pair<std::string, std::string>>{
           {"torus.json", "24"}, {"csg_block.json", "96"}, {"gyroid_in_sphere.json", "140"}}) {
    SCOPED_TRACE(scene + " at " + cells + " cells");
    const std::vector<std::string> job = {"run", "isosurface", "--scene", (scenes / scene).string(), "--cells", cells};
    auto run = [&](const std::string& name, std::vector<std::string> extra) {
      std::vector<std::string> args = job;
      args.insert(args.end(), {"-o", (dir_ / name).string()});
      args.insert(args.end(), extra.begin(), extra.end());
      const ProcessResult r = cli(args);
      EXPECT_EQ(r.code, 0) << r;
      return dir_ / name;
    };
    // The default: one standard Draco mesh on the wire, written as received.
    const fs::path draco = run("draco", {});
    ASSERT_TRUE(draco_decoder_decodes(draco / "frame_0000.drc", draco / "decoded.ply"));
    const Surface reference = surface_of(draco / "decoded.ply");
    // No .drc asked for: Draco pieces on the wire, welded here.
    const fs::path pieces = run("pieces", {"--format", "ply,obj"});
    EXPECT_FALSE(fs::exists(pieces / "frame_0000.drc"));
    expect_same_surface(surface_of(pieces / "frame_0000.ply"), reference, "Draco pieces as PLY");
    expect_same_surface(surface_of(pieces / "frame_0000.obj"), reference, "Draco pieces as OBJ");
    // meshopt: PLY by default; as .drc, standard Draco on the job's grid.
    const fs::path meshopt = run("meshopt", {"--encoding", "meshopt"});
    expect_same_surface(surface_of(meshopt / "frame_0000.ply"), reference, "meshopt as PLY");
    const fs::path meshopt_drc = run("meshopt_drc", {"--encoding", "meshopt", "--format", "drc"});
    ASSERT_TRUE(draco_decoder_decodes(meshopt_drc / "frame_0000.drc", meshopt_drc / "decoded.ply"));
    expect_same_surface(surface_of(meshopt_drc / "decoded.ply"), reference, "meshopt as .drc");
  }
}

TEST_F(Encodings, WatchWritesAStandardDracoFileOfAPiecedJob) {
  const fs::path scene = fs::path(SURFACER_SOURCE_DIR) / "examples" / "scenes" / "gyroid_in_sphere.json";
  write_file(dir_ / "job.json", R"({"output": {"encoding": "MESH_ENCODING_DRACO_PIECES"},
      "isosurface": {"cells": 120, "method": "POLYGONIZER_CUBES", "scenes": [)" +
                                    read_file(scene) + "]}}");
  const ProcessResult submitted = cli({"submit", "--spec", (dir_ / "job.json").string()});
  ASSERT_EQ(submitted.code, 0) << submitted;
  const std::string id = submitted.out.substr(0, submitted.out.find('\n'));
  const ProcessResult watched = cli({"watch", id, "-o", (dir_ / "watched").string()});
  ASSERT_EQ(watched.code, 0) << watched;
  ASSERT_TRUE(draco_decoder_decodes(dir_ / "watched" / "frame_0000.drc", dir_ / "watched" / "decoded.ply"));
  EXPECT_TRUE(mesh_file_has(dir_ / "watched" / "decoded.ply", kClosedManifold));
}

TEST_F(Encodings, RawAndAnotherEncodingIsAUsageError) {
  for (const std::vector<std::string>& extra :
       {std::vector<std::string>{"--raw", "--encoding", "meshopt"}, std::vector<std::string>{"--encoding", "zstd"},
        std::vector<std::string>{"--raw", "--quantization-bits", "12"}}) {
    std::vector<std::string> args = {"run", "isosurface", "--scene", "s.json", "-o", (dir_ / "x").string()};
    args.insert(args.end(), extra.begin(), extra.end());
    const ProcessResult r = cli(args);
    EXPECT_EQ(r.code, 2) << r;
  }
}

}  // namespace
}  // namespace surfacer::client
