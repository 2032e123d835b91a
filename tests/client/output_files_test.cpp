// Where frames go: -o DIR or -o PATTERN, the number in each name, input patterns whose {} takes any zero padding,
// and the VTK files written from received frames.
#include "client/output_files.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>

#include "client/exit_codes.h"
#include "client/frame_writer.h"
#include "client/particle_files.h"
#include "core/mesh/mesh_io.h"
#include "core/particles/particle_io.h"
#include "tests/support/cli_parse.h"
#include "tests/support/files.h"
#include "tests/support/test_meshes.h"

namespace surfacer::client {
namespace {

namespace fs = std::filesystem;

// The usage error `f` throws; fails the test when it throws nothing.
template <class F>
std::string usage_error(F&& f) {
  try {
    f();
  } catch (const CliError& e) {
    EXPECT_EQ(e.code(), ExitCode::kUsage) << e.what();
    return e.what();
  }
  ADD_FAILURE() << "no usage error";
  return "";
}

TEST(OutputNaming, DirectoryNamesCarryTheFrameNumbersWithAtLeastFourDigits) {
  FrameOutputOptions o = frame_output_options("out", {"vtu", "ply", "vtu"}, "run");
  EXPECT_EQ(o.dir, "out");
  EXPECT_EQ(o.formats, (std::vector<FileFormat>{FileFormat::kVtu, FileFormat::kPly}));
  EXPECT_FALSE(o.pattern);
  EXPECT_EQ(frame_file_path(o, 3, FileFormat::kVtu), fs::path("out/frame_0003.vtu"));
  for (const int start : {0, 7, 100, 9999, 12345}) {
    o.frame_numbers = {start, start + 1, start + 2};
    for (int i = 0; i < 3; ++i) {
      char want[48];
      std::snprintf(want, sizeof want, "out/frame_%04d.vtk", start + i);
      EXPECT_EQ(frame_file_path(o, i, FileFormat::kVtk), fs::path(want)) << start;
    }
    EXPECT_EQ(frame_file_path(o, 5, FileFormat::kVtk), fs::path("out/frame_0005.vtk"));  // past the numbers: index
  }
}

TEST(OutputNaming, PatternsNameEachFrameAndTheirExtensionSetsTheFormat) {
  struct Case {
    std::string pattern;
    int number;
    std::string file;
    FileFormat format;
  };
  for (const Case& c : std::vector<Case>{{"out/surface_{:04d}.ply", 100, "out/surface_0100.ply", FileFormat::kPly},
                                         {"out/surface_{:04d}.ply", 0, "out/surface_0000.ply", FileFormat::kPly},
                                         {"s_{}.vtu", 7, "s_7.vtu", FileFormat::kVtu},
                                         {"s_{}.vtu", 12345, "s_12345.vtu", FileFormat::kVtu},
                                         {"a/b/{:06d}.VTK", 42, "a/b/000042.VTK", FileFormat::kVtk},
                                         {"f{:02d}.obj", 123, "f123.obj", FileFormat::kObj},
                                         {"f{:03d}.drc", -5, "f-05.drc", FileFormat::kDrc}}) {
    SCOPED_TRACE(c.pattern);
    FrameOutputOptions o = frame_output_options(c.pattern, {}, "run");
    ASSERT_TRUE(o.pattern);
    EXPECT_EQ(o.formats, std::vector<FileFormat>{c.format});
    EXPECT_EQ(o.dir, fs::path(c.pattern).has_parent_path() ? fs::path(c.pattern).parent_path() : fs::path("."));
    o.frame_numbers = {c.number};
    EXPECT_EQ(frame_file_path(o, 0, c.format), fs::path(c.file));
  }
}

// -o FILE.ext without a placeholder is one file for a one-frame job; a job of several frames is refused before it
// runs, asking for a placeholder; an existing directory of that name stays a directory.
TEST(OutputNaming, AFileNameIsTheOneFrameOfAOneFrameJob) {
  const FrameOutputOptions o = frame_output_options("out/mesh.ply", {}, "run");
  ASSERT_TRUE(o.file);
  EXPECT_EQ(o.dir, std::filesystem::path("out"));
  EXPECT_EQ(o.formats, (std::vector<FileFormat>{FileFormat::kPly}));
  EXPECT_EQ(frame_file_path(o, 0, FileFormat::kPly), std::filesystem::path("out/mesh.ply"));
  EXPECT_NO_THROW(check_one_file(o, 1));
  EXPECT_NE(usage_error([&] { check_one_file(o, 3); }).find("-o 'out/mesh_{:04d}.ply'"), std::string::npos);
  EXPECT_NE(usage_error([&] { check_one_file(o, std::nullopt); }).find("several frames"), std::string::npos);
  EXPECT_NE(usage_error([&] { frame_file_path(o, 1, FileFormat::kPly); }).find("placeholder"), std::string::npos);
  EXPECT_NE(usage_error([] { frame_output_options("out/mesh.vtu", {"ply"}, "run"); }).find("drop --format"),
            std::string::npos);
  // Not a mesh extension, or a directory that exists: a directory, as before.
  EXPECT_FALSE(frame_output_options("out/run.1", {}, "run").file);
  const std::filesystem::path dir = std::filesystem::temp_directory_path() / "surfacer_out_as_dir.ply";
  std::filesystem::create_directories(dir);
  EXPECT_FALSE(frame_output_options(dir.string(), {}, "run").file);
  std::filesystem::remove_all(dir);
  FrameOutputOptions d = frame_output_options("out", {}, "run");
  EXPECT_NO_THROW(check_one_file(d, 5));
}

TEST(OutputNaming, BadOutputsAreUsageErrorsNamingTheFlag) {
  EXPECT_NE(usage_error([] { frame_output_options("out/s_{:04d}.ply", {"vtk"}, "run"); }).find("drop --format"),
            std::string::npos);
  EXPECT_NE(
      usage_error([] { frame_output_options("out/s_{}.png", {}, "run"); }).find(".drc, .ply, .obj, .vtk, .vtu or .glb"),
      std::string::npos);
  EXPECT_NE(usage_error([] { frame_output_options("out/s_{}", {}, "run"); }).find("-o out/s_{}"), std::string::npos);
  EXPECT_NE(usage_error([] { frame_output_options("out_{}/s.ply", {}, "run"); }).find("directory name"),
            std::string::npos);
  EXPECT_NE(usage_error([] { frame_output_options("out/s_{:x}.ply", {}, "watch"); }).find("-o out/s_{:x}.ply"),
            std::string::npos);
  EXPECT_NE(usage_error([] { frame_output_options("out/s_{}_{}.ply", {}, "run"); }).find("exactly one"),
            std::string::npos);
  EXPECT_NE(usage_error([] { frame_output_options("", {}, "watch"); }).find("watch needs an output directory"),
            std::string::npos);
}

TEST(OutputNaming, OutputNumbersAreTheInputsWhenEveryFrameHasOneAndTheyIncrease) {
  EXPECT_EQ(output_numbers({100, 101, 102}), (std::vector<int>{100, 101, 102}));
  EXPECT_EQ(output_numbers({3, 10, 11}), (std::vector<int>{3, 10, 11}));
  EXPECT_TRUE(output_numbers({}).empty());
  EXPECT_TRUE(output_numbers({100, std::nullopt}).empty());  // a plain file among them
  EXPECT_TRUE(output_numbers({5, 6, 5, 6}).empty());         // two patterns over the same range
}

TEST(OutputNaming, CommandLineTakesVtkAndGlbFormatsAndPatterns) {
  const fs::path dir = testing::fresh_temp_dir("output_naming_cli");
  testing::write_file(dir / "s.json", R"({"root": {"sphere": {"radius": 1}}})");
  auto run = [&](std::vector<std::string> output) {
    std::vector<std::string> args = {"run", "isosurface", "--scene", (dir / "s.json").string()};
    args.insert(args.end(), output.begin(), output.end());
    return testing::parse_cli(args);
  };
  const testing::ParsedCli formats = run({"-o", "out", "--format", "vtk,vtu,glb"});
  ASSERT_EQ(testing::exit_code_of(formats), ExitCode::kSuccess) << formats.err;
  const auto& output = std::get<RunCommand>(std::get<Invocation>(formats.result).command).output;
  EXPECT_EQ(output.formats, (std::vector<FileFormat>{FileFormat::kVtk, FileFormat::kVtu, FileFormat::kGlb}));
  const testing::ParsedCli glb_pattern = run({"-o", "out/f_{:04d}.GLB"});
  ASSERT_EQ(testing::exit_code_of(glb_pattern), ExitCode::kSuccess) << glb_pattern.err;
  EXPECT_EQ(std::get<RunCommand>(std::get<Invocation>(glb_pattern.result).command).output.formats,
            std::vector<FileFormat>{FileFormat::kGlb});
  const testing::ParsedCli pattern = run({"-o", "out/f_{:04d}.vtu"});
  ASSERT_EQ(testing::exit_code_of(pattern), ExitCode::kSuccess) << pattern.err;
  EXPECT_EQ(std::get<RunCommand>(std::get<Invocation>(pattern.result).command).output.pattern, "out/f_{:04d}.vtu");
  const testing::ParsedCli both = run({"-o", "out/f_{:04d}.vtu", "--format", "ply"});
  EXPECT_EQ(testing::exit_code_of(both), ExitCode::kUsage);
  EXPECT_NE(both.err.find("--format"), std::string::npos) << both.err;
  const testing::ParsedCli bad = run({"-o", "out", "--format", "stl"});
  EXPECT_EQ(testing::exit_code_of(bad), ExitCode::kUsage);
  const testing::ParsedCli watch = testing::parse_cli({"watch", "j-1", "-o", "w/m_{}.vtk"});
  ASSERT_EQ(testing::exit_code_of(watch), ExitCode::kSuccess) << watch.err;
  EXPECT_EQ(std::get<WatchCommand>(std::get<Invocation>(watch.result).command).output.formats,
            std::vector<FileFormat>{FileFormat::kVtk});
  fs::remove_all(dir);
}

// --- Input patterns ----------------------------------------------------------------------------------------------

class InputPatterns : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = testing::fresh_temp_dir("input_patterns"); }
  void TearDown() override { fs::remove_all(dir_); }
  void touch(const std::string& name) { testing::write_file(dir_ / name, "0 0 0\n"); }
  ParticleInputFiles expand(const std::string& pattern, std::optional<int> start = {}, std::optional<int> end = {}) {
    ParticleInputOptions o;
    o.inputs = {(dir_ / pattern).string()};
    o.start = start;
    o.end = end;
    return expand_particle_sequence(o);
  }
  fs::path dir_;
};

