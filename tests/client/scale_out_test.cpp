// Scale-out `run` (--server a,b,c): the splitting helpers, then real `surfacer-server` processes on loopback ports,
// one of them SIGKILLed while it works on its first batch. Frames (the default .glb files) are compared byte for byte
// with a single-server run and read back.
#include "client/scale_out.h"

#include <gtest/gtest.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <map>
#include <random>
#include <regex>
#include <set>
#include <sstream>
#include <thread>

#include "client/cli.h"
#include "client/job_spec.h"
#include "client/server_list.h"
#include "client/upload.h"
#include "tests/support/files.h"
#include "tests/support/mesh_expectations.h"
#include "tests/support/process.h"
#include "tests/support/server_process.h"

namespace surfacer::client {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using namespace surfacer::testing;

// ---------------------------------------------------------------------------------------------------------------
// Helpers without servers

TEST(ScaleOutSplit, BatchesCoverEveryFrameOnceInOrder) {
  for (int frames : {1, 2, 5, 12, 13, 100, 101}) {
    for (int servers : {1, 2, 3, 7}) {
      const auto batches = make_batches(frames, servers);
      const int per = std::max(1, static_cast<int>(std::ceil(frames / (4.0 * servers))));
      std::vector<int> all;
      for (const auto& b : batches) {
        EXPECT_GE(b.size(), 1u);
        EXPECT_LE(static_cast<int>(b.size()), per);
        all.insert(all.end(), b.begin(), b.end());
      }
      std::vector<int> expected(static_cast<std::size_t>(frames));
      for (int i = 0; i < frames; ++i) expected[static_cast<std::size_t>(i)] = i;
      EXPECT_EQ(all, expected) << frames << " frames, " << servers << " servers";
    }
  }
  EXPECT_EQ(make_batches(12, 3).size(), 12u);  // ceil(12 / 12) = 1 frame each
  EXPECT_EQ(make_batches(100, 3).front().size(), 9u);
}

v1::Scene sphere_scene(double radius) {
  v1::Scene scene;
  scene.set_name("s" + std::to_string(radius));
  scene.mutable_root()->mutable_sphere()->set_radius(radius);
  return scene;
}

TEST(ScaleOutSplit, SubJobsHoldTheirFramesAndShareTheWholeJobsGrid) {
  v1::JobSpec whole;
  whole.set_name("seq");
  for (int i = 0; i < 6; ++i) *whole.mutable_isosurface()->add_scenes() = sphere_scene(0.5 + 0.1 * i);
  whole.mutable_isosurface()->set_cells(32);
  EXPECT_EQ(sequence_frames(whole), 6);
  pin_whole_job_geometry(whole, {}, {});
  ASSERT_TRUE(whole.isosurface().has_bounds());
  // The union of the spheres (radius 1.0) padded by two cells of 2.0 / 32.
  const double h = 2.0 / 32;
  EXPECT_NEAR(whole.isosurface().cell_size(), h, 1e-12);
  EXPECT_NEAR(whole.isosurface().bounds().max().x(), 1.0 + 2 * h, 1e-9);
  EXPECT_NEAR(whole.isosurface().bounds().min().z(), -1.0 - 2 * h, 1e-9);

  const v1::JobSpec sub = sub_job_spec(whole, {4, 1});
  ASSERT_EQ(sub.isosurface().scenes_size(), 2);
  EXPECT_EQ(sub.isosurface().scenes(0).name(), whole.isosurface().scenes(4).name());
  EXPECT_EQ(sub.isosurface().scenes(1).name(), whole.isosurface().scenes(1).name());
  EXPECT_EQ(sub.isosurface().bounds().SerializeAsString(), whole.isosurface().bounds().SerializeAsString());
  EXPECT_EQ(sub.isosurface().cell_size(), whole.isosurface().cell_size());
  EXPECT_EQ(sub.name(), "seq [frames 4, 1]");

  v1::JobSpec single;
  *single.mutable_isosurface()->add_scenes() = sphere_scene(1);
  EXPECT_EQ(sequence_frames(single), 0);
  v1::JobSpec optimize;
  *optimize.mutable_optimize()->mutable_scene() = sphere_scene(1);
  EXPECT_EQ(sequence_frames(optimize), 0);

  // An invalid scene is reported as the server would, naming the whole job's index.
  v1::JobSpec bad = whole;
  bad.mutable_isosurface()->clear_bounds();
  bad.mutable_isosurface()->set_cells(32);
  bad.mutable_isosurface()->mutable_scenes(3)->mutable_root()->mutable_sphere()->set_radius(-1);
  try {
    pin_whole_job_geometry(bad, {}, {});
    FAIL() << "a negative radius passed";
  } catch (const CliError& e) {
    EXPECT_EQ(e.code(), ExitCode::kJobFailed);
    EXPECT_NE(std::string(e.what()).find("spec.isosurface.scenes[3]"), std::string::npos) << e.what();
  }
}

TEST(ScaleOutSplit, MessagesNameTheWholeJobsIndicesAndUploadsAreFound) {
  EXPECT_EQ(globalize_indices("spec.isosurface.scenes[1].root.sphere.radius (-1) must be > 0", {7, 9}),
            "spec.isosurface.scenes[9].root.sphere.radius (-1) must be > 0");
  EXPECT_EQ(globalize_indices("spec.particles.frames[0]: particle 3; frames[1]", {4, 5}),
            "spec.particles.frames[4]: particle 3; frames[5]");
  EXPECT_EQ(globalize_indices("scenes[5] scenes[x] frames[", {1}), "scenes[5] scenes[x] frames[");
  EXPECT_EQ(frames_text({3, 4, 5}), "frames 3-5");
  EXPECT_EQ(frames_text({7}), "frame 7");
  EXPECT_EQ(frames_text({3, 9}), "frames 3, 9");

  v1::JobSpec spec;
  *spec.mutable_isosurface()->add_scenes() = sphere_scene(1);
  EXPECT_FALSE(find_upload_reference(spec));
  v1::Scene grid;
  grid.mutable_root()->mutable_grid()->set_upload_id("u-123");
  *spec.mutable_isosurface()->add_scenes() = grid;
  const auto found = find_upload_reference(spec);
  ASSERT_TRUE(found);
  EXPECT_NE(found->find("spec.isosurface.scenes[1]"), std::string::npos) << *found;
  EXPECT_NE(found->find("u-123"), std::string::npos) << *found;
}

TEST(ScaleOutSplit, ServerListsAndDnsNames) {
  EXPECT_EQ(parse_server_list("a:1, b:2 ,[::1]:3,a:1"), (std::vector<std::string>{"a:1", "b:2", "[::1]:3"}));
  for (const char* bad : {"a:1,,b:2", "a:1,b", "a:1,b:x", "a:1,::1"}) {
    try {
      parse_server_list(bad);
      ADD_FAILURE() << bad << " was accepted";
    } catch (const CliError& e) {
      EXPECT_EQ(e.code(), ExitCode::kUsage);
      EXPECT_NE(std::string(e.what()).find("--server"), std::string::npos) << e.what();
    }
  }
  const auto local = resolve_dns_name("dns:///localhost:50051");
  EXPECT_NE(std::find(local.begin(), local.end(), "127.0.0.1:50051"), local.end()) << local.size();
  EXPECT_EQ(dns_host("dns:///surfacer.example:443"), "surfacer.example");
  EXPECT_THROW(resolve_dns_name("dns:///localhost"), CliError);

  // A list is for `run` only.
  std::vector<const char*> argv = {"surfacer", "--server", "a:1,b:2", "list"};
  std::ostringstream out, err;
  const auto parsed = parse_command_line(static_cast<int>(argv.size()), argv.data(), out, err, nullptr);
  ASSERT_TRUE(std::holds_alternative<ExitCode>(parsed));
  EXPECT_EQ(std::get<ExitCode>(parsed), ExitCode::kUsage);
  EXPECT_NE(err.str().find("run"), std::string::npos) << err.str();
}

// ---------------------------------------------------------------------------------------------------------------
// Real servers

// The first `columns` cells of every line.
std::string csv_prefix(const std::string& csv, int columns) {
  std::istringstream lines(csv);
  std::string out;
  for (std::string line; std::getline(lines, line);) {
    std::istringstream cells(line);
    std::string cell;
    for (int c = 0; c < columns && std::getline(cells, cell, ','); ++c) out += (c > 0 ? "," : "") + cell;
    out += "\n";
  }
  return out;
}

class ScaleOutEndToEnd : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("surfacer_scale_out_" + std::to_string(::getpid())) /
           ::testing::UnitTest::GetInstance()->current_test_info()->name();
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override {
    servers_.clear();
    if (!HasFailure()) fs::remove_all(dir_);
  }

