// End to end for the job types beyond isosurface: a `surfacer-server` child on a loopback port and the `surfacer`
// binary, with inputs generated here (particle files, scenes), checked through exit codes, files and mesh checks.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <random>
#include <sstream>

#include "core/mesh/mesh_io.h"
#include "tests/support/cli_server_test.h"
#include "tests/support/files.h"
#include "tests/support/mesh_expectations.h"
#include "tests/support/process.h"
#include "tests/support/server_process.h"
#include "tests/support/test_meshes.h"

namespace surfacer::client {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using namespace surfacer::testing;

constexpr const char* kSphere = R"({"name": "sphere", "root": {"sphere": {"radius": 0.5}}})";
constexpr const char* kCube = R"({"name": "cube", "root": {"box": {"half_size": {"x": 0.5, "y": 0.5, "z": 0.5}}}})";
constexpr const char* kSmallBox = R"({"name": "box", "root": {"box": {"half_size": {"x": 0.4, "y": 0.3, "z": 0.3}}}})";

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

// What every mesh the CLI writes here must be.
constexpr unsigned kClosedFrame = kClosed | kEdgeManifold | kVertexManifold;

std::vector<std::vector<std::string>> csv_rows(const std::string& text) {
  std::vector<std::vector<std::string>> rows;
  std::istringstream lines(text);
  for (std::string line; std::getline(lines, line);) {
    std::vector<std::string> cells;
    std::size_t pos = 0;
    while (true) {
      const std::size_t comma = line.find(',', pos);
      cells.push_back(line.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos));
      if (comma == std::string::npos) break;
      pos = comma + 1;
    }
    rows.push_back(cells);
  }
  return rows;
}

int column(const std::vector<std::string>& header, const std::string& name) {
  const auto it = std::find(header.begin(), header.end(), name);
  return it == header.end() ? -1 : static_cast<int>(it - header.begin());
}

class CliJobsEndToEnd : public CliServerTest<CliJobsEndToEnd> {
 public:
  static constexpr const char* kName = "cli_jobs_e2e";
  static std::vector<std::string> server_flags() { return {"--drain-seconds", "1"}; }
  static void write_inputs(const fs::path& root) {
    write_file(root / "sphere.json", kSphere);
    write_file(root / "cube.json", kCube);
    write_file(root / "box.json", kSmallBox);
  }
};

TEST_F(CliJobsEndToEnd, IsosurfaceTilesGivesAClosedMeshWithoutLowValence) {
  ProcessResult r = cli({"run", "isosurface", "--scene", (root_ / "sphere.json").string(), "--method", "tiles",
                         "--cells", "32", "-o", (dir_ / "tiles").string(), "--format", "ply"});
  ASSERT_EQ(r.code, 0) << r;
  MeshReport tiles;
  EXPECT_TRUE(mesh_file_has(dir_ / "tiles" / "frame_0000.ply", kClosedFrame, &tiles));
  EXPECT_GE(tiles.min_valence, 5);
  EXPECT_NEAR(tiles.volume, sphere_volume(0.5), 0.05 * sphere_volume(0.5));

  r = cli({"run", "isosurface", "--scene", (root_ / "sphere.json").string(), "--method", "cubes", "--cells", "32", "-o",
           (dir_ / "cubes").string(), "--format", "ply"});
  ASSERT_EQ(r.code, 0) << r;
  MeshReport cubes;
  EXPECT_TRUE(mesh_file_has(dir_ / "cubes" / "frame_0000.ply", kClosedFrame, &cubes));
  EXPECT_LT(cubes.min_valence, 5);  // Marching Cubes' valence-3/4
}