TEST_F(InputPatterns, EmptyPlaceholderMatchesAnyZeroPadding) {
  touch("fluid_7.xyz");
  touch("fluid_0008.xyz");
  touch("fluid_009.xyz");
  touch("fluid_10.xyz");
  touch("fluid_x.xyz");
  touch("other_0007.xyz");
  for (const auto& [start, end] : std::vector<std::pair<std::optional<int>, std::optional<int>>>{
           {std::nullopt, std::nullopt}, {7, 10}, {7, std::nullopt}, {std::nullopt, 10}}) {
    const ParticleInputFiles files = expand("fluid_{}.xyz", start, end);
    EXPECT_EQ(files.files, (std::vector<fs::path>{dir_ / "fluid_7.xyz", dir_ / "fluid_0008.xyz", dir_ / "fluid_009.xyz",
                                                  dir_ / "fluid_10.xyz"}));
    EXPECT_EQ(output_numbers(files.numbers), (std::vector<int>{7, 8, 9, 10}));
  }
  const ParticleInputFiles part = expand("fluid_{}.xyz", 8, 9);
  EXPECT_EQ(output_numbers(part.numbers), (std::vector<int>{8, 9}));
  // {:04d} still names exactly one padding.
  EXPECT_EQ(expand("fluid_{:04d}.xyz").files, std::vector<fs::path>{dir_ / "fluid_0008.xyz"});
  // A gap names the missing frame.
  std::remove((dir_ / "fluid_009.xyz").c_str());
  const std::string gap = usage_error([&] { expand("fluid_{}.xyz"); });
  EXPECT_NE(gap.find("1 of the 4 frames 7..10 are missing"), std::string::npos) << gap;
  EXPECT_NE(gap.find("fluid_9.xyz (with any zero padding)"), std::string::npos) << gap;
}