  // Starts `n` servers with one worker each; returns their addresses.
  void start_servers(int n) {
    for (int i = 0; i < n; ++i) {
      servers_.push_back(std::make_unique<ServerProcess>(dir_ / ("server" + std::to_string(i)), 1,
                                                         std::vector<std::string>{"--drain-seconds", "1"}));
      ASSERT_FALSE(servers_.back()->address().empty()) << servers_.back()->log();
    }
  }
  std::string server_list() const {
    std::string list;
    for (const auto& s : servers_) list += (list.empty() ? "" : ",") + s->address();
    return list;
  }

  // `count` torus scenes, each a little thicker than the one before (so frames differ); `bad` gets a negative
  // radius. Returns the --scene arguments.
  std::vector<std::string> scenes(int count, int bad = -1) {
    std::vector<std::string> args;
    for (int i = 0; i < count; ++i) {
      const fs::path file = dir_ / ("scene" + std::to_string(i) + ".json");
      char json[200];
      if (i == bad) {
        std::snprintf(json, sizeof json, R"({"name": "bad", "root": {"sphere": {"radius": -1}}})");
      } else {
        std::snprintf(json, sizeof json,
                      R"({"name": "t%d", "root": {"torus": {"majorRadius": 1, "minorRadius": %.3f}}})", i,
                      0.3 + 0.02 * i);
      }
      write_file(file, json);
      args.push_back("--scene");
      args.push_back(file.string());
    }
    return args;
  }

