// End to end with real processes: a `surfacer-server` child on a loopback port (or the CLI's in-process server)
// and the `surfacer` binary, checked through exit codes, files and Debian's draco_decoder.
#include <gtest/gtest.h>
#include <signal.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <sstream>
#include <thread>

#include "core/mesh/mesh_checks.h"
#include "core/mesh/mesh_io.h"
#include "tests/support/files.h"
#include "tests/support/mesh_expectations.h"
#include "tests/support/process.h"
#include "tests/support/server_process.h"

namespace surfacer::client {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using namespace surfacer::testing;

constexpr const char* kSphere =
    R"({"name": "sphere", "root": {"sphere": {"center": {"x": 0, "y": 0, "z": 0}, "radius": 1}}})";
constexpr const char* kTorus = R"({"name": "torus", "root": {"torus": {"majorRadius": 1, "minorRadius": 0.35}}})";
constexpr const char* kBadRadius = R"({"name": "bad", "root": {"sphere": {"radius": -1}}})";

// One server for the whole suite (started in SetUpTestSuite, SIGTERM in TearDownTestSuite).
class CliEndToEnd : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    root_ = fresh_temp_dir("cli_e2e");
    write_file(root_ / "sphere.json", kSphere);
    write_file(root_ / "torus.json", kTorus);
    write_file(root_ / "bad_radius.json", kBadRadius);
    write_file(root_ / "malformed.json", R"({"root": {"sphere": {"radius": 1,,}}})");
    server_ = new ServerProcess(root_ / "server", 2, {"--drain-seconds", "1"});
    ASSERT_GT(server_->port(), 0) << "surfacer-server wrote no port file; its stderr:\n" << server_->log();
  }

  static void TearDownTestSuite() {
    if (server_ != nullptr) {
      EXPECT_EQ(server_->stop(), 0) << "surfacer-server did not shut down cleanly on SIGTERM";
      delete server_;
      server_ = nullptr;
    }
    fs::remove_all(root_);
  }

  void SetUp() override {
    ASSERT_TRUE(server_ != nullptr && server_->port() > 0);
    dir_ = current_test_dir(root_);
  }

  // Starts the CLI; `remote` prepends --server ADDRESS.
  std::unique_ptr<ChildProcess> spawn(std::vector<std::string> args, bool remote = true,
                                      const std::string& tag = "cli") {
    if (remote) args.insert(args.begin(), {"--server", server_->address()});
    args.insert(args.begin(), cli_binary().string());
    return std::make_unique<ChildProcess>(args, dir_ / (tag + ".out"), dir_ / (tag + ".err"));
  }
  ProcessResult cli(std::vector<std::string> args, bool remote = true, std::chrono::seconds timeout = 60s) {
    static int counter = 0;
    const std::string tag = "cli" + std::to_string(counter++);
    return finish(*spawn(std::move(args), remote, tag), timeout);
  }

  static fs::path root_;
  static ServerProcess* server_;
  fs::path dir_;
};

fs::path CliEndToEnd::root_;
ServerProcess* CliEndToEnd::server_ = nullptr;

// Every example scene gives a closed frame in the default file, a .glb of the Draco pieces, and in the standard .drc
// that Debian's draco_decoder reads.
TEST_F(CliEndToEnd, EveryExampleSceneGivesAClosedDracoFrame) {
  std::vector<fs::path> scenes;
  for (const auto& entry : fs::directory_iterator(fs::path(SURFACER_SOURCE_DIR) / "examples" / "scenes")) {
    if (entry.path().extension() == ".json") scenes.push_back(entry.path());
  }
  std::sort(scenes.begin(), scenes.end());
  ASSERT_FALSE(scenes.empty()) << "no examples/scenes/*.json";
  for (const auto& scene : scenes) {
    SCOPED_TRACE(scene.filename().string());
    const fs::path out = dir_ / scene.stem();
    ProcessResult r = cli({"run", "isosurface", "--scene", scene.string(), "-o", out.string(), "--cells", "48"});
    ASSERT_EQ(r.code, 0) << r;
    EXPECT_FALSE(fs::exists(out / "frame_0000.drc")) << r;
    EXPECT_TRUE(mesh_file_has(out / "frame_0000.glb", kClosed));
    EXPECT_NE(r.err.find("wrote 1 frame to " + out.string() + "/"), std::string::npos) << r;
    r = cli({"run", "isosurface", "--scene", scene.string(), "-o", out.string(), "--cells", "48", "--format", "drc"});
    ASSERT_EQ(r.code, 0) << r;
    const fs::path ply = out / "frame_0000_decoded.ply";
    ASSERT_TRUE(draco_decoder_decodes(out / "frame_0000.drc", ply));
    EXPECT_TRUE(mesh_file_has(ply, kClosed));
  }
}

