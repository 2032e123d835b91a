// Machine-readable runs and pictures, end to end: the `surfacer` binary against a `surfacer-server` child. JSON
// outputs (--json documents, --progress json lines) are read back by Python's json module; PNGs are decoded by
// stb_image and must show the mesh where it projects and the background elsewhere. Also --version on both
// binaries, the server's surfacer_build_info metric on its logged metrics port, and the job_finished log line.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <filesystem>
#include <regex>
#include <string>

#include "core/mesh/mesh_codec.h"
#include "core/mesh/mesh_io.h"
#include "core/util/format.h"
#include "core/util/version.h"
#include "tests/support/cli_server_test.h"
#include "tests/support/files.h"
#include "tests/support/json_check.h"
#include "tests/support/process.h"
#include "tests/support/test_meshes.h"

namespace surfacer::client {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using namespace surfacer::testing;

const Rgb kBackground{255, 255, 255};

bool centre_shaded_corners_background(const Image& image) {
  const int w = image.width, h = image.height;
  if (w == 0) return false;
  return image.at(w / 2, h / 2) != kBackground && image.at(0, 0) == kBackground && image.at(w - 1, 0) == kBackground &&
         image.at(0, h - 1) == kBackground && image.at(w - 1, h - 1) == kBackground;
}

// GET http://127.0.0.1:port/metrics, the body ("" on failure).
std::string get_metrics(int port) {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<std::uint16_t>(port));
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  std::string response;
  if (connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0) {
    const std::string request = "GET /metrics HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n";
    if (write(fd, request.data(), request.size()) == static_cast<ssize_t>(request.size())) {
      char buf[4096];
      for (ssize_t n; (n = read(fd, buf, sizeof buf)) > 0;) response.append(buf, static_cast<std::size_t>(n));
    }
  }
  close(fd);
  return response;
}

class RunReportEndToEnd : public CliServerTest<RunReportEndToEnd> {
 public:
  static constexpr const char* kName = "run_report_e2e";
  static std::vector<std::string> server_flags() { return {"--drain-seconds", "1", "--metrics-listen", "127.0.0.1:0"}; }
  static void write_inputs(const fs::path& root) {
    write_file(root / "sphere.json", R"({"name": "sphere", "root": {"sphere": {"radius": 0.5}}})");
    write_file(root / "moved.json", R"({"name": "moved", "root": {"transform": {"translate": {"x": 1.5},
                   "child": {"sphere": {"radius": 0.5}}}}})");
    write_file(root / "bad.json", R"({"name": "bad", "root": {"sphere": {"radius": -1}}})");
  }
};

TEST_F(RunReportEndToEnd, RunWithJsonProgressSummaryAndPreviews) {
  const fs::path out = dir_ / "out";
  const ProcessResult r =
      cli({"run", "isosurface", "--scene", (root_ / "sphere.json").string(), "--scene", (root_ / "moved.json").string(),
           "--cells", "32", "-o", out.string(), "--format", "ply,drc", "--progress", "json", "--json", "--preview"});
  ASSERT_EQ(r.code, 0) << r;
  // stdout: one JSON document.
  EXPECT_EQ(python_json(r.out, "d['job']['state'], d['job']['kind'], d['job']['error'], d['frames_written']"),
            "('SUCCEEDED', 'isosurface', None, 2)");
  EXPECT_EQ(python_json(r.out,
                        "[f['index'] for f in d['frames']], [f['closed'] and f['manifold'] for f in "
                        "d['frames']]"),
            "([0, 1], [True, True])");
  EXPECT_EQ(python_json(r.out, "all(f['triangles'] > 100 and len(f['files']) == 2 for f in d['frames'])"), "True");
  EXPECT_EQ(python_json(r.out, "d['triangles'] == sum(f['triangles'] for f in d['frames']), d['wall_seconds'] > 0"),
            "(True, True)");
  // stderr: every line a JSON object with an event; both frames, state changes and progress among them.
  EXPECT_EQ(python_json(r.err, "all(isinstance(e, dict) and 'event' in e and 'time' in e for e in d)", true), "True");
  EXPECT_EQ(python_json(r.err, "sorted(e['frame']['index'] for e in d if e['event'] == 'frame')", true), "[0, 1]");
  EXPECT_EQ(python_json(r.err, "[e['state'] for e in d if e['event'] == 'state'][-1]", true), "SUCCEEDED");
  EXPECT_EQ(python_json(r.err,
                        "all(0 <= e['fraction'] <= 1 and 'eta_s' in e and 'stage' in e and 'frame' in e "
                        "for e in d if e['event'] == 'progress')",
                        true),
            "True");
  // Previews: one per frame, from one camera on both frames' bounds. The sphere at the origin is left of the moved
  // one; each picture shows its sphere and background in the corners.
  EXPECT_EQ(python_json(r.out, "[p.split('/')[-1] for p in d['previews']]"), "['frame_0000.png', 'frame_0001.png']");
  const Image first = read_png(out / "preview" / "frame_0000.png");
  const Image second = read_png(out / "preview" / "frame_0001.png");
  ASSERT_EQ(first.width, 480);
  ASSERT_EQ(first.height, 360);
  ASSERT_EQ(second.width, 480);
  const auto mean_x = [](const Image& image) {
    double sum = 0;
    int n = 0;
    for (int y = 0; y < image.height; ++y) {
      for (int x = 0; x < image.width; ++x) {
        if (image.at(x, y) != kBackground) {
          sum += x;
          ++n;
        }
      }
    }
    return n > 0 ? sum / n : -1.0;
  };
  EXPECT_GT(mean_x(first), 0);
  EXPECT_GT(mean_x(second), 0);
  EXPECT_NE(mean_x(first), mean_x(second));  // the camera did not follow the sphere
  for (const Image* image : {&first, &second}) {
    EXPECT_EQ(image->at(0, 0), kBackground);
    EXPECT_EQ(image->at(image->width - 1, image->height - 1), kBackground);
  }
  // The server logged the job's end with its frames and duration.
  const std::regex finished(
      "event=job_finished job=([^ ]+) kind=isosurface state=JOB_STATE_SUCCEEDED frames=2 "
      "frames_total=2 duration_s=[0-9]+\\.[0-9]{3}");
  EXPECT_TRUE(std::regex_search(server_->log(), finished)) << server_->log();
}