TEST_F(CliJobsEndToEnd, ParticlesBlobGivesAClosedMeshAndASummaryTable) {
  const std::string blob = particle_ball(Vec3(0, 0, 0), 0.4, 0.05, 1);
  write_file(dir_ / "blob.xyz", blob);
  const auto particles = std::count(blob.begin(), blob.end(), '\n') - 1;
  ProcessResult r = cli({"run", "particles", "--input", (dir_ / "blob.xyz").string(), "--r-inner", "0.03", "-o",
                         (dir_ / "out").string(), "--format", "ply"});
  ASSERT_EQ(r.code, 0) << r;
  const Mesh mesh = read_mesh(dir_ / "out" / "frame_0000.ply");
  EXPECT_TRUE(mesh_file_has(dir_ / "out" / "frame_0000.ply", kClosedFrame));
  // Faithful: every vertex lies near the blob's boundary (radius 0.4 plus r_inner..r_outer).
  for (const Vec3& v : mesh.vertices) {
    ASSERT_GT(v.norm(), 0.4 - 0.05) << v.transpose();
    ASSERT_LT(v.norm(), 0.4 + 0.06 + 0.02) << v.transpose();
  }
  EXPECT_NE(r.err.find("uploaded 1/1: particle frame 0"), std::string::npos) << r;
  EXPECT_NE(r.err.find("frame  particles  triangles  seconds"), std::string::npos) << r;
  EXPECT_NE(r.err.find(std::to_string(particles)), std::string::npos) << r;
  EXPECT_NE(r.err.find("1 frame, "), std::string::npos) << r;
}

TEST_F(CliJobsEndToEnd, ParticleSequenceByPatternWritesFramesInOrder) {
  for (int i = 0; i < 3; ++i) {
    char name[32];
    std::snprintf(name, sizeof name, "fluid_%04d.xyz", i + 7);
    write_file(dir_ / name, particle_ball(Vec3(i, 0, 0), 0.25, 0.05, 10 + i));
  }
  ProcessResult r = cli({"run", "particles", "--input", (dir_ / "fluid_{:04d}.xyz").string(), "--r-inner", "0.03", "-o",
                         (dir_ / "seq").string(), "--format", "ply"});
  ASSERT_EQ(r.code, 0) << r;
  // The files keep the inputs' frame numbers (7, 8, 9).
  for (int i = 0; i < 3; ++i) {
    const fs::path frame = dir_ / "seq" / ("frame_000" + std::to_string(i + 7) + ".ply");
    ASSERT_TRUE(fs::exists(frame)) << frame << "\n" << r;
    EXPECT_TRUE(mesh_file_has(frame, kClosedFrame));
    EXPECT_NEAR(centroid(read_mesh(frame)).x(), i, 0.05) << "frame " << i << " is not the " << i << "-th file";
  }
  EXPECT_FALSE(fs::exists(dir_ / "seq" / "frame_0000.ply"));
  EXPECT_FALSE(fs::exists(dir_ / "seq" / "frame_0010.ply"));
  EXPECT_EQ(csv_rows(read_file(dir_ / "seq" / "stats.csv")).size(), 4u);
  EXPECT_NE(r.err.find("3 frames, "), std::string::npos) << r;
}

// `run` sends a particle sequence as an open one: the job is queued with its first frame, and the others join it as
// they are uploaded (the server's log has the job submitted with one frame); the frames are the whole sequence's.
TEST_F(CliJobsEndToEnd, ParticleSequenceJoinsTheJobFrameByFrame) {
  for (int i = 0; i < 4; ++i) {
    write_file(dir_ / ("drop_" + std::to_string(i) + ".xyz"), particle_ball(Vec3(0.1 * i, 0, 0), 0.2, 0.05, 20 + i));
  }
  ProcessResult r = cli({"run", "particles", "--input", (dir_ / "drop_{}.xyz").string(), "--r-inner", "0.03", "-o",
                         (dir_ / "open").string(), "--format", "ply"});
  ASSERT_EQ(r.code, 0) << r;
  EXPECT_NE(r.err.find("(4 frames, the rest uploaded while it runs)"), std::string::npos) << r;
  const std::size_t at = r.err.find("submitted job ");
  ASSERT_NE(at, std::string::npos) << r;
  const std::string id = r.err.substr(at + 14, r.err.find(' ', at + 14) - at - 14);
  const std::string log = server_->log();
  const std::size_t submitted = log.find("event=job_submitted job=" + id);
  ASSERT_NE(submitted, std::string::npos) << id << "\n" << log;
  EXPECT_NE(log.substr(submitted, log.find('\n', submitted) - submitted).find("frames=1"), std::string::npos) << log;
  for (int i = 0; i < 4; ++i) {
    const fs::path frame = dir_ / "open" / ("frame_000" + std::to_string(i) + ".ply");
    ASSERT_TRUE(fs::exists(frame)) << frame << "\n" << r;
    EXPECT_TRUE(mesh_file_has(frame, kClosedFrame));
    EXPECT_NEAR(centroid(read_mesh(frame)).x(), 0.1 * i, 0.02) << "frame " << i;
  }
}

