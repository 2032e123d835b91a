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
    ASSERT_TRUE(job.isosurface);
    EXPECT_EQ(job.isosurface->method, method);
  }
  EXPECT_FALSE(run_job(parse_cli({"run", "isosurface", "--scene", "a.json", "-o", "d"})).isosurface->method);
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
  ASSERT_TRUE(job.particles);
  const ParticlesOptions& o = *job.particles;
  EXPECT_EQ(o.input.inputs, (std::vector<std::string>{"f_{:04d}.xyz", "extra.ply"}));
  EXPECT_EQ(o.input.start, 2);
  EXPECT_EQ(o.input.end, 5);
  EXPECT_EQ(o.r_inner, 0.1);
  EXPECT_FALSE(o.derive_r_inner);
  EXPECT_EQ(o.r_outer, 0.25);
  EXPECT_EQ(o.spacing_factor, 0.7);
  EXPECT_EQ(o.sweeps, (std::array<int, 3>{4, 20, 3}));
  EXPECT_EQ(o.relaxation, 0.5);
  EXPECT_EQ(o.erosion, 0.2);
  EXPECT_TRUE(o.unconstrained_polish);
  EXPECT_TRUE(o.vertex_only_band);
  EXPECT_EQ(o.min_angle, 2.5);
  EXPECT_EQ(o.container_box, (Box{0, 0, 0, 1, 2, 3}));
  EXPECT_EQ(o.container_scene, fs::path("solid.json"));
  EXPECT_EQ(o.min_particles, 12);
  EXPECT_TRUE(job.normals);
  EXPECT_EQ(job.encoding, "raw");
  EXPECT_EQ(job.name, "splash");
  const auto& run = std::get<RunCommand>(std::get<Invocation>(p.result).command);
  EXPECT_EQ(run.output.dir, "out");
  EXPECT_EQ(run.output.formats, (std::vector<FileFormat>{FileFormat::kPly, FileFormat::kObj}));
}