  std::unique_ptr<ChildProcess> spawn(std::vector<std::string> args, const std::string& tag) {
    args.insert(args.begin(), cli_binary().string());
    return std::make_unique<ChildProcess>(args, dir_ / (tag + ".out"), dir_ / (tag + ".err"));
  }
  ProcessResult cli(std::vector<std::string> args, const std::string& tag) {
    return finish(*spawn(std::move(args), tag), 90s);
  }

  // Waits until the server's log shows a started job; false after `timeout`.
  bool wait_for_job_started(const ServerProcess& server, std::chrono::seconds timeout = 30s) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < deadline) {
      if (server.log().find("event=job_started") != std::string::npos) return true;
      std::this_thread::sleep_for(2ms);
    }
    return false;
  }

  // Jobs of a server by state name, from `surfacer list`.
  std::map<std::string, int> job_states(const std::string& address) {
    ProcessResult r = cli({"--server", address, "list"}, "list" + std::to_string(list_counter_++));
    EXPECT_EQ(r.code, 0) << r;
    std::map<std::string, int> states;
    std::istringstream lines(r.out);
    std::string line;
    std::getline(lines, line);  // header
    while (std::getline(lines, line)) {
      std::istringstream cells(line);
      std::string id, state;
      cells >> id >> state;
      ++states[state];
    }
    return states;
  }

  // Every server ends with no queued or running job; returns the number of cancelled jobs over all of them.
  int expect_nothing_left_running() {
    int cancelled = 0;
    for (const auto& s : servers_) {
      std::map<std::string, int> states;
      const auto deadline = std::chrono::steady_clock::now() + 10s;
      do {
        states = job_states(s->address());
        if (states["RUNNING"] == 0 && states["QUEUED"] == 0) break;
        std::this_thread::sleep_for(100ms);
      } while (std::chrono::steady_clock::now() < deadline);
      EXPECT_EQ(states["RUNNING"], 0) << s->address();
      EXPECT_EQ(states["QUEUED"], 0) << s->address();
      cancelled += states["CANCELLED"];
    }
    return cancelled;
  }

  // frame_0000.glb .. frame_{n-1}.glb (the default files) and stats.csv, nothing else (no temporary files).
  void expect_exactly_frames(const fs::path& out, int n) {
    std::set<std::string> names;
    for (const auto& entry : fs::directory_iterator(out)) names.insert(entry.path().filename().string());
    std::set<std::string> expected = {"stats.csv"};
    for (int i = 0; i < n; ++i) {
      char name[32];
      std::snprintf(name, sizeof name, "frame_%04d.glb", i);
      expected.insert(name);
    }
    EXPECT_EQ(names, expected);
  }

  // Every frame reads back as a closed mesh and equals the reference byte for byte;
  // stats.csv has one row per frame in order, with the reference's mesh figures.
  void expect_same_as_reference(const fs::path& out, const fs::path& ref, int n) {
    for (int i = 0; i < n; ++i) {
      char name[32];
      std::snprintf(name, sizeof name, "frame_%04d.glb", i);
      const fs::path glb = out / name;
      EXPECT_TRUE(mesh_file_has(glb, kClosed));
      EXPECT_TRUE(read_file(glb) == read_file(ref / name)) << name << " differs from the single-server run";
    }
    const std::string csv = read_file(out / "stats.csv");
    EXPECT_EQ(count_lines(csv), n + 1) << csv;
    std::istringstream lines(csv);
    std::string line;
    std::getline(lines, line);
    for (int i = 0; i < n && std::getline(lines, line); ++i) {
      EXPECT_EQ(line.substr(0, line.find(',')), std::to_string(i)) << csv;
    }
    // frame .. volume: the mesh figures (the timings differ from run to run).
    EXPECT_EQ(csv_prefix(csv, 11), csv_prefix(read_file(ref / "stats.csv"), 11));
  }

  // drop_0000.xyz ..: `frames` jittered lattice balls drifting along x; returns their pattern.
  std::string write_droplets(int frames) {
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> jitter(-0.01, 0.01);
    for (int f = 0; f < frames; ++f) {
      std::string text;
      char line[96];
      for (int k = -6; k <= 6; ++k) {
        for (int j = -6; j <= 6; ++j) {
          for (int i = -6; i <= 6; ++i) {
            if (i * i + j * j + k * k > 30) continue;
            std::snprintf(line, sizeof line, "%.6f %.6f %.6f\n", 0.1 * i + 0.05 * f + jitter(rng),
                          0.1 * j + jitter(rng), 0.1 * k + jitter(rng));
            text += line;
          }
        }
      }
      char name[32];
      std::snprintf(name, sizeof name, "drop_%04d.xyz", f);
      write_file(dir_ / name, text);
    }
    return (dir_ / "drop_{:04d}.xyz").string();
  }

  fs::path dir_;
  std::vector<std::unique_ptr<ServerProcess>> servers_;
  int list_counter_ = 0;
};

