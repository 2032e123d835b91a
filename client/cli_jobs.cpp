#include "client/cli_jobs.h"

#include <algorithm>
#include <charconv>
#include <cmath>

#include "client/exit_codes.h"
#include "core/active/active_surface.h"
#include "core/mesh/mesh_codec.h"
#include "core/optimize/mesh_optimizer.h"
#include "core/particles/particle_surfacer.h"
#include "core/polygonize/polygonize.h"
#include "core/util/format.h"

namespace surfacer::client {
namespace {

CliError usage(const std::string& message) { return CliError(ExitCode::kUsage, message); }

// Number checks with short messages (CLI11's own print the whole double range); CLI11 prefixes the flag.
CLI::Validator number_check(bool allow_zero) {
  return CLI::Validator(
      [allow_zero](std::string& text) -> std::string {
        double value = 0;
        const char* end = text.data() + text.size();
        auto [ptr, ec] = std::from_chars(text.data(), end, value);
        if (text.empty() || ec != std::errc() || ptr != end || !std::isfinite(value)) {
          return "\"" + text + "\" is not a number";
        }
        if (allow_zero ? value < 0 : value <= 0) return text + " must be " + (allow_zero ? ">= 0" : "> 0");
        return "";
      },
      allow_zero ? ">= 0" : "> 0");
}

const CLI::Validator positive = number_check(false);
const CLI::Validator non_negative = number_check(true);

std::string number_text(double v) { return format_number(v); }

// Defaults shown in --help are the engines' own (core options structs); the CLI never sends a default itself.
const PolygonizeOptions kIsosurfaceDefaults;
const PolygonizeOptions kStartDefaults = default_start_polygonize();
const ParticleSurfacingOptions kParticleDefaults;
const MeshOptimizerOptions kOptimizerDefaults;
const ActiveSurfaceOptions kActiveDefaults;
const DracoOptions kDracoDefaults;

std::string default_text(double v) { return " (default " + format_number(v) + ")"; }

// "Example:" footer: `run_example` for run, `submit_example` for submit.
void set_examples(CLI::App* app, const std::string& verb, const std::vector<std::string>& run_examples,
                  const std::vector<std::string>& submit_examples, const std::string& notes = "") {
  const auto& examples = verb == "run" ? run_examples : submit_examples;
  std::string text = examples.size() == 1 ? "Example:\n" : "Examples:\n";
  for (const auto& e : examples) text += "  " + e + "\n";
  if (!notes.empty()) text += notes;
  app->footer(text + "\n" + kGlobalNote);
}

CLI::Option* add_particle_inputs(CLI::App* app, ParticleInputOptions& input) {
  CLI::Option* opt =
      app->add_option("--input", input.inputs,
                      "particle file (.xyz .txt .csv .ply .vtk .vtu .bin .bgeo .json, gzip allowed) or sequence "
                      "pattern (fluid_{}.bgeo: any zero padding; fluid_{:04d}.ply: exactly 4 digits); repeat to "
                      "append; frame i = the i-th file")
          ->required()
          ->type_name("FILE|PATTERN");
  app->add_option("--start", input.start,
                  "first frame number of the pattern(s) (default: the smallest present in the directory)")
      ->type_name("N");
  app->add_option("--end", input.end, "last frame number, inclusive (default: the largest present in the directory)")
      ->type_name("M");
  return opt;
}

void add_isosurface(CLI::App* parent, const std::string& verb, JobFlags& flags, OutputFlags* output) {
  CLI::App* iso = parent->add_subcommand("isosurface", "Polygonize the surface f = 0 of one or more scenes");
  iso->add_option("--scene", flags.iso.scenes,
                  "scene file (protobuf JSON of surfacer.v1.Scene); repeat for a sequence, one frame per scene")
      ->required()
      ->type_name("FILE");
  CLI::Option* cells =
      iso->add_option("--cells", flags.iso.cells,
                      "cells along the longest axis of the bounds" + default_text(kIsosurfaceDefaults.cells))
          ->check(positive)
          ->type_name("N");
  iso->add_option("--cell-size", flags.iso.cell_size,
                  "edge of a cubic cell (cubes) or mean sample spacing (tiles), in scene units")
      ->check(positive)
      ->excludes(cells)
      ->type_name("H");
  iso->add_option("--bounds", flags.iso_bounds,
                  "region to polygonize: x0,y0,z0,x1,y1,z1 (default: the scenes' own bounds, padded by " +
                      format_number(PolygonizeOptions::kPadCells) + " cells)")
      ->type_name("BOX");
  iso->add_option(
         "--method", flags.iso.method,
         "polygonizer: tiles (Marching Tiles, every vertex of valence >= 5) or cubes (Marching Cubes); default " +
             std::string(polygonizer_name(kIsosurfaceDefaults.method)))
      ->check(CLI::IsMember({"cubes", "tiles"}))
      ->type_name("NAME");
  add_job_common_flags(iso, flags.job);
  if (output != nullptr) add_output_flags(iso, *output);
  set_examples(iso, verb,
               {"surfacer run isosurface --scene a.json --scene b.json --cells 64 --method tiles "
                "--bounds=-2,-2,-2,2,2,2 -o out/ --format drc,ply"},
               {"surfacer --server localhost:50051 submit isosurface --scene a.json --scene b.json --cells 64"});
  flags.isosurface = iso;
}

void add_particles(CLI::App* parent, const std::string& verb, JobFlags& flags, OutputFlags* output) {
  ParticlesOptions& p = flags.particles;
  CLI::App* app = parent->add_subcommand(
      "particles", "Surface particle frames (Williams 2008): one smooth, watertight mesh per frame");
  add_particle_inputs(app, p.input);
  CLI::Option* r_inner =
      app->add_option("--r-inner", p.r_inner,
                      "inner radius: every vertex stays at least this far from every particle (scene units)")
          ->check(positive)
          ->type_name("R");
  app->add_flag("--derive-r-inner", p.derive_r_inner, "derive r_inner from the mean nearest-neighbour spacing")
      ->excludes(r_inner);
  app->add_option("--r-outer", p.r_outer,
                  "outer radius: every vertex stays within this distance of some particle (default " +
                      format_number(ParticleSurfacingOptions::kDefaultOuterRatio) +
                      " x r_inner; flat on a lattice of spacing d when r_outer^2 >= r_inner^2 + d^2/2)")
      ->check(positive)
      ->type_name("R");
  app->add_option("--spacing-factor", p.spacing_factor,
                  "sample spacing of the initial tiling / r_inner" + default_text(kParticleDefaults.spacing_factor))
      ->check(positive)
      ->type_name("F");
  app->add_option("--sweeps", flags.sweeps,
                  "Gauss-Seidel sweeps: Laplacian,Bilaplacian,polish (default " +
                      std::to_string(kParticleDefaults.laplacian_sweeps) + "," +
                      std::to_string(kParticleDefaults.bilaplacian_sweeps) + "," +
                      std::to_string(kParticleDefaults.polish_sweeps) + ")")
      ->type_name("L,B,P");
  app->add_option("--relaxation", p.relaxation,
                  "under-relaxation of the Laplacian sweeps" + default_text(kParticleDefaults.relaxation))
      ->check(positive)
      ->type_name("W");
  app->add_option("--erosion", p.erosion, "move vertices inward by EPS x r_inner at the end (default off)")
      ->check(non_negative)
      ->type_name("EPS");
  app->add_flag("--unconstrained-polish", p.unconstrained_polish,
                "keep the thesis' polish: no final projection, so some vertices may end outside [r_inner, r_outer]");
  app->add_flag("--vertex-only-band", p.vertex_only_band,
                "keep the thesis' band at the vertices only: the cusps of the r_outer spheres are not held (fuller "
                "surfaces; faces over particle lattices are not flat)");
  app->add_option("--min-angle", p.min_angle,
                  "repair triangles with a smaller angle, in degrees (0: no repair)" +
                      default_text(kParticleDefaults.min_angle_degrees))
      ->type_name("DEG");
  app->add_option("--container-box", flags.container_box,
                  "keep the surface inside this box: x0,y0,z0,x1,y1,z1 (vertices outside are snapped to it)")
      ->type_name("BOX");
  app->add_option("--container-scene", p.container_scene,
                  "keep the surface inside this implicit solid (scene JSON, negative inside)")
      ->type_name("FILE");
  app->add_option("--min-particles", p.min_particles,
                  "drop surface components around fewer particles than this (stray spray; default " +
                      std::to_string(kParticleDefaults.min_particles_per_component) + ": keep all)")
      ->check(non_negative)
      ->type_name("N");
  add_job_common_flags(app, flags.job);
  if (output != nullptr) add_output_flags(app, *output);
  set_examples(
      app, verb,
      {"surfacer run particles --input 'sim/fluid_{:04d}.bgeo' --start 0 --end 199 --r-inner 0.01 -o out/ "
       "--format ply",
       "surfacer run particles --input drop.xyz --derive-r-inner --container-box 0,0,0,1,1,1 -o out/"},
      {"surfacer --server localhost:50051 submit particles --input 'sim/fluid_{}.bgeo' --r-inner 0.01"},
      std::string("Frames are uploaded one at a time (float32) before the job is queued; a bad file stops the command\n"
                  "(exit 2) naming the file and the line or byte. frame_NNNN carries the input's frame number (one\n"
                  "pattern, or increasing numbers), else N counts the inputs from 0. ") +
          (verb == "run" ? "A table of particles,\ntriangles and seconds per frame is printed at the end.\n"
                         : "The job id is printed\nonce every frame is uploaded; `surfacer watch ID -o DIR` fetches "
                           "the meshes and prints the table.\n"));
  flags.particles_app = app;
}

void add_optimize(CLI::App* parent, const std::string& verb, JobFlags& flags, OutputFlags* output) {
  OptimizeOptions& o = flags.optimize;
  CLI::App* app = parent->add_subcommand(
      "optimize", "Optimize a mesh toward a scene's surface (Ohtake-Belyaev-Pasko 2002), recovering sharp features");
  app->add_option("--scene", o.scene, "the field: scene file (protobuf JSON of surfacer.v1.Scene)")
      ->required()
      ->type_name("FILE");
  CLI::Option* mesh =
      app->add_option("--start-mesh", o.start_mesh, "start mesh file (.ply, .obj, .drc or .glb), uploaded as is")
          ->type_name("FILE");
  app->add_option(
         "--start-cells", o.start_cells,
         "or polygonize the scene on the server: cells along the longest axis" + default_text(kStartDefaults.cells))
      ->check(positive)
      ->excludes(mesh)
      ->type_name("N");
  app->add_option("--start-method", o.start_method,
                  "polygonizer of the start mesh: cubes or tiles (default " +
                      std::string(polygonizer_name(kStartDefaults.method)) + ")")
      ->check(CLI::IsMember({"cubes", "tiles"}))
      ->excludes(mesh)
      ->type_name("NAME");
  app->add_option("--start-bounds", flags.start_bounds,
                  "region of the start polygonization: x0,y0,z0,x1,y1,z1 (default: the scene's bounds, padded)")
      ->excludes(mesh)
      ->type_name("BOX");
  app->add_option("--iterations", o.iterations,
                  "stop after N iterations" + default_text(kOptimizerDefaults.max_iterations))
      ->check(positive)
      ->type_name("N");
  app->add_option("--tolerance", o.tolerance, "stop when E_d and E_n change by less than T (relative)")
      ->check(positive)
      ->type_name("T");
  app->add_option("--snapshot-every", o.snapshot_every,
                  "stream a snapshot frame every K iterations (default: only the result)")
      ->check(positive)
      ->type_name("K");
  app->add_option("--flows", flags.flows,
                  "flows to run, comma-separated: d (distance), n (normal), t (tangential); "
                  "default d,n,t")
      ->type_name("LIST");
  app->add_option("--c-d", o.c_d, "D-flow coefficient" + default_text(kOptimizerDefaults.c_d))
      ->check(positive)
      ->type_name("X");
  app->add_option("--c-n", o.c_n, "N-flow coefficient" + default_text(kOptimizerDefaults.c_n))
      ->check(positive)
      ->type_name("X");
  app->add_option("--c-t", o.c_t, "T-flow coefficient" + default_text(kOptimizerDefaults.c_t))
      ->check(positive)
      ->type_name("X");
  app->add_option("--step-bound", o.step_bound,
                  "D-flow step bound c in |C_D F_D| <= c sqrt(A(P))" + default_text(kOptimizerDefaults.step_bound))
      ->check(positive)
      ->type_name("C");
  app->add_flag("--modified-flows", o.modified_flows, "local-energy gradient descent (paper section 3.1)");
  app->add_option("--t-flow-iterations", o.t_flow_iterations,
                  "run the T-flow for exactly N iterations (default: off once E_d stabilises)")
      ->check(non_negative)
      ->type_name("N");
  app->add_option("--subdivide", o.subdivide, "adaptive 1-to-4 subdivision where delta(T) exceeds THRESHOLD")
      ->check(positive)
      ->type_name("THRESHOLD");
  app->add_option("--triangle-budget", o.triangle_budget, "stop subdividing at N triangles")
      ->check(positive)
      ->type_name("N");
  add_job_common_flags(app, flags.job);
  if (output != nullptr) add_output_flags(app, *output);
  set_examples(app, verb,
               {"surfacer run optimize --scene examples/scenes/csg_block.json --start-cells 64 --iterations 200 "
                "--snapshot-every 10 -o out/",
                "surfacer run optimize --scene cube.json --start-mesh sphere.ply --flows d,n --modified-flows -o out/"},
               {"surfacer --server localhost:50051 submit optimize --scene csg_block.json --start-mesh start.drc"},
               std::string(verb == "run" ? "" : "With `surfacer watch ID -o DIR`: ") +
                   "each snapshot's iteration and figures (e_d, e_n, max_distance, rms_distance,\n"
                   "min_angle_degrees, ...) go to DIR/iterations.csv, one row per snapshot; the last frame is the "
                   "result.\n");
  flags.optimize_app = app;
}

void add_active_common(CLI::App* app, JobFlags& flags, OutputFlags* output) {
  ActiveOptions& a = flags.active;
  app->add_option("--grid-spacing", a.grid_spacing, "spacing h of the potential's grid, in scene units")
      ->required()
      ->check(positive)
      ->type_name("H");
  app->add_option("--bounds", flags.active_bounds, "domain hint x0,y0,z0,x1,y1,z1 (the grid is sparse and unbounded)")
      ->type_name("BOX");
  app->add_option("--alpha", a.alpha,
                  "tracking strength, coat and morph only (default " +
                      format_number(ActiveSurfaceOptions::kTrackingAlpha) + "; advect has no target to track)")
      ->check(non_negative)
      ->type_name("X");
  app->add_option("--beta", a.beta, "surface tension (advect: on top of the velocity, as --gamma and --delta)")
      ->check(non_negative)
      ->type_name("X");
  app->add_option("--gamma", a.gamma, "area preservation")->check(non_negative)->type_name("X");
  app->add_option("--delta", a.delta, "volume preservation (advect: holds the volume the scheme would lose)")
      ->check(non_negative)
      ->type_name("X");
  app->add_option("--cfl", a.cfl, "CFL factor of the time step" + default_text(*kActiveDefaults.cfl))
      ->check(positive)
      ->type_name("X");
  app->add_option("--polygonizer", a.polygonizer,
                  "polygonizer of each frame: tiles or cubes (default " +
                      std::string(polygonizer_name(kActiveDefaults.polygonizer)) + ")")
      ->check(CLI::IsMember({"tiles", "cubes"}))
      ->type_name("NAME");
  add_job_common_flags(app, flags.job);
  if (output != nullptr) add_output_flags(app, *output);
}

void add_active(CLI::App* parent, const std::string& verb, JobFlags& flags, OutputFlags* output) {
  CLI::App* active = parent->add_subcommand(
      "active", "Active implicit surfaces (Desbrun-Cani 1998): coat particles, morph scenes, advect a scene");
  active->require_subcommand(1);
  const std::string server = verb == "run" ? "" : "--server localhost:50051 ";
  const std::string out = verb == "run" ? " -o out/" : "";
  const std::string prefix = "surfacer " + server + verb + " active ";
  const std::string coat_example =
      prefix + "coat --input 'sim/fluid_{:04d}.bgeo' --kernel-radius 0.05 --grid-spacing 0.01" + out;
  const std::string morph_example =
      prefix + "morph --from blob.json --to spheres.json --grid-spacing 0.02 --max-frames 100" + out;
  const std::string advect_example =
      prefix + "advect --scene sphere.json --enright --period 3 --frame-interval 0.1 --frames 30 --grid-spacing 0.01" +
      out;
  active->footer("Examples:\n  " + coat_example + "\n  " + morph_example + "\n  " + advect_example +
                 "\nEvery mode needs --grid-spacing H; see `surfacer " + verb + " active MODE --help`.\n\n" +
                 kGlobalNote);

  CLI::App* coat = active->add_subcommand("coat", "A skin over a particle sequence that follows it frame to frame");
  add_particle_inputs(coat, flags.coat.input);
  coat->add_option("--kernel-radius", flags.coat.kernel_radius, "R of the Wyvill kernel (1 - r^2/R^2)^3")
      ->required()
      ->check(positive)
      ->type_name("R");
  coat->add_option("--iso", flags.coat.iso,
                   "iso value T of the summed kernel field" + default_text(ParticleTargetOptions{}.iso))
      ->check(positive)
      ->type_name("T");
  coat->add_option("--substeps", flags.coat.substeps,
                   "evolve each frame in exactly N sub-steps instead of CFL-sized ones (excludes --cfl)")
      ->check(positive)
      ->type_name("N");
  add_active_common(coat, flags, output);
  coat->footer("Example:\n  " + coat_example +
               "\nParticle frames are uploaded one at a time before the job is queued (as for `particles`).\n\n" +
               kGlobalNote);

  CLI::App* morph = active->add_subcommand("morph", "Morph scene A into scene B, one frame per output step");
  morph->add_option("--from", flags.morph.from, "start scene file (JSON)")->required()->type_name("A.json");
  morph->add_option("--to", flags.morph.to, "target scene file (JSON)")->required()->type_name("B.json");
  morph
      ->add_option("--tolerance", flags.morph.tolerance,
                   "stop when max |df/dt| falls below X" + default_text(MorphOptions{}.tolerance))
      ->check(positive)
      ->type_name("X");
  morph
      ->add_option("--max-frames", flags.morph.max_frames,
                   "stop after N frames" + default_text(MorphOptions{}.max_frames))
      ->check(positive)
      ->type_name("N");
  morph
      ->add_option("--frame-time", flags.morph.frame_time,
                   "simulated time between output frames" + default_text(MorphOptions{}.frame_duration))
      ->check(positive)
      ->type_name("DT");
  add_active_common(morph, flags, output);
  morph->footer("Example:\n  " + morph_example + "\n\n" + kGlobalNote);

  CLI::App* advect = active->add_subcommand("advect", "Carry a scene with a velocity field");
  advect->add_option("--scene", flags.advect.scene, "the shape: scene file (JSON)")->required()->type_name("FILE");
  CLI::Option* enright =
      advect->add_flag("--enright", flags.enright, "the Enright/LeVeque deformation field (analytic)");
  CLI::Option* period =
      advect->add_option("--period", flags.advect.enright_period, "Enright period T" + default_text(kEnrightPeriod))
          ->check(positive)
          ->needs(enright)
          ->type_name("T");
  CLI::Option* grid = advect
                          ->add_option("--velocity-grid", flags.velocity_grid,
                                       "sampled velocity: raw little-endian float32 x y z per node, x fastest")
                          ->excludes(enright)
                          ->excludes(period)
                          ->type_name("FILE.raw");
  advect->add_option("--velocity-origin", flags.velocity_origin, "position of the grid's first node")
      ->needs(grid)
      ->type_name("x,y,z");
  advect->add_option("--velocity-spacing", flags.velocity_spacing, "node spacing per axis (> 0)")
      ->needs(grid)
      ->type_name("dx,dy,dz");
  advect->add_option("--velocity-dims", flags.velocity_dims, "nodes per axis (>= 2)")
      ->needs(grid)
      ->type_name("nx,ny,nz");
  advect->add_option("--frame-interval", flags.advect.frame_interval, "simulated time between frames")
      ->required()
      ->check(positive)
      ->type_name("DT");
  advect->add_option("--frames", flags.advect.frames, "number of frames")->required()->check(positive)->type_name("N");
  add_active_common(advect, flags, output);
  advect->footer("Examples:\n  " + advect_example + "\n  " + prefix +
                 "advect --scene s.json --velocity-grid wind.raw --velocity-origin=-1,-1,-1 "
                 "--velocity-spacing 0.1,0.1,0.1 --velocity-dims 21,21,21 --frame-interval 0.05 --frames 40 "
                 "--grid-spacing 0.02" +
                 out + "\n\n" + kGlobalNote);

  flags.active_app = active;
  flags.coat_app = coat;
  flags.morph_app = morph;
  flags.advect_app = advect;
}

Triple parse_triple(const std::string& text, const std::string& flag, const std::string& example) {
  const auto v = parse_numbers(text, 3, flag, example);
  return {v[0], v[1], v[2]};
}

}  // namespace

void add_output_flags(CLI::App* app, OutputFlags& flags) {
  app->add_option("-o,--output", flags.dir,
                  "directory for frame_NNNN.<ext> files, stats.csv (and iterations.csv for optimize) (created); or a "
                  "file pattern such as 'out/surface_{:04d}.ply' whose extension sets the format. NNNN is the "
                  "input sequence's own frame number (--start 100 writes frame_0100), else the frame index")
      ->type_name("DIR|PATTERN");
  app->add_option("--format", flags.formats,
                  "files per frame, comma-separated: drc,ply,obj,vtk,vtu,glb (default: .drc for Draco frames, .ply "
                  "for meshopt and raw ones; vtk = legacy binary, vtu = VTK XML with zlib, for ParaView and Blender; "
                  "glb = glTF with Draco pieces, encoded on every core, for Blender, three.js and other glTF readers; "
                  "up to 16 quantization bits)")
      ->delimiter(',')
      ->check(CLI::IsMember({"drc", "ply", "obj", "vtk", "vtu", "glb"}))
      ->type_name("LIST");
  add_report_flags(app, flags.report);
}

void add_job_common_flags(CLI::App* app, JobOptions& job) {
  app->add_option("--name", job.name, "free text shown by `surfacer list` (default: the first input's file name)");
  CLI::Option* encoding =
      app->add_option("--encoding", job.encoding,
                      "frames on the wire: draco (the default: small; standard .drc files), meshopt (meshoptimizer's "
                      "codecs: ~10x faster to encode and decode, ~3x larger: for fast networks) or raw (lossless "
                      "binary PLY, double precision)")
          ->check(CLI::IsMember({"draco", "meshopt", "raw"}))
          ->type_name("CODEC");
  app->add_flag_callback(
         "--raw", [&job] { job.encoding = "raw"; }, "the same as --encoding raw")
      ->excludes(encoding);
  app->add_flag("--normals", job.normals, "per-vertex normals in every frame");
  app->add_option("--quantization-bits", job.quantization_bits,
                  "position quantization of Draco and meshopt frames, 1..30 bits" +
                      default_text(kDracoDefaults.quantization_bits))
      ->check(CLI::Range(1, 30))
      ->type_name("B");
}

void add_job_types(CLI::App* parent, const std::string& verb, JobFlags& flags, OutputFlags* output) {
  add_isosurface(parent, verb, flags, output);
  add_particles(parent, verb, flags, output);
  add_optimize(parent, verb, flags, output);
  add_active(parent, verb, flags, output);
}

std::vector<double> parse_numbers(const std::string& text, std::size_t count, const std::string& flag,
                                  const std::string& example) {
  std::vector<double> values;
  std::size_t pos = 0;
  while (true) {
    const std::size_t comma = text.find(',', pos);
    const std::string item = text.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos);
    double value = 0;
    auto [end, ec] = std::from_chars(item.data(), item.data() + item.size(), value);
    if (item.empty() || ec != std::errc() || end != item.data() + item.size() || !std::isfinite(value)) {
      throw usage(flag + " \"" + text + "\" must be " + std::to_string(count) + " comma-separated numbers, e.g. " +
                  flag + "=" + example);
    }
    values.push_back(value);
    if (comma == std::string::npos) break;
    pos = comma + 1;
  }
  if (values.size() != count) {
    throw usage(flag + " \"" + text + "\" has " + std::to_string(values.size()) + " numbers; it needs " +
                std::to_string(count) + ", e.g. " + flag + "=" + example);
  }
  return values;
}