TEST(JobOptions, ParticlesDeriveRInnerAndSubmit) {
  const JobOptions job = run_job(parse_cli({"run", "particles", "--input", "a.bgeo", "--derive-r-inner", "-o", "d"}));
  ASSERT_TRUE(job.particles);
  EXPECT_TRUE(job.particles->derive_r_inner);
  EXPECT_FALSE(job.particles->r_inner);
  const ParsedCli s = parse_cli({"--server", "h:1", "submit", "particles", "--input", "a.bgeo", "--r-inner", "0.5"});
  ASSERT_TRUE(std::holds_alternative<Invocation>(s.result)) << s.err;
  const auto& submit = std::get<SubmitCommand>(std::get<Invocation>(s.result).command);
  ASSERT_TRUE(submit.job.particles);
  EXPECT_EQ(submit.job.particles->r_inner, 0.5);
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
                                            "1.5",
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
  ASSERT_TRUE(job.optimize);
  const OptimizeOptions& o = *job.optimize;
  EXPECT_EQ(o.scene, fs::path("cube.json"));
  EXPECT_FALSE(o.start_mesh);
  EXPECT_EQ(o.start_cells, 24);
  EXPECT_EQ(o.start_method, "tiles");
  EXPECT_EQ(o.start_bounds, (Box{-2, -2, -2, 2, 2, 2}));
  EXPECT_EQ(o.iterations, 20);
  EXPECT_EQ(o.tolerance, 1e-4);
  EXPECT_EQ(o.snapshot_every, 5);
  ASSERT_TRUE(o.flows);
  EXPECT_TRUE(o.flows->d);
  EXPECT_TRUE(o.flows->n);
  EXPECT_FALSE(o.flows->t);
  EXPECT_EQ(o.c_d, 1.5);
  EXPECT_EQ(o.c_n, 0.5);
  EXPECT_EQ(o.c_t, 0.25);
  EXPECT_EQ(o.step_bound, 0.3);
  EXPECT_TRUE(o.modified_flows);
  EXPECT_EQ(o.subdivide, 0.01);
  EXPECT_EQ(o.triangle_budget, 500000);

  const JobOptions mesh = run_job(parse_cli(
      {"run", "optimize", "--scene", "c.json", "--start-mesh", "m.drc", "--t-flow-iterations", "7", "-o", "out"}));
  ASSERT_TRUE(mesh.optimize);
  EXPECT_EQ(mesh.optimize->start_mesh, fs::path("m.drc"));
  EXPECT_EQ(mesh.optimize->t_flow_iterations, 7);
  EXPECT_FALSE(mesh.optimize->flows);
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
                                             "--cfl",
                                             "0.4",
                                             "--polygonizer",
                                             "cubes",
                                             "-o",
                                             "d"}));
  ASSERT_TRUE(coat.active);
  const ActiveOptions& a = *coat.active;
  ASSERT_TRUE(std::holds_alternative<ActiveCoatOptions>(a.mode));
  const auto& c = std::get<ActiveCoatOptions>(a.mode);
  EXPECT_EQ(c.input.inputs, (std::vector<std::string>{"p_{}.xyz"}));
  EXPECT_EQ(c.input.end, 9);
  EXPECT_EQ(c.kernel_radius, 0.3);
  EXPECT_EQ(c.iso, 0.4);
  EXPECT_EQ(c.substeps, 3);
  EXPECT_EQ(a.grid_spacing, 0.05);
  EXPECT_EQ(a.bounds, (Box{-1, -1, -1, 1, 1, 1}));
  EXPECT_EQ(a.alpha, 1.0);
  EXPECT_EQ(a.beta, 0.01);
  EXPECT_EQ(a.gamma, 0.5);
  EXPECT_EQ(a.delta, 2.0);
  EXPECT_EQ(a.cfl, 0.4);
  EXPECT_EQ(a.polygonizer, "cubes");

  const JobOptions morph =
      run_job(parse_cli({"run", "active", "morph", "--from", "a.json", "--to", "b.json", "--tolerance", "1e-3",
                         "--max-frames", "50", "--frame-time", "0.1", "--grid-spacing", "0.02", "-o", "d"}));
  ASSERT_TRUE(morph.active);
  const auto& m = std::get<ActiveMorphOptions>(morph.active->mode);
  EXPECT_EQ(m.from, fs::path("a.json"));
  EXPECT_EQ(m.to, fs::path("b.json"));
  EXPECT_EQ(m.tolerance, 1e-3);
  EXPECT_EQ(m.max_frames, 50);
  EXPECT_EQ(m.frame_time, 0.1);

  const JobOptions enright =
      run_job(parse_cli({"run", "active", "advect", "--scene", "s.json", "--enright", "--period", "2",
                         "--frame-interval", "0.25", "--frames", "8", "--grid-spacing", "0.01", "-o", "d"}));
  ASSERT_TRUE(enright.active);
  const auto& e = std::get<ActiveAdvectOptions>(enright.active->mode);
  EXPECT_EQ(e.scene, fs::path("s.json"));
  EXPECT_EQ(e.enright_period, 2.0);
  EXPECT_FALSE(e.velocity_grid);
  EXPECT_EQ(e.frame_interval, 0.25);
  EXPECT_EQ(e.frames, 8);

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
  ASSERT_TRUE(grid.active);
  const auto& g = std::get<ActiveAdvectOptions>(grid.active->mode);
  ASSERT_TRUE(g.velocity_grid);
  EXPECT_EQ(g.velocity_grid->file, fs::path("v.raw"));
  EXPECT_EQ(g.velocity_grid->origin, (Triple{-1, -2, -3}));
  EXPECT_EQ(g.velocity_grid->spacing, (Triple{0.5, 0.25, 0.125}));
  EXPECT_EQ(g.velocity_grid->dims, (std::array<int, 3>{5, 9, 17}));
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
      {p, "--r-inner"},  // neither --r-inner nor --derive-r-inner
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
      {with(o, {"--iterations", "0"}), "--iterations"},
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
  for (const char* flag : {"--enright", "--period", "--velocity-grid", "--velocity-origin", "--velocity-spacing",
                           "--velocity-dims", "--frame-interval", "--frames", "--grid-spacing", "--alpha", "--cfl"}) {
    EXPECT_NE(advect.out.find(flag), std::string::npos) << flag;
  }
}