TEST_F(InputPatterns, TwoPaddingsOfOneFrameAreAnError) {
  touch("p_7.json");
  touch("p_0007.json");
  const std::string message = usage_error([&] { expand("p_{}.json"); });
  EXPECT_NE(message.find("p_0007.json and p_7.json are both frame 7"), std::string::npos) << message;
  EXPECT_NE(message.find("{:04d}"), std::string::npos) << message;
}

// --- Files written from frames -----------------------------------------------------------------------------------

TEST(OutputNaming, FrameWriterWritesVtkFilesUnderThePatternWithTheInputNumbers) {
  const fs::path dir = testing::fresh_temp_dir("frame_writer_vtk");
  Mesh mesh = testing::icosphere(2, 0.5, Vec3(0.1, 0.2, 0.3));
  ReceivedFrame frame;
  frame.index = 1;
  frame.encoding = v1::MESH_ENCODING_PLY;
  frame.bytes = write_ply(mesh, /*double_precision=*/true);
  frame.stats.set_vertices(static_cast<std::int64_t>(mesh.vertices.size()));

  FrameOutputOptions pattern = frame_output_options((dir / "seq" / "surface_{:05d}.vtu").string(), {}, "run");
  pattern.frame_numbers = {100, 101};
  FrameWriter writer(pattern);
  EXPECT_EQ(writer.write(frame), std::vector<fs::path>{dir / "seq" / "surface_00101.vtu"});
  EXPECT_TRUE(fs::exists(dir / "seq" / "stats.csv"));
  // Lossless frames keep their double positions in VTK files.
  EXPECT_EQ(read_particles(dir / "seq" / "surface_00101.vtu").positions, mesh.vertices);

  FrameOutputOptions both = frame_output_options((dir / "both").string(), {"vtk", "vtu"}, "run");
  both.frame_numbers = {100, 101};
  FrameWriter writer2(both);
  EXPECT_EQ(writer2.write(frame),
            (std::vector<fs::path>{dir / "both" / "frame_0101.vtk", dir / "both" / "frame_0101.vtu"}));
  EXPECT_EQ(read_particles(dir / "both" / "frame_0101.vtk").positions, mesh.vertices);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace surfacer::client