Box parse_box(const std::string& text, const std::string& flag) {
  const auto v = parse_numbers(text, 6, flag, "-1,-1,-1,1,1,1 (x0,y0,z0,x1,y1,z1)");
  const char* axes = "xyz";
  for (int i = 0; i < 3; ++i) {
    if (!(v[i] < v[i + 3])) {
      throw usage(flag + ": the minimum " + axes[i] + " (" + number_text(v[i]) + ") must be below the maximum " +
                  axes[i] + " (" + number_text(v[i + 3]) + ")");
    }
  }
  return {v[0], v[1], v[2], v[3], v[4], v[5]};
}

std::array<int, 3> parse_sweeps(const std::string& text) {
  const auto v = parse_numbers(text, 3, "--sweeps", "5,15,5 (Laplacian,Bilaplacian,polish)");
  std::array<int, 3> sweeps{};
  for (int i = 0; i < 3; ++i) {
    if (v[i] < 0 || v[i] != std::floor(v[i]) || v[i] > 1e6) {
      throw usage("--sweeps \"" + text + "\": sweep counts are whole numbers >= 0, e.g. --sweeps 5,15,5");
    }
    sweeps[i] = static_cast<int>(v[i]);
  }
  return sweeps;
}

FlowSet parse_flows(const std::string& text) {
  FlowSet flows{false, false, false};
  std::size_t pos = 0;
  while (true) {
    const std::size_t comma = text.find(',', pos);
    const std::string item = text.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos);
    if (item == "d") {
      flows.d = true;
    } else if (item == "n") {
      flows.n = true;
    } else if (item == "t") {
      flows.t = true;
    } else {
      throw usage("--flows \"" + text + "\": \"" + item +
                  "\" is not a flow; list some of d (distance), n (normal), t (tangential), e.g. --flows d,n");
    }
    if (comma == std::string::npos) break;
    pos = comma + 1;
  }
  return flows;
}