TEST_F(CliEndToEnd, SequenceWritesOneFramePerSceneAndStatsRows) {
  ProcessResult r = cli({"run", "isosurface", "--scene", (root_ / "sphere.json").string(), "--scene",
                         (root_ / "torus.json").string(), "--cells", "40", "-o", (dir_ / "out").string()});
  ASSERT_EQ(r.code, 0) << r;
  EXPECT_TRUE(fs::exists(dir_ / "out" / "frame_0000.glb"));
  EXPECT_TRUE(fs::exists(dir_ / "out" / "frame_0001.glb"));
  const std::string csv = read_file(dir_ / "out" / "stats.csv");
  EXPECT_EQ(count_lines(csv), 3) << csv;  // header + 2 rows
  EXPECT_NE(csv.find("\n0,"), std::string::npos) << csv;
  EXPECT_NE(csv.find("\n1,"), std::string::npos) << csv;
  EXPECT_NE(r.err.find("frame 1/2: "), std::string::npos) << r;
  EXPECT_NE(r.err.find("closed"), std::string::npos) << r;
  EXPECT_NE(r.err.find("wrote 2 frames"), std::string::npos) << r;
}

TEST_F(CliEndToEnd, PlyAndObjFormatsAndRawLosslessPly) {
  ProcessResult r = cli({"run", "isosurface", "--scene", (root_ / "torus.json").string(), "--cells", "40", "-o",
                         (dir_ / "conv").string(), "--format", "ply,obj"});
  ASSERT_EQ(r.code, 0) << r;
  EXPECT_FALSE(fs::exists(dir_ / "conv" / "frame_0000.drc"));
  EXPECT_TRUE(mesh_file_has(dir_ / "conv" / "frame_0000.ply", kClosed));
  EXPECT_TRUE(mesh_file_has(dir_ / "conv" / "frame_0000.obj", kClosed));

  r = cli({"run", "isosurface", "--scene", (root_ / "torus.json").string(), "--cells", "40", "-o",
           (dir_ / "raw").string(), "--raw"});
  ASSERT_EQ(r.code, 0) << r;
  EXPECT_FALSE(fs::exists(dir_ / "raw" / "frame_0000.drc"));
  const std::string ply = read_file(dir_ / "raw" / "frame_0000.ply");
  EXPECT_NE(ply.find("property double x"), std::string::npos) << ply.substr(0, 300);
  EXPECT_TRUE(mesh_file_has(dir_ / "raw" / "frame_0000.ply", kClosed));
}

