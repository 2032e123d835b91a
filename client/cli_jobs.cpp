#include "client/cli_jobs.h"

#include "client/exit_codes.h"
#include "client/job_fields.h"
#include "client/job_spec.h"
#include "client/output_files.h"
#include "core/mesh/decimate.h"
#include "core/mesh/mesh_codec.h"
#include "core/util/format.h"

namespace surfacer::client {
namespace {

CliError usage(const std::string& message) { return CliError(ExitCode::kUsage, message); }

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
                      "particle file (.xyz .txt .csv .ply .vtk .vtu .vtp .bin .bgeo .json, gzip allowed) or sequence "
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

// The flags of `table` (client/job_fields.h): each sets its proto field as it is parsed, under every spelling.
void add_table_flags(CLI::App* app, JobTable table, JobOptions& job) {
  for (const JobField& field : job_fields(table)) {
    std::string names = cli_flag(spelling(field));
    std::string label = names;  // how an error names it: every spelling the flag has
    for (const std::string& alias : field.aliases) {
      names += "," + cli_flag(alias);
      label += "/" + cli_flag(alias);
    }
    const std::string help = field.help + (field.default_value ? " (default " + field.default_value() + ")" : "");
    if (field.value_name.empty()) {
      app->add_flag_callback(
          names, [&job, table, &field, label] { set_job_field(job.spec, table, field, "true", label, job.names); },
          help);
    } else {
      app->add_option_function<std::string>(
             names,
             [&job, table, &field, label](const std::string& text) {
               set_job_field(job.spec, table, field, text, label, job.names);
             },
             help)
          ->type_name(field.value_name);
    }
  }
}

void add_isosurface(CLI::App* parent, const std::string& verb, JobFlags& flags, OutputFlags* output) {
  CLI::App* iso = parent->add_subcommand("isosurface", "Polygonize the surface f = 0 of one or more scenes");
  iso->add_option("--scene", flags.scenes,
                  "scene file (protobuf JSON of surfacer.v1.Scene); repeat for a sequence, one frame per scene")
      ->required()
      ->type_name("FILE");
  add_table_flags(iso, JobTable::kIsosurface, flags.job);
  add_job_common_flags(iso, flags.job);
  if (output != nullptr) add_output_flags(iso, *output);
  set_examples(iso, verb,
               {"surfacer run isosurface --scene a.json --scene b.json --cells 64 --method tiles "
                "--bounds=-2,-2,-2,2,2,2 -o out/ --format drc,ply"},
               {"surfacer --server localhost:50051 submit isosurface --scene a.json --scene b.json --cells 64"});
  flags.isosurface = iso;
}

void add_particles(CLI::App* parent, const std::string& verb, JobFlags& flags, OutputFlags* output) {
  CLI::App* app = parent->add_subcommand(
      "particles", "Surface particle frames (Williams 2008): one smooth, watertight mesh per frame");
  add_particle_inputs(app, flags.particle_inputs);
  add_table_flags(app, JobTable::kParticles, flags.job);
  app->add_option("--container-scene", flags.job.container_scene,
                  "keep the surface inside this implicit solid (scene JSON, negative inside; container.solid)")
      ->type_name("FILE");
  add_job_common_flags(app, flags.job);
  if (output != nullptr) add_output_flags(app, *output);
  set_examples(
      app, verb,
      {"surfacer run particles --input 'sim/fluid_{:04d}.bgeo' --start 0 --end 199 --r-inner 0.01 -o out/ "
       "--format ply",
       "surfacer run particles --input drop.xyz --derive-r-inner --container-box 0,0,0,1,1,1 -o out/"},
      {"surfacer --server localhost:50051 submit particles --input 'sim/fluid_{}.bgeo' --r-inner 0.01"},
      std::string("Every frame is read once first (a bad file stops the command, exit 2, naming the file and\n"
                  "the line or byte, before any job is queued); then the job starts with the first frame and\n"
                  "each later one joins it as it is uploaded (float32), so the server surfaces frame k while\n"
                  "frame k+1 uploads (a server without open sequences gets them all first).\n") +
          "frame_NNNN carries the input's frame number (one pattern, or increasing numbers), else N\ncounts the "
          "inputs from 0. " +
          (verb == "run" ? "A table of particles, triangles and seconds per frame is printed at the\nend.\n"
                         : "The job id is printed once every frame is uploaded and part of the job\n(whose first "
                           "frames may be done by then); `surfacer watch ID -o DIR` fetches the meshes\nand prints "
                           "the table.\n"));
  flags.particles_app = app;
}

void add_optimize(CLI::App* parent, const std::string& verb, JobFlags& flags, OutputFlags* output) {
  CLI::App* app = parent->add_subcommand(
      "optimize", "Optimize a mesh toward a scene's surface (Ohtake-Belyaev-Pasko 2002), recovering sharp features");
  app->add_option("--scene", flags.scene, "the field: scene file (protobuf JSON of surfacer.v1.Scene)")
      ->required()
      ->type_name("FILE");
  app->add_option("--start-mesh", flags.job.start_mesh,
                  "start mesh file (.ply, .obj, .drc, .glb or .gltf), uploaded as is (instead of polygonize.*)")
      ->type_name("FILE");
  add_table_flags(app, JobTable::kOptimize, flags.job);
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
  add_table_flags(app, JobTable::kActive, flags.job);
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
  add_particle_inputs(coat, flags.particle_inputs);
  add_table_flags(coat, JobTable::kCoat, flags.job);
  add_active_common(coat, flags, output);
  coat->footer("Example:\n  " + coat_example +
               "\nParticle frames are uploaded one at a time before the job is queued (only `particles` jobs start\n"
               "with the first frame and take the others as they are uploaded).\n\n" +
               kGlobalNote);

  CLI::App* morph = active->add_subcommand("morph", "Morph scene A into scene B, one frame per output step");
  morph->add_option("--from", flags.from, "start scene file (JSON)")->required()->type_name("A.json");
  morph->add_option("--to", flags.to, "target scene file (JSON)")->required()->type_name("B.json");
  add_table_flags(morph, JobTable::kMorph, flags.job);
  add_active_common(morph, flags, output);
  morph->footer("Example:\n  " + morph_example + "\n\n" + kGlobalNote);

  CLI::App* advect = active->add_subcommand("advect", "Carry a scene with a velocity field");
  advect->add_option("--scene", flags.scene, "the shape: scene file (JSON)")->required()->type_name("FILE");
  CLI::Option* enright =
      advect->add_flag("--enright", flags.enright, "the Enright/LeVeque deformation field (analytic)");
  advect
      ->add_option("--velocity-grid", flags.velocity_grid,
                   "sampled velocity: raw little-endian float32 x y z per node, x fastest (with --velocity-origin, "
                   "--velocity-spacing, --velocity-dims)")
      ->excludes(enright)
      ->type_name("FILE.raw");
  add_table_flags(advect, JobTable::kAdvect, flags.job);
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

}  // namespace

void add_output_flags(CLI::App* app, OutputFlags& flags) {
  app->add_option("-o,--output", flags.dir,
                  "directory for frame_NNNN.<ext> files, stats.csv (and iterations.csv for optimize) (created); or a "
                  "file pattern such as 'out/surface_{:04d}.ply' whose extension sets the format. NNNN is the "
                  "input sequence's own frame number (--start 100 writes frame_0100), else the frame index")
      ->type_name("DIR|PATTERN");
  app->add_option(
         "--format", flags.formats,
         "files per frame, comma-separated: drc,ply,obj,vtk,vtu,glb,gltf,vdb (default: .glb for Draco frames, "
         ".drc over 16 quantization bits, .ply for meshopt and raw ones; drc = one standard Draco mesh, "
         "encoded on one core; vtk = legacy binary, vtu = VTK XML with zlib, for ParaView; glb = "
         "glTF with Draco pieces, encoded on every core, for three.js, blender.org builds and glTF readers with Draco, "
         "up to 16 quantization bits; gltf = plain glTF, uncompressed, for readers without Draco such as Debian's "
         "Blender and VTK; vdb = OpenVDB narrow-band level set, for Houdini, Blender volumes and OpenVDB)")
      ->delimiter(',')
      ->check(CLI::IsMember(file_format_names()))
      ->type_name("LIST");
  app->add_option("--vdb-voxel-size", flags.vdb_voxel_size,
                  "voxel edge of .vdb files in scene units (default: each frame's mean edge length)")
      ->check(CLI::PositiveNumber)
      ->type_name("H");
  add_report_flags(app, flags.report);
}

void add_job_common_flags(CLI::App* app, JobOptions& job) {
  app->add_option("--name", job.name, "free text shown by `surfacer list` (default: the first input's file name)");
  add_table_flags(app, JobTable::kOutput, job);  // --encoding, --normals, --quantization-bits, ..., --decimate
  const JobField& encoding = job_field(JobTable::kOutput, "encoding");
  app->add_flag_callback(
         "--raw",
         [&job, &encoding] { set_job_field(job.spec, JobTable::kOutput, encoding, "raw", "--raw", job.names); },
         "the same as --encoding raw")
      ->excludes(app->get_option(cli_flag(spelling(encoding))));
}

void add_job_types(CLI::App* parent, const std::string& verb, JobFlags& flags, OutputFlags* output) {
  add_isosurface(parent, verb, flags, output);
  add_particles(parent, verb, flags, output);
  add_optimize(parent, verb, flags, output);
  add_active(parent, verb, flags, output);
}

JobOptions finish_job(JobFlags& flags, const std::string& verb) {
  JobOptions job = flags.job;
  std::vector<std::string> types;
  if (flags.isosurface->parsed()) types.emplace_back("isosurface");
  if (flags.particles_app->parsed()) types.emplace_back("particles");
  if (flags.optimize_app->parsed()) types.emplace_back("optimize");
  if (flags.active_app->parsed()) types.emplace_back("active");
  if (job.spec_file && !types.empty()) {
    throw usage(verb + ": give either --spec FILE or a job type (" + types.front() + "), not both");
  }
  if (!job.spec_file && types.empty()) {
    throw usage(verb + " needs a job: `surfacer " + verb + " isosurface|particles|optimize|active ...` or `surfacer " +
                verb + " --spec job.json`");
  }
  if (job.spec.output().encoding() == v1::MESH_ENCODING_PLY && job.spec.output().has_quantization_bits()) {
    throw usage(
        "--quantization-bits applies to Draco and meshopt frames; raw frames are lossless PLY: drop one of "
        "them");
  }
  if (job.spec_file) return job;

  const std::string& type = types.front();
  if (type == "isosurface") {
    table_message(job.spec, JobTable::kIsosurface);
    job.scenes = flags.scenes;
  } else if (type == "particles") {
    table_message(job.spec, JobTable::kParticles);
    job.particles = flags.particle_inputs;
  } else if (type == "optimize") {
    table_message(job.spec, JobTable::kOptimize);
    job.scenes = {flags.scene};
    if (job.start_mesh && job.spec.optimize().has_polygonize()) {
      const std::string given = names_below(job.names, "spec.optimize.polygonize");
      throw usage("--start-mesh and " + given +
                  " both give the start mesh: upload one (--start-mesh) or have the server polygonize the scene");
    }
  } else if (flags.coat_app->parsed()) {
    table_message(job.spec, JobTable::kCoat);
    job.particles = flags.particle_inputs;
  } else if (flags.morph_app->parsed()) {
    table_message(job.spec, JobTable::kMorph);
    job.scenes = {flags.from, flags.to};
  } else {
    table_message(job.spec, JobTable::kAdvect);
    const v1::ActiveAdvect& set = job.spec.active().advect();
    job.scenes = {flags.scene};
    if (flags.enright == flags.velocity_grid.has_value()) {
      throw usage(
          "active advect needs one velocity field: --enright [--period T] or --velocity-grid FILE.raw "
          "--velocity-origin x,y,z --velocity-spacing dx,dy,dz --velocity-dims nx,ny,nz");
    }
    if (set.has_enright() && !flags.enright) {
      throw usage(name_of_field(job.names, "spec.active.advect.enright", false) +
                  " is the Enright field's: add --enright");
    }
    if (flags.velocity_grid) {
      job.velocity_grid = flags.velocity_grid;
    } else if (!set.has_grid()) {
      job.spec.mutable_active()->mutable_advect()->mutable_enright();
    }
  }
  check_job(job);
  return job;
}

}  // namespace surfacer::client