TEST_F(RunReportEndToEnd, ARejectedRunEndsWithAJsonErrorLine) {
  const ProcessResult r = cli({"run", "isosurface", "--scene", (root_ / "bad.json").string(), "-o",
                               (dir_ / "out").string(), "--progress", "json", "--json"});
  ASSERT_EQ(r.code, 4) << r;
  EXPECT_EQ(python_json(r.err, "all('event' in e for e in d)", true), "True") << r;
  EXPECT_EQ(python_json(r.err, "d[-1]['event'], d[-1]['exit_code'], 'radius' in d[-1]['message']", true),
            "('error', 4, True)")
      << r;
}

TEST_F(RunReportEndToEnd, StatusAndListAsJson) {
  ProcessResult r = cli({"submit", "isosurface", "--scene", (root_ / "moved.json").string(), "--cells", "16", "--name",
                         "moved \"sphere\"\n"});
  ASSERT_EQ(r.code, 0) << r;
  const std::string id = std::string(trim(r.out));
  r = cli({"watch", id, "-o", (dir_ / "w").string(), "--json"});  // wait for it to finish
  ASSERT_EQ(r.code, 0) << r;
  EXPECT_EQ(python_json(r.out, "d['job']['id'], d['frames_written']"), "('" + id + "', 1)");

  r = cli({"status", id, "--json"});
  ASSERT_EQ(r.code, 0) << r;
  EXPECT_EQ(python_json(r.out, "d['job']['id'], d['job']['state'], d['job']['frames_done'], d['job']['frames_total']"),
            "('" + id + "', 'SUCCEEDED', 1, 1)");
  // A name with quotes and a newline survives the escaping.
  EXPECT_EQ(python_json(r.out, "d['job']['name'] == 'moved \"sphere\"\\n'"), "True") << r.out;
  EXPECT_EQ(python_json(r.out, "d['job']['finished'] is not None and d['job']['finished'].endswith('Z')"), "True");

  r = cli({"list", "--json"});
  ASSERT_EQ(r.code, 0) << r;
  EXPECT_EQ(python_json(r.out, "'" + id + "' in [j['id'] for j in d['jobs']]"), "True") << r.out;
  r = cli({"list", "--state", "failed", "--json"});
  ASSERT_EQ(r.code, 0) << r;
  EXPECT_EQ(python_json(r.out, "all(j['state'] == 'FAILED' for j in d['jobs'])"), "True") << r.out;
}

TEST_F(RunReportEndToEnd, VersionOnBothBinariesAndBuildInfoMetric) {
  const std::string version(build_version());
  ASSERT_FALSE(version.empty());
  for (const auto& [binary, name] :
       {std::pair{cli_binary(), "surfacer"}, std::pair{server_binary(), "surfacer-server"}}) {
    const ProcessResult r = run_process({binary.string(), "--version"}, dir_ / "v.out", dir_ / "v.err", 30s);
    EXPECT_EQ(r.code, 0) << r;
    EXPECT_EQ(r.out, std::string(name) + " " + version + "\n") << r;
  }
  // The server logs its bound metrics port (it was asked for port 0), and there the build_info gauge is 1.
  std::smatch match;
  const std::string log = server_->log();
  ASSERT_TRUE(std::regex_search(log, match, std::regex("event=server_started .*metrics_port=([0-9]+)"))) << log;
  const std::string metrics = get_metrics(std::stoi(match[1]));
  EXPECT_NE(metrics.find("\nsurfacer_build_info{version=\"" + version + "\"} 1\n"), std::string::npos) << metrics;
}

