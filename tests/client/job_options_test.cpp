// The job-type subcommands particles, optimize, active coat|morph|advect and isosurface --method: parsing (good and
// bad flags) and the JobSpec each builds, including the pending uploads of particle frames, start meshes and
// velocity grids. No server involved.
#include <gtest/gtest.h>

#include <bit>
#include <cstring>
#include <filesystem>
#include <sstream>

#include "client/cli.h"
#include "client/cli_jobs.h"
#include "client/job_fields.h"
#include "client/job_spec.h"
#include "client/particle_files.h"
#include "tests/support/cli_parse.h"
#include "tests/support/files.h"

namespace surfacer::client {
namespace {

namespace fs = std::filesystem;
using surfacer::testing::exit_code_of;
using surfacer::testing::fresh_temp_dir;
using surfacer::testing::parse_cli;
using surfacer::testing::ParsedCli;
using surfacer::testing::write_file;

JobOptions run_job(const ParsedCli& p) {
  EXPECT_TRUE(std::holds_alternative<Invocation>(p.result)) << p.err;
  if (!std::holds_alternative<Invocation>(p.result)) return {};
  return std::get<RunCommand>(std::get<Invocation>(p.result).command).job;
}

std::string joined(const std::vector<std::string>& args) {
  std::string text;
  for (const auto& a : args) text += a + " ";
  return text;
}

// Decodes float32 little-endian records.
std::vector<float> floats(const std::string& bytes) {
  std::vector<float> values(bytes.size() / 4);
  for (std::size_t i = 0; i < values.size(); ++i) {
    std::uint32_t bits = 0;
    for (int b = 3; b >= 0; --b) bits = (bits << 8) | static_cast<unsigned char>(bytes[4 * i + b]);
    values[i] = std::bit_cast<float>(bits);
  }
  return values;
}

constexpr const char* kBall = R"({"name": "ball", "root": {"sphere": {"radius": 0.5}}})";
constexpr const char* kCube = R"({"name": "cube", "root": {"box": {"half_size": {"x": 1, "y": 1, "z": 1}}}})";

// ---------------------------------------------------------------------------------------------------------------
// Parsing

TEST(JobOptions, IsosurfaceMethodTilesOrCubes) {
  for (const char* method : {"tiles", "cubes"}) {
    const JobOptions job =
        run_job(parse_cli({"run", "isosurface", "--scene", "a.json", "--method", method, "-o", "d"}));
    ASSERT_TRUE(job.spec.has_isosurface());
    EXPECT_EQ(job.spec.isosurface().method(),
              std::string(method) == "tiles" ? v1::POLYGONIZER_TILES : v1::POLYGONIZER_CUBES);
    EXPECT_EQ(job.scenes, (std::vector<fs::path>{"a.json"}));
  }
  EXPECT_EQ(run_job(parse_cli({"run", "isosurface", "--scene", "a.json", "-o", "d"})).spec.isosurface().method(),
            v1::POLYGONIZER_UNSPECIFIED);
}

TEST(JobOptions, ParticlesEveryFlag) {
  const ParsedCli p = parse_cli({"run",
                                 "particles",
                                 "--input",
                                 "f_{:04d}.xyz",
                                 "--input",
                                 "extra.ply",
                                 "--start",
                                 "2",
                                 "--end",
                                 "5",
                                 "--r-inner",
                                 "0.1",
                                 "--r-outer",
                                 "0.25",
                                 "--spacing-factor",
                                 "0.7",
                                 "--sweeps",
                                 "4,20,3",
                                 "--relaxation",
                                 "0.5",
                                 "--erosion",
                                 "0.2",
                                 "--unconstrained-polish",
                                 "--vertex-only-band",
                                 "--min-angle",
                                 "2.5",
                                 "--container-box",
                                 "0,0,0,1,2,3",
                                 "--container-scene",
                                 "solid.json",
                                 "--min-particles",
                                 "12",
                                 "--normals",
                                 "--raw",
                                 "-o",
                                 "out",
                                 "--format",
                                 "ply,obj",
                                 "--name",
                                 "splash"});
  const JobOptions job = run_job(p);
  ASSERT_TRUE(job.spec.has_particles());
  const v1::ParticlesJob& o = job.spec.particles();
  EXPECT_EQ(job.particles.inputs, (std::vector<std::string>{"f_{:04d}.xyz", "extra.ply"}));
  EXPECT_EQ(job.particles.start, 2);
  EXPECT_EQ(job.particles.end, 5);
  EXPECT_EQ(o.r_inner(), 0.1);
  EXPECT_FALSE(o.derive_r_inner());
  EXPECT_EQ(o.r_outer(), 0.25);
  EXPECT_EQ(o.spacing_factor(), 0.7);
  EXPECT_EQ(o.laplacian_sweeps(), 4);
  EXPECT_EQ(o.bilaplacian_sweeps(), 20);
  EXPECT_EQ(o.polish_sweeps(), 3);
  EXPECT_EQ(o.relaxation(), 0.5);
  EXPECT_EQ(o.erosion(), 0.2);
  EXPECT_TRUE(o.unconstrained_polish());
  EXPECT_TRUE(o.vertex_only_band());
  EXPECT_EQ(o.min_angle_degrees(), 2.5);
  EXPECT_EQ(o.container().box().min().x(), 0);
  EXPECT_EQ(o.container().box().max().z(), 3);
  EXPECT_EQ(job.container_scene, fs::path("solid.json"));
  EXPECT_EQ(o.min_particles_per_component(), 12);
  EXPECT_TRUE(job.spec.output().normals());
  EXPECT_EQ(job.spec.output().encoding(), v1::MESH_ENCODING_PLY);
  EXPECT_EQ(job.name, "splash");
  const auto& run = std::get<RunCommand>(std::get<Invocation>(p.result).command);
  EXPECT_EQ(run.output.dir, "out");
  EXPECT_EQ(run.output.formats, (std::vector<FileFormat>{FileFormat::kPly, FileFormat::kObj}));
}

// Flags are the proto's field names; the older spellings stay accepted and set the same fields.
TEST(JobOptions, ProtoNamesAndTheirAliasesSetTheSameFields) {
  const std::vector<std::string> base = {"run", "particles", "--input", "a.xyz", "--r-inner", "0.1", "-o", "d"};
  const std::vector<std::pair<std::vector<std::string>, std::vector<std::string>>> pairs = {
      {{"--min-angle-degrees", "3"}, {"--min-angle", "3"}},
      {{"--min-particles-per-component", "7"}, {"--min-particles", "7"}},
      {{"--laplacian-sweeps", "1", "--bilaplacian-sweeps", "2", "--polish-sweeps", "3"}, {"--sweeps", "1,2,3"}},
  };
  for (const auto& [proto, alias] : pairs) {
    std::vector<std::string> a = base, b = base;
    a.insert(a.end(), proto.begin(), proto.end());
    b.insert(b.end(), alias.begin(), alias.end());
    EXPECT_EQ(run_job(parse_cli(a)).spec.SerializeAsString(), run_job(parse_cli(b)).spec.SerializeAsString())
        << joined(a) << " vs " << joined(b);
  }
  const std::vector<std::string> o = {"run", "optimize", "--scene", "c.json", "-o", "d"};
  const std::vector<std::pair<std::vector<std::string>, std::vector<std::string>>> optimize = {
      {{"--max-iterations", "9"}, {"--iterations", "9"}},
      {{"--subdivision-threshold", "0.5"}, {"--subdivide", "0.5"}},
      {{"--polygonize-cells", "12", "--polygonize-method", "cubes"},
       {"--start-cells", "12", "--start-method", "cubes"}},
  };
  for (const auto& [proto, alias] : optimize) {
    std::vector<std::string> a = o, b = o;
    a.insert(a.end(), proto.begin(), proto.end());
    b.insert(b.end(), alias.begin(), alias.end());
    EXPECT_EQ(run_job(parse_cli(a)).spec.SerializeAsString(), run_job(parse_cli(b)).spec.SerializeAsString())
        << joined(a) << " vs " << joined(b);
  }
  // Every table field has a flag in --help under its proto name.
  for (const auto& [command, table] :
       std::vector<std::pair<std::vector<std::string>, JobTable>>{{{"run", "isosurface"}, JobTable::kIsosurface},
                                                                  {{"run", "particles"}, JobTable::kParticles},
                                                                  {{"run", "optimize"}, JobTable::kOptimize},
                                                                  {{"run", "active", "coat"}, JobTable::kActive},
                                                                  {{"run", "active", "coat"}, JobTable::kCoat},
                                                                  {{"run", "active", "morph"}, JobTable::kMorph},
                                                                  {{"run", "active", "advect"}, JobTable::kAdvect},
                                                                  {{"run", "particles"}, JobTable::kOutput},
                                                                  {{"run", "active", "morph"}, JobTable::kOutput}}) {
    std::vector<std::string> args = command;
    args.push_back("--help");
    const ParsedCli help = parse_cli(args);
    for (const JobField& field : job_fields(table)) {
      EXPECT_NE(help.out.find(cli_flag(spelling(field))), std::string::npos) << joined(args) << field.path;
    }
  }
}

TEST(JobOptions, ParticlesDeriveRInnerAndSubmit) {
  const JobOptions job = run_job(parse_cli({"run", "particles", "--input", "a.bgeo", "--derive-r-inner", "-o", "d"}));
  ASSERT_TRUE(job.spec.has_particles());
  EXPECT_TRUE(job.spec.particles().derive_r_inner());
  EXPECT_FALSE(job.spec.particles().has_r_inner());
  const ParsedCli s = parse_cli({"--server", "h:1", "submit", "particles", "--input", "a.bgeo", "--r-inner", "0.5"});
  ASSERT_TRUE(std::holds_alternative<Invocation>(s.result)) << s.err;
  const auto& submit = std::get<SubmitCommand>(std::get<Invocation>(s.result).command);
  ASSERT_TRUE(submit.job.spec.has_particles());
  EXPECT_EQ(submit.job.spec.particles().r_inner(), 0.5);
}

TEST(JobOptions, OptimizeEveryFlag) {
  const JobOptions job = run_job(parse_cli({"run",
                                            "optimize",
                                            "--scene",
                                            "cube.json",
                                            "--start-cells",
                                            "24",
                                            "--start-method",
                                            "tiles",
                                            "--start-bounds",
                                            "-2,-2,-2,2,2,2",
                                            "--iterations",
                                            "20",
                                            "--tolerance",
                                            "1e-4",
                                            "--snapshot-every",
                                            "5",
                                            "--flows",
                                            "d,n",
                                            "--c-d",
                                            "1",
                                            "--c-n",
                                            "0.5",
                                            "--c-t",
                                            "0.25",
                                            "--step-bound",
                                            "0.3",
                                            "--modified-flows",
                                            "--subdivide",
                                            "0.01",
                                            "--triangle-budget",
                                            "500000",
                                            "-o",
                                            "out"}));
  ASSERT_TRUE(job.spec.has_optimize());
  const v1::OptimizeJob& o = job.spec.optimize();
  EXPECT_EQ(job.scenes, (std::vector<fs::path>{"cube.json"}));
  EXPECT_FALSE(job.start_mesh);
  EXPECT_EQ(o.polygonize().cells(), 24);
  EXPECT_EQ(o.polygonize().method(), v1::POLYGONIZER_TILES);
  EXPECT_EQ(o.polygonize().bounds().min().x(), -2);
  EXPECT_EQ(o.polygonize().bounds().max().z(), 2);
  EXPECT_EQ(o.max_iterations(), 20);
  EXPECT_EQ(o.tolerance(), 1e-4);
  EXPECT_EQ(o.snapshot_every(), 5);
  EXPECT_TRUE(o.has_d_flow() && o.d_flow());
  EXPECT_TRUE(o.has_n_flow() && o.n_flow());
  EXPECT_TRUE(o.has_t_flow() && !o.t_flow());
  EXPECT_EQ(o.c_d(), 1);
  EXPECT_EQ(o.c_n(), 0.5);
  EXPECT_EQ(o.c_t(), 0.25);
  EXPECT_EQ(o.step_bound(), 0.3);
  EXPECT_TRUE(o.modified_flows());
  EXPECT_EQ(o.subdivision_threshold(), 0.01);
  EXPECT_EQ(o.triangle_budget(), 500000);

  const JobOptions mesh = run_job(parse_cli(
      {"run", "optimize", "--scene", "c.json", "--start-mesh", "m.drc", "--t-flow-iterations", "7", "-o", "out"}));
  ASSERT_TRUE(mesh.spec.has_optimize());
  EXPECT_EQ(mesh.start_mesh, fs::path("m.drc"));
  EXPECT_EQ(mesh.spec.optimize().t_flow_iterations(), 7);
  EXPECT_FALSE(mesh.spec.optimize().has_d_flow());
}

TEST(JobOptions, ActiveModes) {
  const JobOptions coat = run_job(parse_cli({"run",
                                             "active",
                                             "coat",
                                             "--input",
                                             "p_{}.xyz",
                                             "--start",
                                             "0",
                                             "--end",
                                             "9",
                                             "--kernel-radius",
                                             "0.3",
                                             "--iso",
                                             "0.4",
                                             "--substeps",
                                             "3",
                                             "--grid-spacing",
                                             "0.05",
                                             "--bounds=-1,-1,-1,1,1,1",
                                             "--alpha",
                                             "1",
                                             "--beta",
                                             "0.01",
                                             "--gamma",
                                             "0.5",
                                             "--delta",
                                             "2",
                                             "--polygonizer",
                                             "cubes",
                                             "-o",
                                             "d"}));
  ASSERT_TRUE(coat.spec.has_active());
  const v1::ActiveJob& a = coat.spec.active();
  ASSERT_EQ(a.mode_case(), v1::ActiveJob::kCoat);
  EXPECT_EQ(coat.particles.inputs, (std::vector<std::string>{"p_{}.xyz"}));
  EXPECT_EQ(coat.particles.end, 9);
  EXPECT_EQ(a.coat().kernel_radius(), 0.3);
  EXPECT_EQ(a.coat().iso(), 0.4);
  EXPECT_EQ(a.coat().substeps_per_frame(), 3);
  EXPECT_EQ(a.grid_spacing(), 0.05);
  EXPECT_EQ(a.bounds().min().y(), -1);
  EXPECT_EQ(a.bounds().max().z(), 1);
  EXPECT_EQ(a.alpha(), 1.0);
  EXPECT_EQ(a.beta(), 0.01);
  EXPECT_EQ(a.gamma(), 0.5);
  EXPECT_EQ(a.delta(), 2.0);
  EXPECT_EQ(a.polygonizer(), v1::POLYGONIZER_CUBES);
  const JobOptions cfl = run_job(parse_cli({"run", "active", "morph", "--from", "a.json", "--to", "b.json", "--cfl",
                                            "0.4", "--grid-spacing", "0.02", "-o", "d"}));
  EXPECT_EQ(cfl.spec.active().cfl(), 0.4);

  const JobOptions morph =
      run_job(parse_cli({"run", "active", "morph", "--from", "a.json", "--to", "b.json", "--tolerance", "1e-3",
                         "--max-frames", "50", "--frame-time", "0.1", "--grid-spacing", "0.02", "-o", "d"}));
  ASSERT_EQ(morph.spec.active().mode_case(), v1::ActiveJob::kMorph);
  const v1::ActiveMorph& m = morph.spec.active().morph();
  EXPECT_EQ(morph.scenes, (std::vector<fs::path>{"a.json", "b.json"}));
  EXPECT_EQ(m.tolerance(), 1e-3);
  EXPECT_EQ(m.max_frames(), 50);
  EXPECT_EQ(m.frame_time(), 0.1);

  const JobOptions enright =
      run_job(parse_cli({"run", "active", "advect", "--scene", "s.json", "--enright", "--period", "2",
                         "--frame-interval", "0.25", "--frames", "8", "--grid-spacing", "0.01", "-o", "d"}));
  ASSERT_EQ(enright.spec.active().mode_case(), v1::ActiveJob::kAdvect);
  const v1::ActiveAdvect& e = enright.spec.active().advect();
  EXPECT_EQ(enright.scenes, (std::vector<fs::path>{"s.json"}));
  EXPECT_EQ(e.enright().period(), 2.0);
  EXPECT_FALSE(enright.velocity_grid);
  EXPECT_EQ(e.frame_interval(), 0.25);
  EXPECT_EQ(e.frames(), 8);
  EXPECT_FALSE(e.error_compensation());
  const JobOptions compensated =
      run_job(parse_cli({"run", "active", "advect", "--scene", "s.json", "--enright", "--frame-interval", "0.25",
                         "--frames", "8", "--grid-spacing", "0.01", "--error-compensation", "-o", "d"}));
  EXPECT_TRUE(compensated.spec.active().advect().error_compensation());

  const JobOptions grid = run_job(parse_cli({"run",
                                             "active",
                                             "advect",
                                             "--scene",
                                             "s.json",
                                             "--velocity-grid",
                                             "v.raw",
                                             "--velocity-origin=-1,-2,-3",
                                             "--velocity-spacing",
                                             "0.5,0.25,0.125",
                                             "--velocity-dims",
                                             "5,9,17",
                                             "--frame-interval",
                                             "0.1",
                                             "--frames",
                                             "3",
                                             "--grid-spacing",
                                             "0.05",
                                             "-o",
                                             "d"}));
  const v1::VelocityGrid& g = grid.spec.active().advect().grid();
  EXPECT_EQ(grid.velocity_grid, fs::path("v.raw"));
  EXPECT_EQ(g.origin().x(), -1);
  EXPECT_EQ(g.origin().z(), -3);
  EXPECT_EQ(g.spacing().y(), 0.25);
  EXPECT_EQ(g.nx(), 5);
  EXPECT_EQ(g.ny(), 9);
  EXPECT_EQ(g.nz(), 17);
}

TEST(JobOptions, BadFlagsAreUsageErrorsNamingTheFlag) {
  const std::vector<std::string> p = {"run", "particles", "--input", "a.xyz", "-o", "d"};
  auto with = [](std::vector<std::string> base, const std::vector<std::string>& extra) {
    base.insert(base.end(), extra.begin(), extra.end());
    return base;
  };
  const std::vector<std::string> o = {"run", "optimize", "--scene", "c.json", "-o", "d"};
  const std::vector<std::string> morph = {"run", "active", "morph", "--from", "a.json", "--to", "b.json", "-o", "d"};
  const std::vector<std::string> advect = {"run", "active",   "advect", "--scene",        "s.json", "--frame-interval",
                                           "0.1", "--frames", "3",      "--grid-spacing", "0.1",    "-o",
                                           "d"};
  const std::vector<std::pair<std::vector<std::string>, std::string>> cases = {
      {with(p, {"--r-inner", "0.1", "--derive-r-inner"}), "--derive-r-inner"},
      {with(p, {"--r-inner", "abc"}), "--r-inner"},
      {with(p, {"--r-inner", "-1"}), "--r-inner"},
      {with(p, {"--r-inner", "0.1", "--r-outer", "0.05"}), "--r-outer"},
      {with(p, {"--r-inner", "0.1", "--sweeps", "5,25"}), "--sweeps"},
      {with(p, {"--r-inner", "0.1", "--sweeps", "5,x,5"}), "--sweeps"},
      {with(p, {"--r-inner", "0.1", "--sweeps", "5,2.5,5"}), "--sweeps"},
      {with(p, {"--r-inner", "0.1", "--sweeps", "5,-1,5"}), "--sweeps"},
      {with(p, {"--r-inner", "0.1", "--container-box", "0,0,0,1,1"}), "--container-box"},
      {with(p, {"--r-inner", "0.1", "--container-box", "1,0,0,0,1,1"}), "--container-box"},
      {with(p, {"--r-inner", "0.1", "--min-particles", "-3"}), "--min-particles"},
      {with(p, {"--r-inner", "0.1", "--spacing-factor", "0"}), "--spacing-factor"},
      {with(p, {"--r-inner", "0.1", "--raw", "--quantization-bits", "10"}), "--quantization-bits"},
      {{"run", "particles", "--r-inner", "0.1", "-o", "d"}, "--input"},
      {{"run", "particles", "--input", "a.xyz", "--r-inner", "0.1"}, "-o DIR"},
      {with(o, {"--start-mesh", "m.ply", "--start-cells", "10"}), "--start-cells"},
      {with(o, {"--start-mesh", "m.ply", "--start-method", "cubes"}), "--start-method"},
      {with(o, {"--start-method", "hexes"}), "--start-method"},
      {with(o, {"--start-bounds", "0,0,0,1,1,-1"}), "--start-bounds"},
      {with(o, {"--flows", "d,x"}), "--flows"},
      {with(o, {"--flows", "d,n", "--t-flow-iterations", "5"}), "--t-flow-iterations"},
      {with(o, {"--iterations", "-1"}), "--iterations"},
      {with(o, {"--c-d", "1.5"}), "--c-d"},  // core's range (0, 1], checked before anything is submitted
      {with(o, {"--snapshot-every", "many"}), "--snapshot-every"},
      {with(o, {"--triangle-budget", "-5"}), "--triangle-budget"},
      {{"run", "optimize", "--iterations", "5", "-o", "d"}, "--scene"},
      {morph, "--grid-spacing"},
      {with(morph, {"--grid-spacing", "0"}), "--grid-spacing"},
      {with(morph, {"--grid-spacing", "0.1", "--max-frames", "0"}), "--max-frames"},
      {with(morph, {"--grid-spacing", "0.1", "--polygonizer", "hexes"}), "--polygonizer"},
      {with(morph, {"--grid-spacing", "0.1", "--beta", "-1"}), "--beta"},
      {{"run", "active", "morph", "--from", "a.json", "--grid-spacing", "0.1", "-o", "d"}, "--to"},
      {advect, "--enright"},  // no velocity field
      {with(advect, {"--enright", "--velocity-grid", "v.raw"}), "--velocity-grid"},
      {with(advect, {"--period", "3"}), "--period"},
      {with(advect, {"--velocity-grid", "v.raw"}), "--velocity-origin"},
      {with(advect, {"--velocity-grid", "v.raw", "--velocity-origin", "0,0,0", "--velocity-spacing", "1,1,1",
                     "--velocity-dims", "1,4,4"}),
       "--velocity-dims"},
      {with(advect, {"--velocity-grid", "v.raw", "--velocity-origin", "0,0", "--velocity-spacing", "1,1,1",
                     "--velocity-dims", "4,4,4"}),
       "--velocity-origin"},
      {with(advect, {"--velocity-grid", "v.raw", "--velocity-origin", "0,0,0", "--velocity-spacing", "1,0,1",
                     "--velocity-dims", "4,4,4"}),
       "--velocity-spacing"},
      {{"run", "active", "advect", "--scene", "s.json", "--enright", "--frame-interval", "0.1", "--grid-spacing", "0.1",
        "-o", "d"},
       "--frames"},
      {{"run", "active", "coat", "--input", "a.xyz", "--grid-spacing", "0.1", "-o", "d"}, "--kernel-radius"},
      {{"run", "active", "--grid-spacing", "0.1", "-o", "d"}, "coat"},  // no mode
      {{"run", "isosurface", "--scene", "a.json", "--method", "hexes", "-o", "d"}, "--method"},
      {{"run", "particles", "--input", "a.xyz", "--r-inner", "0.1", "-o", "d", "isosurface", "--scene", "a"},
       "isosurface"},
  };
  for (const auto& [args, flag] : cases) {
    const ParsedCli r = parse_cli(args);
    EXPECT_EQ(exit_code_of(r), ExitCode::kUsage) << joined(args);
    EXPECT_NE(r.err.find("surfacer: error: "), std::string::npos) << joined(args) << "\n" << r.err;
    EXPECT_NE(r.err.find(flag), std::string::npos) << joined(args) << "\nexpected the message to name " << flag << ":\n"
                                                   << r.err;
  }
}

TEST(JobOptions, EveryNewSubcommandHasHelpWithAnExample) {
  const std::vector<std::vector<std::string>> commands = {{"run", "particles"},
                                                          {"submit", "particles"},
                                                          {"run", "optimize"},
                                                          {"submit", "optimize"},
                                                          {"run", "active"},
                                                          {"submit", "active"},
                                                          {"run", "active", "coat"},
                                                          {"run", "active", "morph"},
                                                          {"run", "active", "advect"},
                                                          {"submit", "active", "coat"},
                                                          {"submit", "active", "morph"},
                                                          {"submit", "active", "advect"},
                                                          {"run", "isosurface"}};
  for (auto args : commands) {
    const std::string name = joined(args);
    args.push_back("--help");
    const ParsedCli h = parse_cli(args);
    EXPECT_EQ(exit_code_of(h), ExitCode::kSuccess) << name;
    EXPECT_NE(h.out.find("Example"), std::string::npos) << name << "\n" << h.out;
    EXPECT_NE(h.out.find("surfacer " + args[0] + " "), std::string::npos) << name << "\n" << h.out;
  }
  const ParsedCli particles = parse_cli({"run", "particles", "--help"});
  for (const char* flag :
       {"--input", "--start", "--end", "--r-inner", "--derive-r-inner", "--r-outer", "--spacing-factor", "--sweeps",
        "--relaxation", "--erosion", "--container-box", "--container-scene", "--min-particles", "--min-angle",
        "--unconstrained-polish", "--vertex-only-band", "--format", "--normals", "--raw"}) {
    EXPECT_NE(particles.out.find(flag), std::string::npos) << flag;
  }
  const ParsedCli advect = parse_cli({"run", "active", "advect", "--help"});
  for (const char* flag :
       {"--enright", "--period", "--velocity-grid", "--velocity-origin", "--velocity-spacing", "--velocity-dims",
        "--frame-interval", "--frames", "--grid-spacing", "--alpha", "--cfl", "--error-compensation"}) {
    EXPECT_NE(advect.out.find(flag), std::string::npos) << flag;
  }
}

// The table's values from text: the syntax of each proto type, errors naming the spelling given.
TEST(JobOptions, TableValuesFromText) {
  const auto field = [](JobTable table, const std::string& path) -> const JobField& { return job_field(table, path); };
  EXPECT_THROW(field(JobTable::kOutput, "no_such_field"), std::logic_error);
  v1::JobSpec spec;
  std::map<std::string, std::string> names;
  set_job_field(spec, JobTable::kIsosurface, field(JobTable::kIsosurface, "bounds"), "-1,-2,-3,1,2,3", "--bounds",
                names);
  EXPECT_EQ(spec.isosurface().bounds().min().y(), -2);
  EXPECT_EQ(spec.isosurface().bounds().max().z(), 3);
  EXPECT_EQ(names.at("spec.isosurface.bounds"), "--bounds");
  set_job_field(spec, JobTable::kIsosurface, field(JobTable::kIsosurface, "cells"), "40", "--cells", names);
  EXPECT_EQ(spec.isosurface().cells(), 40);
  // A second member of a oneof the user set is refused, naming both.
  try {
    set_job_field(spec, JobTable::kIsosurface, field(JobTable::kIsosurface, "cell_size"), "0.1", "--cell-size", names);
    ADD_FAILURE() << "cells and cell_size were both taken";
  } catch (const CliError& e) {
    EXPECT_NE(std::string(e.what()).find("--cells"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("--cell-size"), std::string::npos) << e.what();
  }
  const JobField& flows = field(JobTable::kOptimize, "flows");
  set_job_field(spec, JobTable::kOptimize, flows, "t", "--flows", names);
  EXPECT_FALSE(spec.optimize().d_flow());
  EXPECT_FALSE(spec.optimize().n_flow());
  EXPECT_TRUE(spec.optimize().t_flow());
  for (const char* bad : {"", "d,x", "dn"}) {
    EXPECT_THROW(set_job_field(spec, JobTable::kOptimize, flows, bad, "--flows", names), CliError) << bad;
  }
  const JobField& box = field(JobTable::kParticles, "container.box");
  for (const char* bad : {"1,2,", "1,nan,3,4,5,6", "1,2,3,4,5", "a,b,c,d,e,f"}) {
    try {
      set_job_field(spec, JobTable::kParticles, box, bad, "container_box", names);
      ADD_FAILURE() << bad;
    } catch (const CliError& e) {
      EXPECT_EQ(e.code(), ExitCode::kUsage);
      EXPECT_NE(std::string(e.what()).find("container_box"), std::string::npos) << e.what();
    }
  }
  set_job_field(spec, JobTable::kParticles, box, "0,0,0,1,1,1", "container_box", names);  // as Python names it
  const JobField& cells = field(JobTable::kIsosurface, "cells");
  for (const char* bad : {"1.5", "x", "99999999999"}) {
    EXPECT_THROW(set_job_field(spec, JobTable::kIsosurface, cells, bad, "--cells", names), CliError) << bad;
  }
  EXPECT_THROW(set_job_field(spec, JobTable::kIsosurface, field(JobTable::kIsosurface, "method"), "unspecified",
                             "--method", names),
               CliError);
  // An enum takes its values' short names and the table's words for them: encoding's "raw" is the proto's PLY.
  const JobField& encoding = field(JobTable::kOutput, "encoding");
  for (const auto& [text, value] :
       std::vector<std::pair<std::string, v1::MeshEncoding>>{{"raw", v1::MESH_ENCODING_PLY},
                                                             {"ply", v1::MESH_ENCODING_PLY},
                                                             {"draco", v1::MESH_ENCODING_DRACO},
                                                             {"draco_pieces", v1::MESH_ENCODING_DRACO_PIECES},
                                                             {"meshopt", v1::MESH_ENCODING_MESHOPT}}) {
    set_job_field(spec, JobTable::kOutput, encoding, text, "--encoding", names);
    EXPECT_EQ(spec.output().encoding(), value) << text;
  }
  try {
    set_job_field(spec, JobTable::kOutput, encoding, "zstd", "encoding", names);
    ADD_FAILURE() << "zstd was taken";
  } catch (const CliError& e) {
    EXPECT_EQ(std::string(e.what()), "encoding must be raw or draco or ply or draco_pieces or meshopt, not zstd");
  }
  EXPECT_EQ(python_type(JobTable::kOutput, encoding),
            "Literal[\"draco\", \"ply\", \"draco_pieces\", \"meshopt\", \"raw\"]");
  // Every field of spec.output is in the output table: a front end cannot miss one.
  const auto* output = v1::OutputOptions::descriptor();
  for (int i = 0; i < output->field_count(); ++i) {
    EXPECT_NO_THROW(field(JobTable::kOutput, output->field(i)->name())) << output->field(i)->name();
  }
  // Spellings: flag and keyword of a path and of an alias.
  EXPECT_EQ(cli_flag("container.box"), "--container-box");
  EXPECT_EQ(keyword("container.box"), "container_box");
  EXPECT_EQ(cli_flag("min-angle"), "--min-angle");
  EXPECT_EQ(keyword("min-angle"), "min_angle");
  EXPECT_EQ(name_of_field(names, "spec.particles.container.box.min.x", false), "container_box");
  EXPECT_EQ(name_of_field({}, "spec.particles.min_angle_degrees", false), "--min-angle-degrees");
  EXPECT_EQ(name_of_field({}, "spec.active.coat.substeps_per_frame", true), "substeps_per_frame");
  EXPECT_EQ(name_of_field({}, "spec.particles.laplacian_sweeps", false), "--laplacian-sweeps");
}

// ---------------------------------------------------------------------------------------------------------------
// Sequences

TEST(ParticleInputs, PatternsExpandOverTheFilesPresentOrTheGivenRange) {
  const fs::path dir = fresh_temp_dir("jobopts_seq");
  for (int i : {3, 4, 5, 6}) write_file(dir / ("f_000" + std::to_string(i) + ".xyz"), "0 0 0\n");
  write_file(dir / "f_7.xyz", "0 0 0\n");  // not a {:04d} name: ignored
  write_file(dir / "single.xyz", "0 0 0\n");
  const std::string pattern = (dir / "f_{:04d}.xyz").string();

  ParticleInputOptions all{{pattern}, {}, {}};
  auto files = expand_particle_inputs(all);
  ASSERT_EQ(files.size(), 4u);
  EXPECT_EQ(files.front(), dir / "f_0003.xyz");
  EXPECT_EQ(files.back(), dir / "f_0006.xyz");

  ParticleInputOptions ranged{{pattern, (dir / "single.xyz").string()}, 4, 5};
  files = expand_particle_inputs(ranged);
  EXPECT_EQ(files, (std::vector<fs::path>{dir / "f_0004.xyz", dir / "f_0005.xyz", dir / "single.xyz"}));

  ParticleInputOptions from{{pattern}, 5, {}};
  EXPECT_EQ(expand_particle_inputs(from).size(), 2u);

  auto usage_message = [](const ParticleInputOptions& options) {
    try {
      expand_particle_inputs(options);
    } catch (const CliError& e) {
      EXPECT_EQ(e.code(), ExitCode::kUsage);
      return std::string(e.what());
    }
    ADD_FAILURE() << "no error";
    return std::string();
  };
  // A gap (frame 2 is missing) names the first missing file.
  EXPECT_NE(usage_message({{pattern}, 2, 4}).find("f_0002.xyz"), std::string::npos);
  EXPECT_NE(usage_message({{(dir / "g_{}.xyz").string()}, {}, {}}).find("g_{}.xyz"), std::string::npos);
  EXPECT_NE(usage_message({{(dir / "single.xyz").string()}, 0, 3}).find("--start/--end"), std::string::npos);
  EXPECT_NE(usage_message({{(dir / "nope.xyz").string()}, {}, {}}).find("nope.xyz"), std::string::npos);
  EXPECT_NE(usage_message({{pattern}, 6, 3}).find("--end"), std::string::npos);
  EXPECT_NE(usage_message({{(dir / "f_{:04q}.xyz").string()}, 0, 1}).find("--input"), std::string::npos);
  EXPECT_TRUE(is_sequence_pattern("a_{}.bgeo"));
  EXPECT_FALSE(is_sequence_pattern("a_{{literal}}.bgeo"));
  fs::remove_all(dir);
}

TEST(ParticleInputs, RecordsAreFloat32WithOrWithoutRadius) {
  const fs::path dir = fresh_temp_dir("jobopts_records");
  write_file(dir / "plain.xyz", "# a comment\n1 2 3\n-0.5, 0.25, 8\n");
  write_file(dir / "radius.xyz", "1 2 3 0.5\n4 5 6 0.25\n");
  ParticleRecords plain = read_particle_records(dir / "plain.xyz");
  EXPECT_FALSE(plain.with_radius);
  EXPECT_EQ(plain.count, 2);
  EXPECT_EQ(floats(plain.bytes), (std::vector<float>{1, 2, 3, -0.5f, 0.25f, 8}));
  ParticleRecords radius = read_particle_records(dir / "radius.xyz");
  EXPECT_TRUE(radius.with_radius);
  EXPECT_EQ(floats(radius.bytes), (std::vector<float>{1, 2, 3, 0.5f, 4, 5, 6, 0.25f}));

  write_file(dir / "bad.xyz", "0 0 0\n1 1 1\n2 two 2\n");
  write_file(dir / "empty.xyz", "# nothing\n");
  write_file(dir / "huge.xyz", "0 0 1e300\n");
  for (const auto& [name, expected] : std::vector<std::pair<std::string, std::string>>{
           {"bad.xyz", "line 3"}, {"empty.xyz", "no particles"}, {"huge.xyz", "float32"}, {"missing.xyz", ""}}) {
    try {
      read_particle_records(dir / name);
      ADD_FAILURE() << name << " was read";
    } catch (const CliError& e) {
      EXPECT_EQ(e.code(), ExitCode::kUsage) << e.what();
      EXPECT_NE(std::string(e.what()).find(name), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
    }
  }
  fs::remove_all(dir);
}

// ---------------------------------------------------------------------------------------------------------------
// Specs

TEST(JobSpecs, ParticlesFieldsAndOneUploadPerFrame) {
  const fs::path dir = fresh_temp_dir("jobopts_particles_spec");
  write_file(dir / "p_0.xyz", "0 0 0\n1 0 0\n");
  write_file(dir / "p_1.xyz", "0 0 0 0.1\n");
  write_file(dir / "last.xyz", "5 5 5\n6 6 6\n7 7 7\n");
  write_file(dir / "solid.json", kCube);
  JobOptions options = run_job(parse_cli({"run",
                                          "particles",
                                          "--input",
                                          (dir / "p_{}.xyz").string(),
                                          "--input",
                                          (dir / "last.xyz").string(),
                                          "--r-inner",
                                          "0.1",
                                          "--r-outer",
                                          "0.3",
                                          "--spacing-factor",
                                          "0.75",
                                          "--sweeps",
                                          "3,21,2",
                                          "--relaxation",
                                          "0.55",
                                          "--erosion",
                                          "0.05",
                                          "--unconstrained-polish",
                                          "--vertex-only-band",
                                          "--min-angle",
                                          "0",
                                          "--container-box=-1,-1,-1,8,8,8",
                                          "--container-scene",
                                          (dir / "solid.json").string(),
                                          "--min-particles",
                                          "4",
                                          "--normals",
                                          "-o",
                                          "d"}));
  PreparedJob prepared = prepare_job(options);
  v1::JobSpec& spec = prepared.spec;
  ASSERT_TRUE(spec.has_particles());
  const v1::ParticlesJob& job = spec.particles();
  EXPECT_EQ(job.frames_size(), 3);
  EXPECT_DOUBLE_EQ(job.r_inner(), 0.1);
  EXPECT_FALSE(job.derive_r_inner());
  EXPECT_DOUBLE_EQ(job.r_outer(), 0.3);
  EXPECT_DOUBLE_EQ(job.spacing_factor(), 0.75);
  EXPECT_EQ(job.laplacian_sweeps(), 3);
  EXPECT_EQ(job.bilaplacian_sweeps(), 21);
  EXPECT_EQ(job.polish_sweeps(), 2);
  EXPECT_DOUBLE_EQ(job.relaxation(), 0.55);
  EXPECT_DOUBLE_EQ(job.erosion(), 0.05);
  EXPECT_TRUE(job.unconstrained_polish());
  EXPECT_TRUE(job.vertex_only_band());
  ASSERT_TRUE(job.has_min_angle_degrees());
  EXPECT_EQ(job.min_angle_degrees(), 0.0);
  EXPECT_DOUBLE_EQ(job.container().box().max().y(), 8);
  EXPECT_DOUBLE_EQ(job.container().solid().root().box().half_size().x(), 1);
  EXPECT_EQ(job.min_particles_per_component(), 4);
  EXPECT_TRUE(spec.output().normals());
  EXPECT_EQ(spec.name(), "p_0 (+2 more frames)");

  ASSERT_EQ(prepared.uploads.size(), 3u);
  const std::vector<std::pair<bool, std::size_t>> expected = {{false, 24}, {true, 16}, {false, 36}};
  for (int i = 0; i < 3; ++i) {
    const PendingUpload& upload = prepared.uploads[i];
    EXPECT_EQ(upload.frame, i);
    EXPECT_TRUE(job.frames(i).upload_id().empty());
    UploadData data = upload.read(spec, {});
    EXPECT_EQ(job.frames(i).with_radius(), expected[i].first) << i;
    EXPECT_EQ(data.bytes.size(), expected[i].second) << i;
    EXPECT_FALSE(data.file);
    upload.set_id(spec, "u-" + std::to_string(i));
    EXPECT_EQ(job.frames(i).upload_id(), "u-" + std::to_string(i));
  }
  EXPECT_EQ(prepared.uploads[2].read(spec, {}).particles, 3);
  EXPECT_NE(prepared.uploads[2].description.find("last.xyz"), std::string::npos);

  options =
      run_job(parse_cli({"run", "particles", "--input", (dir / "last.xyz").string(), "--derive-r-inner", "-o", "d"}));
  const v1::ParticlesJob derived = prepare_job(options).spec.particles();
  EXPECT_TRUE(derived.derive_r_inner());
  EXPECT_FALSE(derived.has_r_inner());
  EXPECT_FALSE(derived.has_bilaplacian_sweeps());  // the server's default

  // Neither r_inner nor derive_r_inner: a frame with radii is surfaced with them, one without is refused as it is
  // read, naming the flag and the file (core's one statement of the rule).
  options = run_job(parse_cli({"run", "particles", "--input", (dir / "p_{}.xyz").string(), "-o", "d"}));
  prepared = prepare_job(options);
  ASSERT_EQ(prepared.uploads.size(), 2u);
  EXPECT_NO_THROW(prepared.uploads[1].read(prepared.spec, {}));
  try {
    prepared.uploads[0].read(prepared.spec, {});
    ADD_FAILURE() << "a frame without radii was taken without r_inner";
  } catch (const CliError& e) {
    EXPECT_EQ(e.code(), ExitCode::kUsage);
    const std::string what = e.what();
    EXPECT_NE(what.find("--r-inner"), std::string::npos) << what;
    EXPECT_NE(what.find("derive_r_inner"), std::string::npos) << what;
    EXPECT_NE(what.find("p_0.xyz"), std::string::npos) << what;
  }
  fs::remove_all(dir);
}

TEST(JobSpecs, OptimizeFromPolygonizationOrUploadedMesh) {
  const fs::path dir = fresh_temp_dir("jobopts_optimize_spec");
  write_file(dir / "cube.json", kCube);
  const std::string cube = (dir / "cube.json").string();
  JobOptions options = run_job(parse_cli({"run",
                                          "optimize",
                                          "--scene",
                                          cube,
                                          "--start-cells",
                                          "24",
                                          "--start-method",
                                          "tiles",
                                          "--start-bounds=-2,-2,-2,2,2,2",
                                          "--iterations",
                                          "20",
                                          "--tolerance",
                                          "1e-5",
                                          "--snapshot-every",
                                          "5",
                                          "--flows",
                                          "d,n",
                                          "--c-d",
                                          "1",
                                          "--c-n",
                                          "0.5",
                                          "--c-t",
                                          "0.1",
                                          "--step-bound",
                                          "0.2",
                                          "--modified-flows",
                                          "--subdivide",
                                          "0.02",
                                          "--triangle-budget",
                                          "100000",
                                          "-o",
                                          "d"}));
  PreparedJob prepared = prepare_job(options);
  EXPECT_TRUE(prepared.uploads.empty());
  const v1::OptimizeJob& job = prepared.spec.optimize();
  EXPECT_DOUBLE_EQ(job.scene().root().box().half_size().z(), 1);
  ASSERT_EQ(job.start_case(), v1::OptimizeJob::kPolygonize);
  EXPECT_EQ(job.polygonize().method(), v1::POLYGONIZER_TILES);
  EXPECT_EQ(job.polygonize().cells(), 24);
  EXPECT_DOUBLE_EQ(job.polygonize().bounds().min().x(), -2);
  EXPECT_EQ(job.max_iterations(), 20);
  EXPECT_DOUBLE_EQ(job.tolerance(), 1e-5);
  EXPECT_EQ(job.snapshot_every(), 5);
  EXPECT_TRUE(job.has_d_flow() && job.d_flow());
  EXPECT_TRUE(job.has_n_flow() && job.n_flow());
  EXPECT_TRUE(job.has_t_flow() && !job.t_flow());
  EXPECT_DOUBLE_EQ(job.c_d(), 1);
  EXPECT_DOUBLE_EQ(job.c_n(), 0.5);
  EXPECT_DOUBLE_EQ(job.c_t(), 0.1);
  EXPECT_DOUBLE_EQ(job.step_bound(), 0.2);
  EXPECT_TRUE(job.modified_flows());
  EXPECT_FALSE(job.has_t_flow_iterations());
  EXPECT_DOUBLE_EQ(job.subdivision_threshold(), 0.02);
  EXPECT_EQ(job.triangle_budget(), 100000);
  EXPECT_EQ(prepared.spec.name(), "cube");

  // Defaults: an empty Polygonize (the server's start), flows unset.
  options = run_job(parse_cli({"run", "optimize", "--scene", cube, "-o", "d"}));
  const v1::OptimizeJob plain = prepare_job(options).spec.optimize();
  EXPECT_EQ(plain.start_case(), v1::OptimizeJob::kPolygonize);
  EXPECT_EQ(plain.polygonize().method(), v1::POLYGONIZER_UNSPECIFIED);
  EXPECT_FALSE(plain.has_d_flow());
  EXPECT_FALSE(plain.has_max_iterations());

  // A start mesh is one upload of the file's bytes as they are.
  const std::string obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
  write_file(dir / "tet.obj", obj);
  const auto with_mesh = [&](const fs::path& mesh) {
    return run_job(parse_cli({"run", "optimize", "--scene", cube, "--start-mesh", mesh.string(), "-o", "d"}));
  };
  prepared = prepare_job(with_mesh(dir / "tet.obj"));
  ASSERT_EQ(prepared.uploads.size(), 1u);
  UploadData data = prepared.uploads[0].read(prepared.spec, {});
  EXPECT_EQ(data.bytes, obj);
  EXPECT_EQ(data.name, "tet.obj");
  prepared.uploads[0].set_id(prepared.spec, "u-mesh");
  EXPECT_EQ(prepared.spec.optimize().mesh_upload_id(), "u-mesh");

  // A bad mesh fails when read (before any job is queued), naming the file and the line.
  write_file(dir / "bad.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n");
  prepared = prepare_job(with_mesh(dir / "bad.obj"));
  try {
    prepared.uploads[0].read(prepared.spec, {});
    ADD_FAILURE() << "bad.obj was accepted";
  } catch (const CliError& e) {
    EXPECT_EQ(e.code(), ExitCode::kUsage);
    EXPECT_NE(std::string(e.what()).find("bad.obj"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("4"), std::string::npos) << e.what();
  }
  // Missing file or unknown extension: at once.
  EXPECT_THROW(prepare_job(with_mesh(dir / "none.ply")), CliError);
  write_file(dir / "mesh.stl", "solid");
  EXPECT_THROW(prepare_job(with_mesh(dir / "mesh.stl")), CliError);
  fs::remove_all(dir);
}

TEST(JobSpecs, ActiveModes) {
  const fs::path dir = fresh_temp_dir("jobopts_active_spec");
  write_file(dir / "ball.json", kBall);
  write_file(dir / "cube.json", kCube);
  write_file(dir / "c_0.xyz", "0 0 0\n");
  write_file(dir / "c_1.xyz", "0.1 0 0\n0.2 0 0\n");
  const std::string ball = (dir / "ball.json").string();
  const std::vector<std::string> common = {"--grid-spacing",
                                           "0.05",
                                           "--bounds=-1,-1,-1,1,1,1",
                                           "--alpha",
                                           "1",
                                           "--beta",
                                           "0.02",
                                           "--gamma",
                                           "0.3",
                                           "--delta",
                                           "0.4",
                                           "-o",
                                           "d"};
  const auto active = [&](std::vector<std::string> args) {
    args.insert(args.begin(), {"run", "active"});
    args.insert(args.end(), common.begin(), common.end());
    return run_job(parse_cli(args));
  };

  PreparedJob prepared = prepare_job(active({"coat", "--input", (dir / "c_{}.xyz").string(), "--kernel-radius", "0.3",
                                             "--iso", "0.45", "--substeps", "4", "--polygonizer", "tiles"}));
  const v1::ActiveJob& job = prepared.spec.active();
  EXPECT_DOUBLE_EQ(job.grid_spacing(), 0.05);
  EXPECT_DOUBLE_EQ(job.bounds().max().x(), 1);
  EXPECT_DOUBLE_EQ(job.alpha(), 1);
  EXPECT_DOUBLE_EQ(job.beta(), 0.02);
  EXPECT_DOUBLE_EQ(job.gamma(), 0.3);
  EXPECT_DOUBLE_EQ(job.delta(), 0.4);
  EXPECT_EQ(job.polygonizer(), v1::POLYGONIZER_TILES);
  ASSERT_EQ(job.mode_case(), v1::ActiveJob::kCoat);
  EXPECT_EQ(job.coat().frames_size(), 2);
  EXPECT_DOUBLE_EQ(job.coat().kernel_radius(), 0.3);
  EXPECT_DOUBLE_EQ(job.coat().iso(), 0.45);
  EXPECT_EQ(job.coat().substeps_per_frame(), 4);
  ASSERT_EQ(prepared.uploads.size(), 2u);
  EXPECT_EQ(prepared.uploads[1].read(prepared.spec, {}).bytes.size(), 24u);
  prepared.uploads[1].set_id(prepared.spec, "u-c1");
  EXPECT_EQ(job.coat().frames(1).upload_id(), "u-c1");

  prepared = prepare_job(active({"morph", "--from", ball, "--to", (dir / "cube.json").string(), "--tolerance", "0.01",
                                 "--max-frames", "12", "--frame-time", "0.5", "--cfl", "0.5"}));
  EXPECT_TRUE(prepared.uploads.empty());
  const v1::ActiveMorph& m = prepared.spec.active().morph();
  EXPECT_DOUBLE_EQ(m.from().root().sphere().radius(), 0.5);
  EXPECT_TRUE(m.to().root().has_box());
  EXPECT_DOUBLE_EQ(m.tolerance(), 0.01);
  EXPECT_EQ(m.max_frames(), 12);
  EXPECT_DOUBLE_EQ(m.frame_time(), 0.5);
  EXPECT_DOUBLE_EQ(prepared.spec.active().cfl(), 0.5);
  EXPECT_EQ(prepared.spec.active().polygonizer(), v1::POLYGONIZER_UNSPECIFIED);

  // alpha has no target to track in advect: refused with the server's message.
  std::vector<std::string> advect = {"advect", "--scene",          ball,   "--enright", "--period",
                                     "3",      "--frame-interval", "0.25", "--frames",  "6"};
  const ParsedCli tracked = parse_cli([&] {
    std::vector<std::string> args = {"run", "active"};
    args.insert(args.end(), advect.begin(), advect.end());
    args.insert(args.end(), common.begin(), common.end());
    return args;
  }());
  EXPECT_EQ(exit_code_of(tracked), ExitCode::kUsage);
  EXPECT_NE(tracked.err.find("spec.active.alpha"), std::string::npos) << tracked.err;

  const auto advect_job = [&](std::vector<std::string> args) {
    args.insert(args.begin(), {"run", "active", "advect", "--scene", ball, "--frame-interval", "0.25", "--frames", "6",
                               "--grid-spacing", "0.05", "-o", "d"});
    return run_job(parse_cli(args));
  };
  prepared = prepare_job(advect_job({"--enright", "--period", "3"}));
  EXPECT_TRUE(prepared.uploads.empty());
  const v1::ActiveAdvect& e = prepared.spec.active().advect();
  ASSERT_EQ(e.velocity_case(), v1::ActiveAdvect::kEnright);
  EXPECT_DOUBLE_EQ(e.enright().period(), 3);
  EXPECT_DOUBLE_EQ(e.frame_interval(), 0.25);
  EXPECT_EQ(e.frames(), 6);
  EXPECT_DOUBLE_EQ(e.shape().root().sphere().radius(), 0.5);

  // A velocity grid: its size is checked against the dimensions at once; the file is streamed when uploaded.
  write_file(dir / "v.raw", std::string(3 * 3 * 2 * 12, '\0'));
  const std::vector<std::string> grid_flags = {"--velocity-grid",
                                               (dir / "v.raw").string(),
                                               "--velocity-origin=-1,-1,-1",
                                               "--velocity-spacing",
                                               "1,1,1",
                                               "--velocity-dims",
                                               "3,3,2"};
  prepared = prepare_job(advect_job(grid_flags));
  const v1::VelocityGrid& grid = prepared.spec.active().advect().grid();
  EXPECT_EQ(grid.nx(), 3);
  EXPECT_EQ(grid.nz(), 2);
  EXPECT_DOUBLE_EQ(grid.origin().y(), -1);
  EXPECT_DOUBLE_EQ(grid.spacing().z(), 1);
  ASSERT_EQ(prepared.uploads.size(), 1u);
  const UploadData data = prepared.uploads[0].read(prepared.spec, {});
  EXPECT_EQ(data.file, dir / "v.raw");
  EXPECT_EQ(data.file_bytes, 216u);
  prepared.uploads[0].set_id(prepared.spec, "u-v");
  EXPECT_EQ(prepared.spec.active().advect().grid().upload_id(), "u-v");
  write_file(dir / "v.raw", std::string(100, '\0'));
  try {
    prepare_job(advect_job(grid_flags));
    ADD_FAILURE() << "a 100-byte grid passed";
  } catch (const CliError& err) {
    EXPECT_EQ(err.code(), ExitCode::kUsage);
    EXPECT_NE(std::string(err.what()).find("216 bytes"), std::string::npos) << err.what();
  }
  fs::remove_all(dir);
}

TEST(JobSpecs, IsosurfaceMethod) {
  const fs::path dir = fresh_temp_dir("jobopts_iso_method");
  write_file(dir / "ball.json", kBall);
  const auto iso = [&](std::vector<std::string> extra) {
    std::vector<std::string> args = {"run", "isosurface", "--scene", (dir / "ball.json").string(), "-o", "d"};
    args.insert(args.end(), extra.begin(), extra.end());
    return prepare_job(run_job(parse_cli(args))).spec.isosurface();
  };
  EXPECT_EQ(iso({"--method", "tiles"}).method(), v1::POLYGONIZER_TILES);
  EXPECT_EQ(iso({"--method", "cubes"}).method(), v1::POLYGONIZER_CUBES);
  EXPECT_EQ(iso({}).method(), v1::POLYGONIZER_UNSPECIFIED);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace surfacer::client

namespace surfacer::client {
namespace {

// What the Python package hands prepare_job(): a scene as JSON and a particle frame in memory, named by keys in the
// options like files, mixed with a real file; they become the same spec and uploads a file would.
TEST(InMemoryInputs, ScenesAndParticleFramesStandInForFiles) {
  const fs::path dir = fresh_temp_dir("in_memory_inputs");
  write_file(dir / "cube.json", kCube);
  write_file(dir / "b.xyz", "0 0 0\n1 0 0\n");

  InMemoryInputs memory;
  memory.scenes["scene[0]"] = kBall;
  memory.particles["frame[0]"].positions = {Vec3(0, 0, 0), Vec3(0.5, 0, 0), Vec3(0, 0.5, 0)};

  JobOptions iso;
  iso.spec.mutable_isosurface();
  iso.scenes = {"scene[0]", dir / "cube.json"};
  const PreparedJob scenes = prepare_job(iso, memory);
  ASSERT_EQ(scenes.spec.isosurface().scenes_size(), 2);
  EXPECT_EQ(scenes.spec.isosurface().scenes(0).name(), "ball");
  EXPECT_EQ(scenes.spec.isosurface().scenes(1).name(), "cube");

  JobOptions particles;
  particles.spec.mutable_particles()->set_r_inner(0.1);
  particles.particles.inputs = {"frame[0]", (dir / "b.xyz").string()};
  const PreparedJob frames = prepare_job(particles, memory);
  ASSERT_EQ(frames.uploads.size(), 2u);
  v1::JobSpec spec = frames.spec;
  const UploadData first = frames.uploads[0].read(spec, InputLimits{});
  EXPECT_EQ(first.particles, 3);
  EXPECT_EQ(floats(first.bytes), (std::vector<float>{0, 0, 0, 0.5f, 0, 0, 0, 0.5f, 0}));
  EXPECT_EQ(frames.uploads[1].read(spec, InputLimits{}).particles, 2);

  // The checks of a file apply: a bad scene, an empty frame, a frame over the server's limit.
  memory.scenes["scene[0]"] = R"({"root": {"sphere": {"radius": 1, "colour": 2}}})";
  try {
    prepare_job(iso, memory);
    ADD_FAILURE() << "a scene with an unknown field was accepted";
  } catch (const CliError& e) {
    EXPECT_EQ(e.code(), ExitCode::kUsage);
    EXPECT_NE(std::string(e.what()).find("scene scene[0]"), std::string::npos) << e.what();
  }
  InputLimits two;
  two.max_particles = 2;
  EXPECT_THROW(frames.uploads[0].read(spec, two), CliError);
  memory.particles["frame[0]"].positions.clear();
  const PreparedJob empty = prepare_job(particles, memory);
  EXPECT_THROW(empty.uploads[0].read(spec, InputLimits{}), CliError);
}

// What a client asks of the server: one Draco mesh only where a standard .drc file is written from the stream (.drc
// among the files, or the CLI's default file on a grid glTF cannot hold); every other Draco request comes in pieces,
// encoded and decoded on every core: the default .glb, files without .drc, and the Python package, which keeps the
// frames in memory. Other encodings stay.
TEST(JobOptions, DracoFramesComeInPiecesUnlessADrcFileIsWritten) {
  using F = FileFormat;
  const std::vector<std::vector<F>> writes_drc = {{F::kDrc}, {F::kPly, F::kDrc}, {F::kGlb, F::kDrc}};
  const std::vector<std::vector<F>> no_drc = {{F::kPly}, {F::kObj, F::kVtu}, {F::kGlb}};
  for (const v1::MeshEncoding asked :
       {v1::MESH_ENCODING_UNSPECIFIED, v1::MESH_ENCODING_DRACO, v1::MESH_ENCODING_DRACO_PIECES,
        v1::MESH_ENCODING_MESHOPT, v1::MESH_ENCODING_PLY}) {
    SCOPED_TRACE(v1::MeshEncoding_Name(asked));
    const bool draco = asked == v1::MESH_ENCODING_UNSPECIFIED || asked == v1::MESH_ENCODING_DRACO;
    const v1::MeshEncoding pieces = draco ? v1::MESH_ENCODING_DRACO_PIECES : asked;
    for (const std::optional<int> bits : {std::optional<int>{}, std::optional<int>{8}, std::optional<int>{16},
                                          std::optional<int>{17}, std::optional<int>{24}}) {
      SCOPED_TRACE(bits ? std::to_string(*bits) + " bits" : "default bits");
      const auto spec_asking = [&] {
        v1::JobSpec spec;
        spec.mutable_output()->set_encoding(asked);
        if (bits) spec.mutable_output()->set_quantization_bits(*bits);
        return spec;
      };
      // glTF holds grids of up to 16 bits; raw frames go in a .glb without a grid.
      const auto glb_refused = [&](const std::vector<F>& formats) {
        return bits > 16 && asked != v1::MESH_ENCODING_PLY &&
               std::find(formats.begin(), formats.end(), F::kGlb) != formats.end();
      };
      for (const bool drc : {true, false}) {
        for (const std::vector<F>& formats : drc ? writes_drc : no_drc) {
          v1::JobSpec spec = spec_asking();
          if (glb_refused(formats)) {
            EXPECT_THROW(fit_encoding_to_files(spec, formats), CliError);
            continue;
          }
          fit_encoding_to_files(spec, formats);
          EXPECT_EQ(spec.output().encoding(), drc ? asked : pieces);
        }
      }
      v1::JobSpec defaults = spec_asking();
      fit_encoding_to_files(defaults, {});
      EXPECT_EQ(defaults.output().encoding(), bits > 16 ? asked : pieces);
      v1::JobSpec spec = spec_asking();
      fit_encoding_to_memory(spec);
      EXPECT_EQ(spec.output().encoding(), pieces);
    }
  }
}

}  // namespace
}  // namespace surfacer::client