TEST(JobOptions, ValueParsers) {
  EXPECT_EQ(parse_box("-1,-2,-3,1,2,3", "--bounds"), (Box{-1, -2, -3, 1, 2, 3}));
  EXPECT_EQ(parse_sweeps("0,15,5"), (std::array<int, 3>{0, 15, 5}));
  const FlowSet t = parse_flows("t");
  EXPECT_FALSE(t.d);
  EXPECT_FALSE(t.n);
  EXPECT_TRUE(t.t);
  EXPECT_THROW(parse_flows(""), CliError);
  EXPECT_THROW(parse_numbers("1,2,", 3, "--x", "1,2,3"), CliError);
  EXPECT_THROW(parse_numbers("1,nan,3", 3, "--x", "1,2,3"), CliError);
  EXPECT_EQ(parse_numbers("1e-3,2,3", 3, "--x", "1,2,3")[0], 1e-3);
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
  JobOptions options;
  ParticlesOptions p;
  p.input = {{(dir / "p_{}.xyz").string(), (dir / "last.xyz").string()}, {}, {}};
  p.r_inner = 0.1;
  p.r_outer = 0.3;
  p.spacing_factor = 0.75;
  p.sweeps = {{3, 21, 2}};
  p.relaxation = 0.55;
  p.erosion = 0.05;
  p.unconstrained_polish = true;
  p.vertex_only_band = true;
  p.min_angle = 0;
  p.container_box = Box{-1, -1, -1, 8, 8, 8};
  p.container_scene = dir / "solid.json";
  p.min_particles = 4;
  options.particles = p;
  options.normals = true;
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

  options.particles->r_inner.reset();
  options.particles->derive_r_inner = true;
  options.particles->sweeps.reset();
  options.particles->input.inputs = {(dir / "last.xyz").string()};
  const v1::ParticlesJob derived = prepare_job(options).spec.particles();
  EXPECT_TRUE(derived.derive_r_inner());
  EXPECT_FALSE(derived.has_r_inner());
  EXPECT_FALSE(derived.has_bilaplacian_sweeps());  // the server's default
  fs::remove_all(dir);
}