TEST_F(ScaleOutEndToEnd, AServerKilledDuringItsFirstBatchLosesNothing) {
  start_servers(3);
  constexpr int kFrames = 12;
  std::vector<std::string> args = {
      "--server", server_list(),          "--timeout", "2", "-v", "run", "isosurface", "--cells", "64",
      "-o",       (dir_ / "out").string()};
  const auto scene_args = scenes(kFrames);
  args.insert(args.end(), scene_args.begin(), scene_args.end());
  auto run = spawn(args, "run");
  ServerProcess& victim = *servers_[0];
  const std::string victim_address = victim.address();
  ASSERT_TRUE(wait_for_job_started(victim)) << read_file(dir_ / "run.err");
  victim.kill_now();
  const ProcessResult r = finish(*run, 90s);
  ASSERT_EQ(r.code, 0) << r;
  EXPECT_NE(r.err.find("server " + victim_address + " is unreachable"), std::string::npos) << r;
  EXPECT_NE(r.err.find("back to the queue"), std::string::npos) << r;
  EXPECT_NE(r.err.find("retries: 1 batch"), std::string::npos) << r;
  EXPECT_NE(r.err.find("wrote 12 frames"), std::string::npos) << r;
  // Verbose: each frame names the server that made it, never the dead one after its death.
  std::smatch m;
  const std::regex from(R"(frame (\d+)/12: .*\[(127\.0\.0\.1:\d+), job)");
  std::set<int> reported;
  for (auto it = std::sregex_iterator(r.err.begin(), r.err.end(), from); it != std::sregex_iterator(); ++it) {
    reported.insert(std::stoi((*it)[1]));
    EXPECT_NE((*it)[2], victim_address) << r;  // killed before it finished a frame
  }
  EXPECT_EQ(reported.size(), static_cast<std::size_t>(kFrames)) << r;

  std::vector<std::string> ref_args = {"--server", servers_[1]->address(), "run", "isosurface", "--cells", "64",
                                       "-o",       (dir_ / "ref").string()};
  ref_args.insert(ref_args.end(), scene_args.begin(), scene_args.end());
  const ProcessResult ref = cli(ref_args, "ref");
  ASSERT_EQ(ref.code, 0) << ref;
  expect_exactly_frames(dir_ / "out", kFrames);
  expect_same_as_reference(dir_ / "out", dir_ / "ref", kFrames);
}