TEST_F(CliJobsEndToEnd, BadParticleFileExitsTwoNamingFileAndLineAndQueuesNoJob) {
  write_file(dir_ / "drop_0.xyz", particle_ball(Vec3(0, 0, 0), 0.2, 0.05, 3));
  write_file(dir_ / "drop_1.xyz", "0 0 0\n0.1 0.1 0.1\n0.2 zero 0.2\n");
  ProcessResult r = cli({"run", "particles", "--input", (dir_ / "drop_{}.xyz").string(), "--r-inner", "0.03", "--name",
                         "must-not-exist", "-o", (dir_ / "bad").string()});
  EXPECT_EQ(r.code, 2) << r;
  EXPECT_NE(r.err.find("surfacer: error: "), std::string::npos) << r;
  EXPECT_NE(r.err.find("drop_1.xyz"), std::string::npos) << r;
  EXPECT_NE(r.err.find("line 3"), std::string::npos) << r;
  ProcessResult list = cli({"list"});
  ASSERT_EQ(list.code, 0) << list;
  EXPECT_EQ(list.out.find("must-not-exist"), std::string::npos) << list;
  EXPECT_FALSE(fs::exists(dir_ / "bad" / "frame_0000.drc"));
}

TEST_F(CliJobsEndToEnd, OptimizeWritesSnapshotsAndIterationsCsvWithFallingError) {
  ProcessResult r =
      cli({"run", "optimize", "--scene", (root_ / "cube.json").string(), "--start-cells", "24", "--iterations", "20",
           "--snapshot-every", "5", "-o", (dir_ / "opt").string(), "--format", "ply"});
  ASSERT_EQ(r.code, 0) << r;
  const auto rows = csv_rows(read_file(dir_ / "opt" / "iterations.csv"));
  ASSERT_GE(rows.size(), 3u) << read_file(dir_ / "opt" / "iterations.csv");
  const auto& header = rows[0];
  ASSERT_EQ(header[0], "frame");
  ASSERT_EQ(header[1], "iteration");
  ASSERT_EQ(header[2], "triangles");
  const int e_d = column(header, "e_d");
  ASSERT_GE(e_d, 0) << "no e_d column";
  EXPECT_GE(column(header, "max_distance"), 0);
  EXPECT_TRUE(std::is_sorted(header.begin() + 3, header.end()));
  int last_iteration = -1;
  for (std::size_t i = 1; i < rows.size(); ++i) {
    EXPECT_EQ(rows[i][0], std::to_string(i - 1));
    const int iteration = std::stoi(rows[i][1]);
    EXPECT_GT(iteration, last_iteration) << "row " << i;
    last_iteration = iteration;
    const fs::path frame = dir_ / "opt" / ("frame_000" + std::to_string(i - 1) + ".ply");
    ASSERT_TRUE(fs::exists(frame)) << frame;
  }
  EXPECT_EQ(last_iteration, 20);
  // The start (snapshot 0, Marching Cubes of the cube) has its vertices on the faces but chamfered edges: the flows
  // first pull vertices onto the edges, then E_d falls from snapshot to snapshot while E_n falls throughout.
  const int e_n = column(header, "e_n");
  for (std::size_t i = 3; i < rows.size(); ++i) {
    EXPECT_LT(std::stod(rows[i][e_d]), std::stod(rows[i - 1][e_d])) << "E_d did not fall at row " << i;
  }
  EXPECT_LT(std::stod(rows.back()[e_n]), std::stod(rows[1][e_n]) / 10) << "E_n did not fall 10x";
  EXPECT_TRUE(mesh_file_has(dir_ / "opt" / ("frame_000" + std::to_string(rows.size() - 2) + ".ply"), kClosedFrame));
  EXPECT_NE(r.err.find("iterations.csv"), std::string::npos) << r;
}