TEST(JobSpecs, OptimizeFromPolygonizationOrUploadedMesh) {
  const fs::path dir = fresh_temp_dir("jobopts_optimize_spec");
  write_file(dir / "cube.json", kCube);
  JobOptions options;
  OptimizeOptions o;
  o.scene = dir / "cube.json";
  o.start_cells = 24;
  o.start_method = "tiles";
  o.start_bounds = Box{-2, -2, -2, 2, 2, 2};
  o.iterations = 20;
  o.tolerance = 1e-5;
  o.snapshot_every = 5;
  o.flows = FlowSet{true, true, false};
  o.c_d = 1;
  o.c_n = 0.5;
  o.c_t = 0.1;
  o.step_bound = 0.2;
  o.modified_flows = true;
  o.subdivide = 0.02;
  o.triangle_budget = 100000;
  options.optimize = o;
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
  OptimizeOptions bare;
  bare.scene = dir / "cube.json";
  options.optimize = bare;
  const v1::OptimizeJob plain = prepare_job(options).spec.optimize();
  EXPECT_EQ(plain.start_case(), v1::OptimizeJob::kPolygonize);
  EXPECT_EQ(plain.polygonize().method(), v1::POLYGONIZER_UNSPECIFIED);
  EXPECT_FALSE(plain.has_d_flow());
  EXPECT_FALSE(plain.has_max_iterations());

  // A start mesh is one upload of the file's bytes as they are.
  const std::string obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
  write_file(dir / "tet.obj", obj);
  bare.start_mesh = dir / "tet.obj";
  options.optimize = bare;
  prepared = prepare_job(options);
  ASSERT_EQ(prepared.uploads.size(), 1u);
  UploadData data = prepared.uploads[0].read(prepared.spec, {});
  EXPECT_EQ(data.bytes, obj);
  EXPECT_EQ(data.name, "tet.obj");
  prepared.uploads[0].set_id(prepared.spec, "u-mesh");
  EXPECT_EQ(prepared.spec.optimize().mesh_upload_id(), "u-mesh");

  // A bad mesh fails when read (before any job is queued), naming the file and the line.
  write_file(dir / "bad.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n");
  bare.start_mesh = dir / "bad.obj";
  options.optimize = bare;
  prepared = prepare_job(options);
  try {
    prepared.uploads[0].read(prepared.spec, {});
    ADD_FAILURE() << "bad.obj was accepted";
  } catch (const CliError& e) {
    EXPECT_EQ(e.code(), ExitCode::kUsage);
    EXPECT_NE(std::string(e.what()).find("bad.obj"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("4"), std::string::npos) << e.what();
  }
  // Missing file or unknown extension: at once.
  bare.start_mesh = dir / "none.ply";
  options.optimize = bare;
  EXPECT_THROW(prepare_job(options), CliError);
  write_file(dir / "mesh.stl", "solid");
  bare.start_mesh = dir / "mesh.stl";
  options.optimize = bare;
  EXPECT_THROW(prepare_job(options), CliError);
  fs::remove_all(dir);
}

TEST(JobSpecs, ActiveModes) {
  const fs::path dir = fresh_temp_dir("jobopts_active_spec");
  write_file(dir / "ball.json", kBall);
  write_file(dir / "cube.json", kCube);
  write_file(dir / "c_0.xyz", "0 0 0\n");
  write_file(dir / "c_1.xyz", "0.1 0 0\n0.2 0 0\n");

  JobOptions options;
  ActiveOptions a;
  a.grid_spacing = 0.05;
  a.bounds = Box{-1, -1, -1, 1, 1, 1};
  a.alpha = 1;
  a.beta = 0.02;
  a.gamma = 0.3;
  a.delta = 0.4;
  a.cfl = 0.5;
  a.polygonizer = "tiles";
  ActiveCoatOptions coat;
  coat.input = {{(dir / "c_{}.xyz").string()}, {}, {}};
  coat.kernel_radius = 0.3;
  coat.iso = 0.45;
  coat.substeps = 4;
  a.mode = coat;
  options.active = a;
  PreparedJob prepared = prepare_job(options);
  const v1::ActiveJob& job = prepared.spec.active();
  EXPECT_DOUBLE_EQ(job.grid_spacing(), 0.05);
  EXPECT_DOUBLE_EQ(job.bounds().max().x(), 1);
  EXPECT_DOUBLE_EQ(job.alpha(), 1);
  EXPECT_DOUBLE_EQ(job.beta(), 0.02);
  EXPECT_DOUBLE_EQ(job.gamma(), 0.3);
  EXPECT_DOUBLE_EQ(job.delta(), 0.4);
  EXPECT_DOUBLE_EQ(job.cfl(), 0.5);
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

  ActiveMorphOptions morph;
  morph.from = dir / "ball.json";
  morph.to = dir / "cube.json";
  morph.tolerance = 0.01;
  morph.max_frames = 12;
  morph.frame_time = 0.5;
  a.mode = morph;
  a.polygonizer.reset();
  options.active = a;
  prepared = prepare_job(options);
  EXPECT_TRUE(prepared.uploads.empty());
  const v1::ActiveMorph& m = prepared.spec.active().morph();
  EXPECT_DOUBLE_EQ(m.from().root().sphere().radius(), 0.5);
  EXPECT_TRUE(m.to().root().has_box());
  EXPECT_DOUBLE_EQ(m.tolerance(), 0.01);
  EXPECT_EQ(m.max_frames(), 12);
  EXPECT_DOUBLE_EQ(m.frame_time(), 0.5);
  EXPECT_EQ(prepared.spec.active().polygonizer(), v1::POLYGONIZER_UNSPECIFIED);

  ActiveAdvectOptions advect;
  advect.scene = dir / "ball.json";
  advect.enright_period = 3;
  advect.frame_interval = 0.25;
  advect.frames = 6;
  a.mode = advect;
  options.active = a;
  prepared = prepare_job(options);
  EXPECT_TRUE(prepared.uploads.empty());
  const v1::ActiveAdvect& e = prepared.spec.active().advect();
  ASSERT_EQ(e.velocity_case(), v1::ActiveAdvect::kEnright);
  EXPECT_DOUBLE_EQ(e.enright().period(), 3);
  EXPECT_DOUBLE_EQ(e.frame_interval(), 0.25);
  EXPECT_EQ(e.frames(), 6);
  EXPECT_DOUBLE_EQ(e.shape().root().sphere().radius(), 0.5);

  // A velocity grid: its size is checked against the dimensions at once; the file is streamed when uploaded.
  advect.enright_period.reset();
  advect.velocity_grid = VelocityGridOptions{dir / "v.raw", {-1, -1, -1}, {1, 1, 1}, {3, 3, 2}};
  write_file(dir / "v.raw", std::string(3 * 3 * 2 * 12, '\0'));
  a.mode = advect;
  options.active = a;
  prepared = prepare_job(options);
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
    prepare_job(options);
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
  JobOptions options;
  options.isosurface = IsosurfaceOptions{{dir / "ball.json"}, {}, {}, {}, "tiles"};
  EXPECT_EQ(prepare_job(options).spec.isosurface().method(), v1::POLYGONIZER_TILES);
  options.isosurface->method = "cubes";
  EXPECT_EQ(prepare_job(options).spec.isosurface().method(), v1::POLYGONIZER_CUBES);
  options.isosurface->method.reset();
  EXPECT_EQ(prepare_job(options).spec.isosurface().method(), v1::POLYGONIZER_UNSPECIFIED);
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
  iso.isosurface.emplace().scenes = {"scene[0]", dir / "cube.json"};
  const PreparedJob scenes = prepare_job(iso, memory);
  ASSERT_EQ(scenes.spec.isosurface().scenes_size(), 2);
  EXPECT_EQ(scenes.spec.isosurface().scenes(0).name(), "ball");
  EXPECT_EQ(scenes.spec.isosurface().scenes(1).name(), "cube");

  JobOptions particles;
  particles.particles.emplace().input.inputs = {"frame[0]", (dir / "b.xyz").string()};
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

}  // namespace
}  // namespace surfacer::client