TEST_F(CliEndToEnd, RunWholeSpecFromJson) {
  write_file(dir_ / "job.json", std::string(R"({"name": "spec job", "output": {"encoding": "MESH_ENCODING_PLY"},
      "isosurface": {"cells": 32, "scenes": [)") +
                                    kSphere + "," + kTorus + "]}}");
  ProcessResult r =
      cli({"run", "--spec", (dir_ / "job.json").string(), "-o", (dir_ / "spec").string(), "--format", "obj"});
  ASSERT_EQ(r.code, 0) << r;
  EXPECT_TRUE(mesh_file_has(dir_ / "spec" / "frame_0000.obj", kClosed));
  EXPECT_TRUE(mesh_file_has(dir_ / "spec" / "frame_0001.obj", kClosed));
}

TEST_F(CliEndToEnd, SubmitThenWatchFromFrame) {
  const std::string sphere = (root_ / "sphere.json").string();
  ProcessResult s =
      cli({"submit", "isosurface", "--scene", sphere, "--scene", sphere, "--scene", sphere, "--cells", "32"});
  ASSERT_EQ(s.code, 0) << s;
  std::string id = s.out;
  while (!id.empty() && std::isspace(static_cast<unsigned char>(id.back()))) id.pop_back();
  ASSERT_FALSE(id.empty());
  ASSERT_EQ(id.find('\n'), std::string::npos) << "submit prints only the job id: " << s;

  ProcessResult w = cli({"watch", id, "--from-frame", "1", "-o", (dir_ / "w").string()});
  ASSERT_EQ(w.code, 0) << w;
  EXPECT_FALSE(fs::exists(dir_ / "w" / "frame_0000.glb"));
  EXPECT_TRUE(mesh_file_has(dir_ / "w" / "frame_0001.glb", kClosed));  // submit asks for what run asks for
  EXPECT_TRUE(mesh_file_has(dir_ / "w" / "frame_0002.glb", kClosed));
  EXPECT_EQ(count_lines(read_file(dir_ / "w" / "stats.csv")), 3);

  ProcessResult st = cli({"status", id});
  ASSERT_EQ(st.code, 0) << st;
  EXPECT_NE(st.out.find("SUCCEEDED"), std::string::npos) << st;
  EXPECT_NE(st.out.find("3/3"), std::string::npos) << st;

  ProcessResult ls = cli({"list", "--state", "succeeded"});
  ASSERT_EQ(ls.code, 0) << ls;
  EXPECT_NE(ls.out.find(id), std::string::npos) << ls;
}

TEST_F(CliEndToEnd, UnreachableServerExitsThree) {
  const std::string address = "127.0.0.1:" + std::to_string(free_port());
  ProcessResult r = cli({"--server", address, "--timeout", "1", "run", "isosurface", "--scene",
                         (root_ / "sphere.json").string(), "-o", (dir_ / "x").string()},
                        /*remote=*/false);
  EXPECT_EQ(r.code, 3) << r;
  EXPECT_NE(r.err.find("surfacer: error: "), std::string::npos) << r;
  EXPECT_NE(r.err.find(address), std::string::npos) << r;
}

TEST_F(CliEndToEnd, MalformedSceneExitsTwoNamingTheFile) {
  ProcessResult r =
      cli({"run", "isosurface", "--scene", (root_ / "malformed.json").string(), "-o", (dir_ / "x").string()});
  EXPECT_EQ(r.code, 2) << r;
  EXPECT_NE(r.err.find("surfacer: error: "), std::string::npos) << r;
  EXPECT_NE(r.err.find("malformed.json"), std::string::npos) << r;
  ProcessResult missing =
      cli({"run", "isosurface", "--scene", (root_ / "nope.json").string(), "-o", (dir_ / "x").string()});
  EXPECT_EQ(missing.code, 2) << missing;
  EXPECT_NE(missing.err.find("nope.json"), std::string::npos) << missing;
  ProcessResult flag = cli({"run", "isosurface", "--cells", "many"});
  EXPECT_EQ(flag.code, 2) << flag;
}

TEST_F(CliEndToEnd, RejectedJobExitsFourNamingTheField) {
  ProcessResult r =
      cli({"run", "isosurface", "--scene", (root_ / "bad_radius.json").string(), "-o", (dir_ / "x").string()});
  EXPECT_EQ(r.code, 4) << r;
  EXPECT_NE(r.err.find("INVALID_ARGUMENT"), std::string::npos) << r;
  EXPECT_NE(r.err.find("radius"), std::string::npos) << r;
}

// A job that runs for seconds: many frames at a fine resolution.
std::vector<std::string> long_job_args(const fs::path& scene, const fs::path& out, const std::string& name) {
  std::vector<std::string> args = {"run", "isosurface", "--cells", "160", "--name", name, "-o", out.string()};
  for (int i = 0; i < 40; ++i) {
    args.push_back("--scene");
    args.push_back(scene.string());
  }
  return args;
}

TEST_F(CliEndToEnd, CancelFromAnotherCommandMakesRunExitFive) {
  auto run = spawn(long_job_args(root_ / "torus.json", dir_ / "long", "cancel-me"), true, "run");
  std::string id;
  const auto deadline = std::chrono::steady_clock::now() + 20s;
  while (id.empty() && std::chrono::steady_clock::now() < deadline) {
    ProcessResult ls = cli({"list", "--state", "queued,running"});
    ASSERT_EQ(ls.code, 0) << ls;
    std::istringstream lines(ls.out);
    for (std::string line; std::getline(lines, line);) {
      if (line.find("cancel-me") != std::string::npos) id = line.substr(0, line.find(' '));
    }
    if (id.empty()) std::this_thread::sleep_for(100ms);
  }
  ASSERT_FALSE(id.empty()) << "the long job never showed up in `surfacer list`";
  ProcessResult c = cli({"cancel", id});
  EXPECT_EQ(c.code, 0) << c;
  const auto t0 = std::chrono::steady_clock::now();
  EXPECT_EQ(run->wait(20s), 5) << read_file(dir_ / "run.err");
  EXPECT_LT(std::chrono::steady_clock::now() - t0, 5s);
  ProcessResult st = cli({"status", id});
  EXPECT_NE(st.out.find("CANCELLED"), std::string::npos) << st;
}

TEST_F(CliEndToEnd, CtrlCDuringRunCancelsTheJobAndExitsFive) {
  auto run = spawn(long_job_args(root_ / "torus.json", dir_ / "long", "interrupt-me"), true, "run");
  const auto deadline = std::chrono::steady_clock::now() + 20s;
  while (read_file(dir_ / "run.err").find("submitted job") == std::string::npos &&
         std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(20ms);
  }
  const std::string err = read_file(dir_ / "run.err");
  ASSERT_NE(err.find("submitted job "), std::string::npos) << err;
  std::string id = err.substr(err.find("submitted job ") + 14);
  id = id.substr(0, id.find(' '));
  run->signal(SIGINT);
  EXPECT_EQ(run->wait(20s), 5) << read_file(dir_ / "run.err");
  ProcessResult st = cli({"status", id});
  EXPECT_NE(st.out.find("CANCELLED"), std::string::npos) << st;
}

TEST_F(CliEndToEnd, LocalModeWritesClosedMeshes) {
  ProcessResult r =
      cli({"run", "isosurface", "--scene", (root_ / "sphere.json").string(), "--scene", (root_ / "torus.json").string(),
           "--cells", "40", "-o", (dir_ / "local").string(), "--workers", "2"},
          /*remote=*/false);
  ASSERT_EQ(r.code, 0) << r;
  EXPECT_TRUE(mesh_file_has(dir_ / "local" / "frame_0000.glb", kClosed));
  EXPECT_TRUE(mesh_file_has(dir_ / "local" / "frame_0001.glb", kClosed));
  EXPECT_EQ(r.err.find("warning"), std::string::npos) << "run needs no in-process warning: " << r;

  ProcessResult list = cli({"list"}, /*remote=*/false);
  EXPECT_EQ(list.code, 0) << list;
  EXPECT_NE(list.err.find("warning: using an in-process server"), std::string::npos) << list;
}

TEST_F(CliEndToEnd, HealthPrintsServing) {
  ProcessResult r = cli({"health"});
  EXPECT_EQ(r.code, 0) << r;
  EXPECT_EQ(r.out, "SERVING\n") << r;
  ProcessResult local = cli({"health"}, /*remote=*/false);
  EXPECT_EQ(local.code, 0) << local;
  EXPECT_EQ(local.out, "SERVING\n") << local;
}

TEST_F(CliEndToEnd, HealthOfAnUnknownServicePrintsServiceUnknownAndExitsUnreachable) {
  ProcessResult r = cli({"health", "--service", "no.such.Service"});
  EXPECT_EQ(r.code, 3) << r;  // kUnreachable: not SERVING
  EXPECT_EQ(r.out, "SERVICE_UNKNOWN\n") << r;
  EXPECT_NE(r.err.find("not serving service \"no.such.Service\" (health: SERVICE_UNKNOWN)"), std::string::npos) << r;
}

// The frame encodings: whatever travels on the wire (one Draco mesh, Draco pieces, meshopt pieces), the files on
// disk are standard and hold the same surface on the job's quantization grid.
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

TEST_F(CliEndToEnd, EveryEncodingWritesTheSameSurfaceInStandardFiles) {
  const fs::path scenes = fs::path(SURFACER_SOURCE_DIR) / "examples" / "scenes";
  // From one piece to many (a piece holds up to 262144 triangles).
  for (const auto& [scene, cells] : std::vector<std::pair<std::string, std::string>>{
           {"torus.json", "24"}, {"csg_block.json", "96"}, {"gyroid_in_sphere.json", "140"}}) {
    SCOPED_TRACE(scene + " at " + cells + " cells");
    const std::vector<std::string> job = {"run", "isosurface", "--scene", (scenes / scene).string(), "--cells", cells};
    auto run = [&](const std::string& name, std::vector<std::string> extra) {
      std::vector<std::string> args = job;
      args.insert(args.end(), {"-o", (dir_ / name).string()});
      args.insert(args.end(), extra.begin(), extra.end());
      const ProcessResult r = cli(args, true, 120s);
      EXPECT_EQ(r.code, 0) << r;
      return dir_ / name;
    };
    // A .drc: one standard Draco mesh on the wire, written as received.
    const fs::path draco = run("draco", {"--format", "drc"});
    ASSERT_TRUE(draco_decoder_decodes(draco / "frame_0000.drc", draco / "decoded.ply"));
    const Surface reference = surface_of(draco / "decoded.ply");
    // The default: Draco pieces on the wire, written as a .glb as received.
    const fs::path glb = run("glb", {});
    EXPECT_FALSE(fs::exists(glb / "frame_0000.drc"));
    expect_same_surface(surface_of(glb / "frame_0000.glb"), reference, "the default .glb");
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

TEST_F(CliEndToEnd, WatchWritesAStandardDracoFileOfAPiecedJob) {
  const fs::path scene = fs::path(SURFACER_SOURCE_DIR) / "examples" / "scenes" / "gyroid_in_sphere.json";
  write_file(dir_ / "job.json", R"({"output": {"encoding": "MESH_ENCODING_DRACO_PIECES"},
      "isosurface": {"cells": 120, "method": "POLYGONIZER_CUBES", "scenes": [)" +
                                    read_file(scene) + "]}}");
  const ProcessResult submitted = cli({"submit", "--spec", (dir_ / "job.json").string()});
  ASSERT_EQ(submitted.code, 0) << submitted;
  const std::string id = submitted.out.substr(0, submitted.out.find('\n'));
  const ProcessResult watched = cli({"watch", id, "-o", (dir_ / "watched").string(), "--format", "drc"});
  ASSERT_EQ(watched.code, 0) << watched;
  ASSERT_TRUE(draco_decoder_decodes(dir_ / "watched" / "frame_0000.drc", dir_ / "watched" / "decoded.ply"));
  EXPECT_TRUE(mesh_file_has(dir_ / "watched" / "decoded.ply", kClosedManifold));
}

TEST_F(CliEndToEnd, RawAndAnotherEncodingIsAUsageError) {
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