// From a lossless PLY, and from the .glb the CLI writes (Draco pieces, read back welded through their seam tags).
TEST_F(CliJobsEndToEnd, OptimizeFromAnUploadedStartMesh) {
  ProcessResult start = cli({"run", "isosurface", "--scene", (root_ / "sphere.json").string(), "--method", "cubes",
                             "--cells", "20", "--raw", "--format", "ply,glb", "-o", (dir_ / "start").string()});
  ASSERT_EQ(start.code, 0) << start;
  for (const char* format : {"ply", "glb"}) {
    SCOPED_TRACE(format);
    const fs::path out = dir_ / (std::string("opt_") + format);
    ProcessResult r = cli({"run", "optimize", "--scene", (root_ / "cube.json").string(), "--start-mesh",
                           (dir_ / "start" / (std::string("frame_0000.") + format)).string(), "--iterations", "10",
                           "-o", out.string(), "--format", "ply"});
    ASSERT_EQ(r.code, 0) << r;
    EXPECT_NE(r.err.find("uploaded 1/1: start mesh"), std::string::npos) << r;
    const auto rows = csv_rows(read_file(out / "iterations.csv"));
    ASSERT_GE(rows.size(), 2u);
    EXPECT_TRUE(mesh_file_has(out / "frame_0000.ply", kClosedFrame));  // the start mesh as the server read it
    const fs::path last = out / ("frame_000" + std::to_string(rows.size() - 2) + ".ply");
    EXPECT_TRUE(mesh_file_has(last, kClosedFrame));
    // Pulled from the sphere (radius 0.5) toward the cube (corners at 0.87 from the centre).
    double max_norm = 0;
    for (const Vec3& v : read_mesh(last).vertices) max_norm = std::max(max_norm, v.norm());
    EXPECT_GT(max_norm, 0.55);
  }
}

// The CLI validates a --start-mesh before uploading it: a ~140-byte Draco file declaring 200 M triangles took it to
// 4.8 GB. It now exits 2 naming the flag and the file, without the memory.
TEST_F(CliJobsEndToEnd, DracoBombStartMeshExitsTwoWithoutTheMemory) {
  write_file(dir_ / "bomb.drc", draco_bomb(200'000'000));
  ProcessResult r = cli({"run", "optimize", "--scene", (root_ / "cube.json").string(), "--start-mesh",
                         (dir_ / "bomb.drc").string(), "-o", (dir_ / "opt").string()});
  EXPECT_EQ(r.code, 2) << r;
  EXPECT_NE(r.err.find("--start-mesh: " + (dir_ / "bomb.drc").string()), std::string::npos) << r;
  EXPECT_NE(r.err.find("it declares far more elements than it holds"), std::string::npos) << r;
  EXPECT_GT(r.peak_rss_bytes, 0u);
  EXPECT_LT(r.peak_rss_bytes, std::uint64_t{256} << 20) << "peak RSS " << (r.peak_rss_bytes >> 20) << " MiB";
}