TEST_F(ScaleOutEndToEnd, ParticleSequenceSplitAcrossServersMatchesOneServer) {
  start_servers(2);
  constexpr int kFrames = 6;
  const std::string pattern = write_droplets(kFrames);
  const ProcessResult r = cli({"--server", server_list(), "run", "particles", "--input", pattern, "--derive-r-inner",
                               "-o", (dir_ / "out").string()},
                              "run");
  ASSERT_EQ(r.code, 0) << r;
  EXPECT_NE(r.err.find("splitting 6 frames into 6 batches"), std::string::npos) << r;
  const ProcessResult ref = cli({"--server", servers_[0]->address(), "run", "particles", "--input", pattern,
                                 "--derive-r-inner", "-o", (dir_ / "ref").string()},
                                "ref");
  ASSERT_EQ(ref.code, 0) << ref;
  expect_exactly_frames(dir_ / "out", kFrames);
  expect_same_as_reference(dir_ / "out", dir_ / "ref", kFrames);
  // Both servers did part of the work.
  for (const auto& s : servers_) {
    EXPECT_EQ(r.err.find(s->address() + ": 0 frames"), std::string::npos) << r;
  }
}

// Batches of two frames go to servers that take open sequences as open sub-jobs: each is queued with its first frame,
// which is done (its file written) while the second is still being read for its upload; the frames are byte for byte
// those of one server.
TEST_F(ScaleOutEndToEnd, ParticleBatchesStreamIntoTheirSubJobs) {
  start_servers(2);
  constexpr int kFrames = 12;  // batches of 2 across 2 servers (make_batches)
  const std::string pattern = write_droplets(kFrames);
  JobOptions options;
  options.particles.inputs = {pattern};
  options.spec.mutable_particles()->set_derive_r_inner(true);
  PreparedJob prepared = prepare_job(options);
  ASSERT_EQ(prepared.uploads.size(), static_cast<std::size_t>(kFrames));
  const fs::path out = dir_ / "out";
  // The second frame of each batch waits, in its upload's read (its first read is the check before any job), until
  // the batch's first frame is written: with every frame uploaded before the sub-job started it would wait in vain.
  auto streamed = std::make_shared<std::atomic<int>>(0);
  for (int g = 1; g < kFrames; g += 2) {
    PendingUpload& pending = prepared.uploads[static_cast<std::size_t>(g)];
    auto reads = std::make_shared<int>(0);
    char first[32];
    std::snprintf(first, sizeof first, "frame_%04d.glb", g - 1);
    pending.read = [read = pending.read, reads, file = out / first, streamed](v1::JobSpec& spec,
                                                                              const InputLimits& limits) {
      if (++*reads == 2) {
        const auto until = std::chrono::steady_clock::now() + 20s;
        while (!fs::exists(file) && std::chrono::steady_clock::now() < until) std::this_thread::sleep_for(10ms);
        if (fs::exists(file)) ++*streamed;
      }
      return read(spec, limits);
    };
  }
  ConnectOptions connect;
  connect.server = server_list();
  FrameOutputOptions output;
  output.dir = out;
  output.frame_numbers = prepared.frame_numbers;
  fit_encoding_to_files(prepared.spec, output.formats);  // as `run` does
  std::ostringstream err;
  ASSERT_EQ(
      run_scale_out(connect, parse_server_list(server_list()), std::move(prepared), output, err, ProgressMode::kLines),
      ExitCode::kSuccess)
      << err.str();
  EXPECT_EQ(*streamed, kFrames / 2) << err.str();
  for (const auto& s : servers_) {  // every sub-job was queued open, with one frame
    const std::string log = s->log();
    for (std::size_t at = log.find("event=job_submitted"); at != std::string::npos;
         at = log.find("event=job_submitted", at + 1)) {
      EXPECT_NE(log.substr(at, log.find('\n', at) - at).find("frames=1"), std::string::npos) << log;
    }
  }
  const ProcessResult ref = cli({"--server", servers_[0]->address(), "run", "particles", "--input", pattern,
                                 "--derive-r-inner", "-o", (dir_ / "ref").string()},
                                "ref");
  ASSERT_EQ(ref.code, 0) << ref;
  expect_exactly_frames(out, kFrames);
  expect_same_as_reference(out, dir_ / "ref", kFrames);
}