TEST_F(RunReportEndToEnd, PreviewCommandPicturesFramesParticlesAndTheOptimizePlot) {
  // The same sphere as each file format the CLI writes, pictured at several sizes.
  const Mesh sphere = icosphere(3, 0.8, Vec3(0.2, 0.1, -0.3));
  write_mesh(dir_ / "a.ply", sphere);
  write_mesh(dir_ / "b.obj", sphere);
  write_file(dir_ / "c.drc", encode_draco(sphere, DracoOptions{}));
  write_mesh(dir_ / "d.glb", sphere);
  for (const std::string size : {"480x360", "64x64", "300x120"}) {
    SCOPED_TRACE(size);
    const fs::path pics = dir_ / ("pics_" + size);
    const ProcessResult r =
        cli({"preview", (dir_ / "a.ply").string(), (dir_ / "b.obj").string(), (dir_ / "c.drc").string(),
             (dir_ / "d.glb").string(), "-o", pics.string(), "--size", size});
    ASSERT_EQ(r.code, 0) << r;
    EXPECT_EQ(count_lines(r.out), 4) << r;
    const int w = std::stoi(size.substr(0, size.find('x')));
    const int h = std::stoi(size.substr(size.find('x') + 1));
    for (const char* name : {"a.png", "b.png", "c.png", "d.png"}) {
      const Image image = read_png(pics / name);
      ASSERT_EQ(image.width, w) << name;
      ASSERT_EQ(image.height, h) << name;
      EXPECT_TRUE(centre_shaded_corners_background(image)) << name;
    }
  }
  // Particles as dots over the surface: the picture changes, in the dots' colour.
  write_file(dir_ / "p.xyz", "0.2 0.1 -0.3\n0.3 0.1 -0.3\n0.2 0.2 -0.3\n");
  ProcessResult r = cli(
      {"preview", (dir_ / "a.ply").string(), "--particles", (dir_ / "p.xyz").string(), "-o", (dir_ / "dots").string()});
  ASSERT_EQ(r.code, 0) << r;
  const Image plain = read_png(dir_ / "pics_480x360" / "a.png");
  const Image dotted = read_png(dir_ / "dots" / "a.png");
  ASSERT_EQ(dotted.width, plain.width);
  int reddish = 0;
  for (int y = 0; y < dotted.height; ++y) {
    for (int x = 0; x < dotted.width; ++x) {
      const Rgb c = dotted.at(x, y);
      reddish += c != plain.at(x, y) && c[0] > c[2] + 40;
    }
  }
  EXPECT_GT(reddish, 3);
  // One particle file per frame, or the command says so.
  r = cli({"preview", (dir_ / "a.ply").string(), (dir_ / "b.obj").string(), "--particles", (dir_ / "p.xyz").string(),
           "-o", (dir_ / "x").string()});
  EXPECT_EQ(r.code, 2) << r;
  EXPECT_NE(r.err.find("one particle file per frame"), std::string::npos) << r;
  r = cli({"preview", (dir_ / "missing.ply").string(), "-o", (dir_ / "x").string()});
  EXPECT_EQ(r.code, 2) << r;
  EXPECT_NE(r.err.find("missing.ply"), std::string::npos) << r;

  // An optimize run's iterations.csv as a plot.
  write_file(dir_ / "iterations.csv",
             "frame,iteration,triangles,e_d,e_n\n0,0,100,1e-3,0.5\n1,10,100,1e-5,0.05\n2,20,100,1e-7,0.01\n");
  r = cli({"preview", "--iterations", (dir_ / "iterations.csv").string(), "-o", (dir_ / "plot").string()});
  ASSERT_EQ(r.code, 0) << r;
  const Image plot = read_png(dir_ / "plot" / "iterations.png");
  ASSERT_EQ(plot.width, 480);
  int colored = 0;
  for (int y = 0; y < plot.height; ++y) {
    for (int x = 0; x < plot.width; ++x) {
      const Rgb c = plot.at(x, y);
      colored += std::max({c[0], c[1], c[2]}) - std::min({c[0], c[1], c[2]}) > 80;
    }
  }
  EXPECT_GT(colored, 200);  // the two coloured lines
}

}  // namespace
}  // namespace surfacer::client