// `run active advect --delta` used to give the same bytes as without it: the control terms now act on top of the
// advection (the volume the scheme loses is held), and --alpha, which has no target to track there, is refused.
TEST_F(CliJobsEndToEnd, ActiveAdvectAppliesTheControlTermsAndRefusesAlpha) {
  write_file(dir_ / "ball.json",
             R"({"root": {"sphere": {"center": {"x": 0.35, "y": 0.35, "z": 0.35}, "radius": 0.15}}})");
  auto advect = [&](const std::string& out, std::vector<std::string> extra) {
    std::vector<std::string> args = {"run",
                                     "active",
                                     "advect",
                                     "--scene",
                                     (dir_ / "ball.json").string(),
                                     "--enright",
                                     "--frame-interval",
                                     "0.25",
                                     "--frames",
                                     "3",
                                     "--grid-spacing",
                                     "0.03125",
                                     "-o",
                                     (dir_ / out).string(),
                                     "--format",
                                     "ply"};
    args.insert(args.end(), extra.begin(), extra.end());
    return cli(args);
  };
  auto last_volume_change = [&](const std::string& out) {
    const auto rows = csv_rows(read_file(dir_ / out / "stats.csv"));
    const int volume = column(rows.at(0), "metric_volume");
    EXPECT_GE(volume, 0);
    return std::stod(rows.back().at(volume)) / std::stod(rows.at(1).at(volume)) - 1.0;
  };
  ProcessResult r = advect("plain", {});
  ASSERT_EQ(r.code, 0) << r;
  r = advect("held", {"--delta", "3"});
  ASSERT_EQ(r.code, 0) << r;
  EXPECT_NE(read_file(dir_ / "plain" / "frame_0003.ply"), read_file(dir_ / "held" / "frame_0003.ply"));
  const double plain = last_volume_change("plain"), held = last_volume_change("held");
  EXPECT_LT(plain, -0.1);
  EXPECT_LT(std::abs(held), 0.2 * std::abs(plain)) << "plain " << plain << ", --delta 3 " << held;

  r = advect("alpha", {"--alpha", "1"});
  EXPECT_EQ(r.code, 2) << r;  // the server's own check, run by the CLI before anything is submitted
  EXPECT_NE(r.err.find("spec.active.alpha"), std::string::npos) << r;
}

TEST_F(CliJobsEndToEnd, ActiveMorphWritesClosedFramesWithMetrics) {
  ProcessResult r = cli({"run", "active", "morph", "--from", (root_ / "sphere.json").string(), "--to",
                         (root_ / "box.json").string(), "--grid-spacing", "0.05", "--max-frames", "4",
                         "--bounds=-1,-1,-1,1,1,1", "-o", (dir_ / "morph").string(), "--format", "ply"});
  ASSERT_EQ(r.code, 0) << r;
  ASSERT_TRUE(fs::exists(dir_ / "morph" / "frame_0000.ply")) << r;
  const auto rows = csv_rows(read_file(dir_ / "morph" / "stats.csv"));
  ASSERT_GE(rows.size(), 3u);
  ASSERT_LE(rows.size(), 5u);  // --max-frames 4
  EXPECT_GE(column(rows[0], "active_nodes"), 0) << read_file(dir_ / "morph" / "stats.csv");
  // The engine's "volume" metric sits beside the mesh check's volume column, so it is named metric_volume; it falls
  // from the sphere's (0.52) toward the box's (0.29).
  const int volume = column(rows[0], "metric_volume");
  ASSERT_GE(volume, 0) << read_file(dir_ / "morph" / "stats.csv");
  EXPECT_LT(std::stod(rows.back()[volume]), std::stod(rows[1][volume]));
  EXPECT_GT(std::stod(rows.back()[volume]), 0.29);
  for (std::size_t i = 1; i < rows.size(); ++i) {
    EXPECT_TRUE(mesh_file_has(dir_ / "morph" / ("frame_000" + std::to_string(i - 1) + ".ply"), kClosedFrame));
  }
}

TEST_F(CliJobsEndToEnd, ActiveCoatFollowsAParticleSequence) {
  for (int i = 0; i < 2; ++i) {
    write_file(dir_ / ("coat_" + std::to_string(i) + ".xyz"), particle_ball(Vec3(0.02 * i, 0, 0), 0.3, 0.05, 20 + i));
  }
  ProcessResult r = cli({"run", "active", "coat", "--input", (dir_ / "coat_{}.xyz").string(), "--kernel-radius", "0.1",
                         "--grid-spacing", "0.03", "-o", (dir_ / "coat").string(), "--format", "ply"});
  ASSERT_EQ(r.code, 0) << r;
  EXPECT_NE(r.err.find("uploaded 2/2: particle frame 1"), std::string::npos) << r;
  for (int i = 0; i < 2; ++i) {
    const fs::path frame = dir_ / "coat" / ("frame_000" + std::to_string(i) + ".ply");
    EXPECT_TRUE(mesh_file_has(frame, kClosedFrame));
    EXPECT_NEAR(centroid(read_mesh(frame)).x(), 0.02 * i, 0.02) << frame;
  }
}