TEST_F(ScaleOutEndToEnd, EveryServerDeadExitsThree) {
  start_servers(2);
  std::vector<std::string> args = {"--server",   server_list(), "--timeout", "1",  "run",
                                   "isosurface", "--cells",     "64",        "-o", (dir_ / "out").string()};
  const auto scene_args = scenes(8);
  args.insert(args.end(), scene_args.begin(), scene_args.end());
  auto run = spawn(args, "run");
  for (auto& s : servers_) {
    ASSERT_TRUE(wait_for_job_started(*s)) << read_file(dir_ / "run.err");
    s->kill_now();
  }
  const ProcessResult r = finish(*run, 90s);
  EXPECT_EQ(r.code, 3) << r;
  EXPECT_NE(r.err.find("every server is unreachable"), std::string::npos) << r;

  // Nothing listening at all: exit 3 as well.
  const std::string nowhere = "127.0.0.1:" + std::to_string(free_port()) + ",127.0.0.1:" + std::to_string(free_port());
  std::vector<std::string> none = {"--server", nowhere,      "--timeout", "1",
                                   "run",      "isosurface", "-o",        (dir_ / "none").string()};
  none.insert(none.end(), scene_args.begin(), scene_args.end());
  const ProcessResult n = cli(none, "none");
  EXPECT_EQ(n.code, 3) << n;
}

TEST_F(ScaleOutEndToEnd, ABadSceneFailsTheRunAndCancelsTheOtherSubJobs) {
  start_servers(3);
  // Heavy frames, so the sub-jobs of the good scenes are still running when the bad one is rejected.
  std::vector<std::string> args = {
      "--server", server_list(),          "run", "isosurface", "--cells", "160", "--bounds=-1.6,-1.6,-0.8,1.6,1.6,0.8",
      "-o",       (dir_ / "out").string()};
  const auto scene_args = scenes(9, /*bad=*/2);
  args.insert(args.end(), scene_args.begin(), scene_args.end());
  const auto t0 = std::chrono::steady_clock::now();
  const ProcessResult r = cli(args, "run");
  EXPECT_EQ(r.code, 4) << r;
  EXPECT_LT(std::chrono::steady_clock::now() - t0, 20s);
  EXPECT_NE(r.err.find("INVALID_ARGUMENT"), std::string::npos) << r;
  EXPECT_NE(r.err.find("spec.isosurface.scenes[2]"), std::string::npos) << "the whole job's index: " << r;
  EXPECT_NE(r.err.find("radius"), std::string::npos) << r;
  EXPECT_GE(expect_nothing_left_running(), 1) << "no sub-job was cancelled";

  // Without --bounds the client checks the scenes itself before submitting anything.
  std::vector<std::string> unbounded = {"--server", server_list(), "run", "isosurface",
                                        "--cells",  "32",          "-o",  (dir_ / "out2").string()};
  unbounded.insert(unbounded.end(), scene_args.begin(), scene_args.end());
  const ProcessResult u = cli(unbounded, "unbounded");
  EXPECT_EQ(u.code, 4) << u;
  EXPECT_NE(u.err.find("spec.isosurface.scenes[2]"), std::string::npos) << u;
}

TEST_F(ScaleOutEndToEnd, CtrlCCancelsEverySubJob) {
  start_servers(2);
  std::vector<std::string> args = {"--server", server_list(), "run", "isosurface",
                                   "--cells",  "160",         "-o",  (dir_ / "out").string()};
  const auto scene_args = scenes(16);
  args.insert(args.end(), scene_args.begin(), scene_args.end());
  auto run = spawn(args, "run");
  for (auto& s : servers_) ASSERT_TRUE(wait_for_job_started(*s)) << read_file(dir_ / "run.err");
  run->signal(SIGINT);
  const ProcessResult r = finish(*run, 30s);
  EXPECT_EQ(r.code, 5) << r;
  EXPECT_NE(r.err.find("interrupted"), std::string::npos) << r;
  EXPECT_GE(expect_nothing_left_running(), 2);
}

TEST_F(ScaleOutEndToEnd, AJobThatIsNotASequenceFailsOverToTheNextServer) {
  start_servers(1);
  const std::string list = "127.0.0.1:" + std::to_string(free_port()) + "," + servers_[0]->address();
  const auto scene_args = scenes(1);
  std::vector<std::string> args = {"--server",   list,      "--timeout", "1",  "run",
                                   "isosurface", "--cells", "32",        "-o", (dir_ / "out").string()};
  args.insert(args.end(), scene_args.begin(), scene_args.end());
  const ProcessResult r = cli(args, "run");
  ASSERT_EQ(r.code, 0) << r;
  EXPECT_NE(r.err.find("resubmitting the whole job to " + servers_[0]->address()), std::string::npos) << r;
  expect_exactly_frames(dir_ / "out", 1);
}

}  // namespace
}  // namespace surfacer::client