JobOptions finish_job(JobFlags& flags, const std::string& verb) {
  JobOptions job = flags.job;
  std::vector<std::string> types;
  if (flags.isosurface->parsed()) types.emplace_back("isosurface");
  if (flags.particles_app->parsed()) types.emplace_back("particles");
  if (flags.optimize_app->parsed()) types.emplace_back("optimize");
  if (flags.active_app->parsed()) types.emplace_back("active");
  if (job.spec && !types.empty()) {
    throw usage(verb + ": give either --spec FILE or a job type (" + types.front() + "), not both");
  }
  if (!job.spec && types.empty()) {
    throw usage(verb + " needs a job: `surfacer " + verb + " isosurface|particles|optimize|active ...` or `surfacer " +
                verb + " --spec job.json`");
  }
  if (job.encoding == "raw" && job.quantization_bits) {
    throw usage(
        "--quantization-bits applies to Draco and meshopt frames; raw frames are lossless PLY: drop one of "
        "them");
  }
  if (job.spec) return job;

  const std::string& type = types.front();
  if (type == "isosurface") {
    IsosurfaceOptions iso = flags.iso;
    if (flags.iso_bounds) iso.bounds = parse_box(*flags.iso_bounds, "--bounds");
    job.isosurface = iso;
  } else if (type == "particles") {
    ParticlesOptions p = flags.particles;
    if (!p.r_inner && !p.derive_r_inner) {
      throw usage("particles needs --r-inner R (e.g. the simulation's particle radius) or --derive-r-inner");
    }
    if (p.r_inner && p.r_outer && !(*p.r_outer > *p.r_inner)) {
      throw usage("--r-outer (" + number_text(*p.r_outer) + ") must exceed --r-inner (" + number_text(*p.r_inner) +
                  "); the default is 2 x r_inner");
    }
    if (flags.sweeps) p.sweeps = parse_sweeps(*flags.sweeps);
    if (flags.container_box) p.container_box = parse_box(*flags.container_box, "--container-box");
    job.particles = p;
  } else if (type == "optimize") {
    OptimizeOptions o = flags.optimize;
    if (flags.start_bounds) o.start_bounds = parse_box(*flags.start_bounds, "--start-bounds");
    if (flags.flows) o.flows = parse_flows(*flags.flows);
    if (o.t_flow_iterations && o.flows && !o.flows->t) {
      throw usage("--t-flow-iterations sets how long the T-flow runs, but --flows \"" + *flags.flows +
                  "\" turns it off: add t to --flows or drop --t-flow-iterations");
    }
    job.optimize = o;
  } else {
    ActiveOptions a = flags.active;
    if (flags.active_bounds) a.bounds = parse_box(*flags.active_bounds, "--bounds");
    if (flags.coat_app->parsed()) {
      a.mode = flags.coat;
    } else if (flags.morph_app->parsed()) {
      a.mode = flags.morph;
    } else {
      ActiveAdvectOptions advect = flags.advect;
      if (flags.enright == flags.velocity_grid.has_value()) {
        throw usage(
            "active advect needs one velocity field: --enright [--period T] or --velocity-grid FILE.raw "
            "--velocity-origin x,y,z --velocity-spacing dx,dy,dz --velocity-dims nx,ny,nz");
      }
      if (flags.velocity_grid) {
        if (!flags.velocity_origin || !flags.velocity_spacing || !flags.velocity_dims) {
          throw usage(
              "--velocity-grid needs --velocity-origin x,y,z, --velocity-spacing dx,dy,dz and "
              "--velocity-dims nx,ny,nz");
        }
        VelocityGridOptions grid;
        grid.file = *flags.velocity_grid;
        grid.origin = parse_triple(*flags.velocity_origin, "--velocity-origin", "0,0,0");
        grid.spacing = parse_triple(*flags.velocity_spacing, "--velocity-spacing", "0.1,0.1,0.1");
        for (double s : grid.spacing) {
          if (!(s > 0))
            throw usage("--velocity-spacing \"" + *flags.velocity_spacing + "\": every spacing must be > 0");
        }
        const Triple dims = parse_triple(*flags.velocity_dims, "--velocity-dims", "21,21,21");
        for (int i = 0; i < 3; ++i) {
          if (dims[i] < 2 || dims[i] != std::floor(dims[i]) || dims[i] > 1e5) {
            throw usage("--velocity-dims \"" + *flags.velocity_dims +
                        "\": node counts are whole numbers from 2 to 100000");
          }
          grid.dims[i] = static_cast<int>(dims[i]);
        }
        advect.velocity_grid = grid;
      }
      a.mode = advect;
    }
    job.active = a;
  }
  return job;
}

}  // namespace surfacer::client