TEST_F(CliJobsEndToEnd, ActiveAdvectEnrightWritesEveryFrame) {
  write_file(dir_ / "enright.json",
             R"({"root": {"sphere": {"center": {"x": 0.35, "y": 0.35, "z": 0.35}, "radius": 0.15}}})");
  ProcessResult r = cli({"run", "active", "advect", "--scene", (dir_ / "enright.json").string(), "--enright",
                         "--period", "3", "--frame-interval", "0.1", "--frames", "2", "--grid-spacing", "0.03", "-o",
                         (dir_ / "advect").string(), "--format", "ply"});
  ASSERT_EQ(r.code, 0) << r;
  const auto rows = csv_rows(read_file(dir_ / "advect" / "stats.csv"));
  ASSERT_GE(rows.size(), 3u) << r;  // the start and 2 frames at least
  for (std::size_t i = 1; i < rows.size(); ++i) {
    EXPECT_TRUE(mesh_file_has(dir_ / "advect" / ("frame_000" + std::to_string(i - 1) + ".ply"), kClosedFrame));
  }
}

// An uploaded velocity grid: a uniform wind (0.2, 0, 0) carries the ball 0.05 per frame of 0.25.
TEST_F(CliJobsEndToEnd, ActiveAdvectByAnUploadedVelocityGrid) {
  std::string grid;
  const float wind[3] = {0.2f, 0.0f, 0.0f};
  for (int node = 0; node < 11 * 11 * 11; ++node) grid.append(reinterpret_cast<const char*>(wind), sizeof wind);
  write_file(dir_ / "wind.raw", grid);
  write_file(dir_ / "ball.json", R"({"root": {"sphere": {"radius": 0.3}}})");
  ProcessResult r = cli({"run",
                         "active",
                         "advect",
                         "--scene",
                         (dir_ / "ball.json").string(),
                         "--velocity-grid",
                         (dir_ / "wind.raw").string(),
                         "--velocity-origin=-1,-1,-1",
                         "--velocity-spacing",
                         "0.2,0.2,0.2",
                         "--velocity-dims",
                         "11,11,11",
                         "--frame-interval",
                         "0.25",
                         "--frames",
                         "2",
                         "--grid-spacing",
                         "0.04",
                         "-o",
                         (dir_ / "wind").string(),
                         "--format",
                         "ply"});
  ASSERT_EQ(r.code, 0) << r;
  EXPECT_NE(r.err.find("uploaded 1/1: velocity grid"), std::string::npos) << r;
  const double x0 = centroid(read_mesh(dir_ / "wind" / "frame_0000.ply")).x();
  const fs::path last = dir_ / "wind" / "frame_0002.ply";
  ASSERT_TRUE(fs::exists(last)) << r;
  EXPECT_TRUE(mesh_file_has(last, kClosedFrame));
  EXPECT_NEAR(centroid(read_mesh(last)).x() - x0, 0.1, 0.02);
}

// submit prints only the job id (uploads are reported on stderr); watch writes the frames and the summary table.
TEST_F(CliJobsEndToEnd, SubmitParticlesThenWatch) {
  write_file(dir_ / "drop.xyz", particle_ball(Vec3(0, 0, 0), 0.25, 0.05, 7));
  ProcessResult s = cli({"submit", "particles", "--input", (dir_ / "drop.xyz").string(), "--r-inner", "0.03"});
  ASSERT_EQ(s.code, 0) << s;
  std::string id = s.out;
  while (!id.empty() && std::isspace(static_cast<unsigned char>(id.back()))) id.pop_back();
  ASSERT_EQ(id.rfind("j-", 0), 0u) << s;
  ASSERT_EQ(id.find('\n'), std::string::npos) << "submit prints only the job id: " << s;
  EXPECT_NE(s.err.find("uploaded 1/1: particle frame 0"), std::string::npos) << s;
  ProcessResult w = cli({"watch", id, "-o", (dir_ / "w").string()});
  ASSERT_EQ(w.code, 0) << w;
  EXPECT_TRUE(mesh_file_has(dir_ / "w" / "frame_0000.glb", kClosedFrame));
  EXPECT_NE(w.err.find("frame  particles  triangles  seconds"), std::string::npos) << w;
}

}  // namespace
}  // namespace surfacer::client
