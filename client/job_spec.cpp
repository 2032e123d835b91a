#include "client/job_spec.h"

#include <google/protobuf/util/json_util.h>

#include <algorithm>
#include <fstream>
#include <sstream>

#include "client/exit_codes.h"
#include "client/output_files.h"
#include "client/particle_files.h"
#include "core/mesh/mesh_io.h"
#include "core/util/errors.h"
#include "core/util/format.h"
#include "wire/protocol.h"
#include "wire/request_limits.h"

namespace surfacer::client {
namespace {

std::string read_text_file(const std::filesystem::path& path, const char* what) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    throw CliError(ExitCode::kUsage, std::string("cannot read ") + what + " " + path.string() + ": " +
                                         std::generic_category().message(errno));
  }
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) throw CliError(ExitCode::kUsage, std::string("cannot read ") + what + " " + path.string());
  return text.str();
}

// `where` names the text in errors ("scene file a.json"), `root_path` the message in errors about its fields ("spec"
// for a JobSpec, "" for a Scene).
template <typename Message>
Message parse_json(const std::string& text, const std::string& where, const std::string& root_path) {
  Message message;
  google::protobuf::util::JsonParseOptions options;
  options.ignore_unknown_fields = false;
  auto status = google::protobuf::util::JsonStringToMessage(text, &message, options);
  // Protobuf's JSON parser stops at 100 nested objects: a scene that deep is refused the way the server refuses it.
  if (!status.ok() && wire::json_object_depth(text) >= 100)
    throw CliError(ExitCode::kUsage, where + ": " + wire::scene_too_deep());
  if (!status.ok()) {
    throw CliError(ExitCode::kUsage, where + " is not a valid " + Message::descriptor()->full_name() +
                                         " in protobuf JSON: " + std::string(status.message()));
  }
  try {
    wire::check_request_limits(message, root_path);
  } catch (const Error& e) {
    throw CliError(ExitCode::kUsage, where + ": " + e.what());
  }
  return message;
}

template <typename Message>
Message parse_json_file(const std::filesystem::path& path, const char* what, const std::string& root_path) {
  return parse_json<Message>(read_text_file(path, what), std::string(what) + " " + path.string(), root_path);
}

// A scene named in the options: in memory, or read from its file.
v1::Scene scene_of(const std::filesystem::path& path, const InMemoryInputs& in_memory) {
  const auto it = in_memory.scenes.find(path.string());
  if (it != in_memory.scenes.end()) return parse_scene_json(it->second, "scene " + it->first);
  return read_scene_file(path);
}

// The frames of `input`: files as the CLI expands them (with their frame numbers), and names the caller holds in
// memory (the Python package's arrays), which have none.
ParticleInputFiles particle_inputs_of(const ParticleInputOptions& input, const InMemoryInputs& in_memory) {
  const auto in_memory_input = [&](const std::string& name) { return in_memory.particles.count(name) != 0; };
  if (std::none_of(input.inputs.begin(), input.inputs.end(), in_memory_input)) return expand_particle_sequence(input);
  ParticleInputFiles frames;
  for (const std::string& name : input.inputs) {
    if (in_memory_input(name)) {
      frames.files.emplace_back(name);
      frames.numbers.emplace_back();
      continue;
    }
    ParticleInputOptions one;
    one.inputs = {name};
    if (is_sequence_pattern(name)) {
      one.start = input.start;
      one.end = input.end;
    }
    const ParticleInputFiles expanded = expand_particle_sequence(one);
    frames.files.insert(frames.files.end(), expanded.files.begin(), expanded.files.end());
    frames.numbers.insert(frames.numbers.end(), expanded.numbers.begin(), expanded.numbers.end());
  }
  return frames;
}

void set_vec3(v1::Vec3* v, double x, double y, double z) {
  v->set_x(x);
  v->set_y(y);
  v->set_z(z);
}

void set_bounds(v1::Bounds* bounds, const Box& b) {
  set_vec3(bounds->mutable_min(), b[0], b[1], b[2]);
  set_vec3(bounds->mutable_max(), b[3], b[4], b[5]);
}

v1::Polygonizer polygonizer(const std::string& name, const std::string& flag) {
  if (name == "cubes") return v1::POLYGONIZER_CUBES;
  if (name == "tiles") return v1::POLYGONIZER_TILES;
  throw CliError(ExitCode::kUsage, flag + " must be cubes or tiles, not " + name);
}

std::string first_and_more(const std::vector<std::filesystem::path>& files, const char* unit) {
  if (files.empty()) return "";
  std::string name = files.front().stem().string();
  if (files.size() > 1) {
    name += " (+" + std::to_string(files.size() - 1) + " more" + (*unit != '\0' ? " " : "") + unit + ")";
  }
  return name;
}

void require_file(const std::filesystem::path& path, const std::string& flag) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    throw CliError(ExitCode::kUsage, flag + " " + path.string() + ": " +
                                         (std::filesystem::exists(path, ec) ? "not a regular file" : "no such file"));
  }
}

// One pending upload per particle file; `frame_of(spec, i)` is the i-th ParticleFrame of the spec.
void add_particle_frames(PreparedJob& job, const std::vector<std::filesystem::path>& files,
                         v1::ParticleFrame* (*frame_of)(v1::JobSpec&, int), const InMemoryInputs& in_memory) {
  for (std::size_t i = 0; i < files.size(); ++i) {
    const int index = static_cast<int>(i);
    const std::filesystem::path& file = files[i];
    const auto it = in_memory.particles.find(file.string());
    const ParticleFrame* frame = it == in_memory.particles.end() ? nullptr : &it->second;  // outlives the upload
    PendingUpload upload;
    upload.description = "particle frame " + std::to_string(index) + " (" + file.string() + ")";
    upload.frame = index;
    upload.read = [file, frame, index, frame_of](v1::JobSpec& spec, const InputLimits& limits) {
      ParticleRecords records =
          frame != nullptr ? pack_particle_records(*frame, file.string(), limits) : read_particle_records(file, limits);
      frame_of(spec, index)->set_with_radius(records.with_radius);
      UploadData data;
      data.name = file.filename().string();
      data.bytes = std::move(records.bytes);
      data.particles = records.count;
      data.detail = std::to_string(records.count) + " particles" + (records.with_radius ? " with radii" : "");
      return data;
    };
    upload.set_id = [index, frame_of](v1::JobSpec& spec, const std::string& id) {
      frame_of(spec, index)->set_upload_id(id);
    };
    job.uploads.push_back(std::move(upload));
  }
}

void build_isosurface(const IsosurfaceOptions& iso, v1::JobSpec& spec, const InMemoryInputs& in_memory) {
  v1::IsosurfaceJob* job = spec.mutable_isosurface();
  for (const auto& path : iso.scenes) *job->add_scenes() = scene_of(path, in_memory);
  if (iso.bounds) set_bounds(job->mutable_bounds(), *iso.bounds);
  if (iso.cell_size) job->set_cell_size(*iso.cell_size);
  if (iso.cells) job->set_cells(*iso.cells);
  if (iso.method) job->set_method(polygonizer(*iso.method, "--method"));
  spec.set_name(first_and_more(iso.scenes, ""));
}

void build_particles(const ParticlesOptions& p, PreparedJob& prepared, const InMemoryInputs& in_memory) {
  v1::JobSpec& spec = prepared.spec;
  v1::ParticlesJob* job = spec.mutable_particles();
  const ParticleInputFiles inputs = particle_inputs_of(p.input, in_memory);
  const auto& files = inputs.files;
  prepared.frame_numbers = output_numbers(inputs.numbers);
  for (std::size_t i = 0; i < files.size(); ++i) job->add_frames();
  add_particle_frames(
      prepared, files, [](v1::JobSpec& s, int i) { return s.mutable_particles()->mutable_frames(i); }, in_memory);
  if (p.r_inner) job->set_r_inner(*p.r_inner);
  job->set_derive_r_inner(p.derive_r_inner);
  if (p.r_outer) job->set_r_outer(*p.r_outer);
  if (p.spacing_factor) job->set_spacing_factor(*p.spacing_factor);
  if (p.sweeps) {
    job->set_laplacian_sweeps((*p.sweeps)[0]);
    job->set_bilaplacian_sweeps((*p.sweeps)[1]);
    job->set_polish_sweeps((*p.sweeps)[2]);
  }
  if (p.relaxation) job->set_relaxation(*p.relaxation);
  if (p.erosion) job->set_erosion(*p.erosion);
  if (p.unconstrained_polish) job->set_unconstrained_polish(true);
  if (p.vertex_only_band) job->set_vertex_only_band(true);
  if (p.min_angle) job->set_min_angle_degrees(*p.min_angle);
  if (p.container_box) set_bounds(job->mutable_container()->mutable_box(), *p.container_box);
  if (p.container_scene) *job->mutable_container()->mutable_solid() = scene_of(*p.container_scene, in_memory);
  if (p.min_particles) job->set_min_particles_per_component(*p.min_particles);
  spec.set_name(first_and_more(files, "frames"));
}

void build_optimize(const OptimizeOptions& o, PreparedJob& prepared, const InMemoryInputs& in_memory) {
  v1::JobSpec& spec = prepared.spec;
  v1::OptimizeJob* job = spec.mutable_optimize();
  *job->mutable_scene() = scene_of(o.scene, in_memory);
  if (o.start_mesh) {
    const std::filesystem::path file = *o.start_mesh;
    require_file(file, "--start-mesh");
    MeshFormat format = MeshFormat::kPly;
    try {
      format = mesh_format_from_path(file);
    } catch (const Error& e) {
      throw CliError(ExitCode::kUsage, "--start-mesh " + file.string() + ": " + e.what());
    }
    PendingUpload upload;
    upload.description = "start mesh (" + file.string() + ")";
    upload.read = [file, format](v1::JobSpec&, const InputLimits&) {
      UploadData data;
      data.name = file.filename().string();
      data.bytes = read_text_file(file, "start mesh");
      try {  // a bad mesh is the user's to fix: say where, before any job is queued
        const Mesh mesh = parse_mesh(data.bytes, format, file.string());
        if (mesh.triangles.empty()) throw InvalidInput("file", file.string() + ": the mesh has no triangles");
        data.detail =
            std::to_string(mesh.vertices.size()) + " vertices, " + std::to_string(mesh.triangles.size()) + " triangles";
      } catch (const Error& e) {
        throw CliError(ExitCode::kUsage, std::string("--start-mesh: ") + e.what());
      }
      return data;
    };
    upload.set_id = [](v1::JobSpec& s, const std::string& id) { s.mutable_optimize()->set_mesh_upload_id(id); };
    prepared.uploads.push_back(std::move(upload));
  } else {
    v1::Polygonize* start = job->mutable_polygonize();  // set even when empty: the server's start defaults
    if (o.start_method) start->set_method(polygonizer(*o.start_method, "--start-method"));
    if (o.start_bounds) set_bounds(start->mutable_bounds(), *o.start_bounds);
    if (o.start_cells) start->set_cells(*o.start_cells);
  }
  if (o.flows) {
    job->set_d_flow(o.flows->d);
    job->set_n_flow(o.flows->n);
    job->set_t_flow(o.flows->t);
  }
  if (o.c_d) job->set_c_d(*o.c_d);
  if (o.c_n) job->set_c_n(*o.c_n);
  if (o.c_t) job->set_c_t(*o.c_t);
  if (o.step_bound) job->set_step_bound(*o.step_bound);
  job->set_modified_flows(o.modified_flows);
  if (o.t_flow_iterations) job->set_t_flow_iterations(*o.t_flow_iterations);
  if (o.iterations) job->set_max_iterations(*o.iterations);
  if (o.tolerance) job->set_tolerance(*o.tolerance);
  if (o.subdivide) job->set_subdivision_threshold(*o.subdivide);
  if (o.triangle_budget) job->set_triangle_budget(*o.triangle_budget);
  if (o.snapshot_every) job->set_snapshot_every(*o.snapshot_every);
  spec.set_name(o.scene.stem().string());
}

void build_active(const ActiveOptions& a, PreparedJob& prepared, const InMemoryInputs& in_memory) {
  v1::JobSpec& spec = prepared.spec;
  v1::ActiveJob* job = spec.mutable_active();
  job->set_grid_spacing(a.grid_spacing);
  if (a.bounds) set_bounds(job->mutable_bounds(), *a.bounds);
  if (a.alpha) job->set_alpha(*a.alpha);
  if (a.beta) job->set_beta(*a.beta);
  if (a.gamma) job->set_gamma(*a.gamma);
  if (a.delta) job->set_delta(*a.delta);
  if (a.cfl) job->set_cfl(*a.cfl);
  if (a.polygonizer) job->set_polygonizer(polygonizer(*a.polygonizer, "--polygonizer"));

  if (const auto* coat = std::get_if<ActiveCoatOptions>(&a.mode)) {
    v1::ActiveCoat* c = job->mutable_coat();
    const ParticleInputFiles inputs = particle_inputs_of(coat->input, in_memory);
    const auto& files = inputs.files;
    prepared.frame_numbers = output_numbers(inputs.numbers);
    for (std::size_t i = 0; i < files.size(); ++i) c->add_frames();
    add_particle_frames(
        prepared, files, [](v1::JobSpec& s, int i) { return s.mutable_active()->mutable_coat()->mutable_frames(i); },
        in_memory);
    c->set_kernel_radius(coat->kernel_radius);
    if (coat->iso) c->set_iso(*coat->iso);
    if (coat->substeps) c->set_substeps_per_frame(*coat->substeps);
    spec.set_name("coat " + first_and_more(files, "frames"));
  } else if (const auto* morph = std::get_if<ActiveMorphOptions>(&a.mode)) {
    v1::ActiveMorph* m = job->mutable_morph();
    *m->mutable_from() = scene_of(morph->from, in_memory);
    *m->mutable_to() = scene_of(morph->to, in_memory);
    if (morph->tolerance) m->set_tolerance(*morph->tolerance);
    if (morph->max_frames) m->set_max_frames(*morph->max_frames);
    if (morph->frame_time) m->set_frame_time(*morph->frame_time);
    spec.set_name("morph " + morph->from.stem().string() + " -> " + morph->to.stem().string());
  } else {
    const auto& advect = std::get<ActiveAdvectOptions>(a.mode);
    v1::ActiveAdvect* m = job->mutable_advect();
    *m->mutable_shape() = scene_of(advect.scene, in_memory);
    m->set_frame_interval(advect.frame_interval);
    m->set_frames(advect.frames);
    if (advect.velocity_grid) {
      const VelocityGridOptions& g = *advect.velocity_grid;
      v1::VelocityGrid* grid = m->mutable_grid();
      set_vec3(grid->mutable_origin(), g.origin[0], g.origin[1], g.origin[2]);
      set_vec3(grid->mutable_spacing(), g.spacing[0], g.spacing[1], g.spacing[2]);
      grid->set_nx(g.dims[0]);
      grid->set_ny(g.dims[1]);
      grid->set_nz(g.dims[2]);
      require_file(g.file, "--velocity-grid");
      const std::uint64_t nodes = static_cast<std::uint64_t>(g.dims[0]) * static_cast<std::uint64_t>(g.dims[1]) *
                                  static_cast<std::uint64_t>(g.dims[2]);
      const std::uint64_t expected = nodes * 3 * sizeof(float);
      std::error_code ec;
      const std::uintmax_t size = std::filesystem::file_size(g.file, ec);
      if (ec || size != expected) {
        throw CliError(
            ExitCode::kUsage,
            "--velocity-grid " + g.file.string() + ": " +
                (ec ? ec.message()
                    : "has " + std::to_string(size) + " bytes; --velocity-dims " + std::to_string(g.dims[0]) + "," +
                          std::to_string(g.dims[1]) + "," + std::to_string(g.dims[2]) + " needs " +
                          std::to_string(nodes) + " nodes x 3 float32 = " + std::to_string(expected) + " bytes"));
      }
      PendingUpload upload;
      upload.description = "velocity grid (" + g.file.string() + ")";
      const std::filesystem::path file = g.file;
      const std::string detail =
          std::to_string(g.dims[0]) + "x" + std::to_string(g.dims[1]) + "x" + std::to_string(g.dims[2]) + " nodes";
      upload.read = [file, expected, detail](v1::JobSpec&, const InputLimits&) {
        UploadData data;
        data.name = file.filename().string();
        data.file = file;
        data.file_bytes = expected;
        data.detail = detail;
        return data;
      };
      upload.set_id = [](v1::JobSpec& s, const std::string& id) {
        s.mutable_active()->mutable_advect()->mutable_grid()->set_upload_id(id);
      };
      prepared.uploads.push_back(std::move(upload));
    } else {
      v1::EnrightVelocity* enright = m->mutable_enright();
      if (advect.enright_period) enright->set_period(*advect.enright_period);
    }
    spec.set_name("advect " + advect.scene.stem().string());
  }
}

}  // namespace

v1::Scene parse_scene_json(const std::string& text, const std::string& where) {
  return parse_json<v1::Scene>(text, where, "");
}

v1::Scene read_scene_file(const std::filesystem::path& path) {
  return parse_json_file<v1::Scene>(path, "scene file", "");
}

v1::JobSpec read_job_spec_file(const std::filesystem::path& path) {
  return parse_json_file<v1::JobSpec>(path, "job spec file", "spec");
}

PreparedJob prepare_job(const JobOptions& options, const InMemoryInputs& in_memory) {
  PreparedJob prepared;
  v1::JobSpec& spec = prepared.spec;
  if (options.spec) {
    spec = read_job_spec_file(*options.spec);
  } else if (options.isosurface) {
    build_isosurface(*options.isosurface, spec, in_memory);
  } else if (options.particles) {
    build_particles(*options.particles, prepared, in_memory);
  } else if (options.optimize) {
    build_optimize(*options.optimize, prepared, in_memory);
  } else if (options.active) {
    build_active(*options.active, prepared, in_memory);
  } else {
    throw CliError(ExitCode::kUsage,
                   "no job given: use a job type (isosurface, particles, optimize, active) or "
                   "--spec FILE");
  }

  if (options.name) {
    spec.set_name(*options.name);
  } else if (spec.name().size() > wire::kMaxNameBytes) {
    spec.set_name(utf8_prefix(spec.name(), wire::kMaxNameBytes));  // a name made from long file names
  }
  v1::OutputOptions* output = spec.mutable_output();
  if (options.encoding == "raw") output->set_encoding(v1::MESH_ENCODING_PLY);
  if (options.encoding == "meshopt") output->set_encoding(v1::MESH_ENCODING_MESHOPT);
  if (options.encoding == "draco") output->set_encoding(v1::MESH_ENCODING_DRACO);
  if (options.encoding && *options.encoding != "raw" && *options.encoding != "meshopt" &&
      *options.encoding != "draco") {
    throw CliError(ExitCode::kUsage, "--encoding must be draco, meshopt or raw, not " + *options.encoding);
  }
  if (options.normals) output->set_normals(true);
  if (options.quantization_bits) output->set_quantization_bits(*options.quantization_bits);
  try {
    wire::check_request_limits(spec, "spec");
  } catch (const Error& e) {
    throw CliError(ExitCode::kUsage, std::string(e.what()) + (options.name ? " (--name)" : ""));
  }
  return prepared;
}

void fit_encoding_to_files(v1::JobSpec& spec, const std::vector<FileFormat>& formats) {
  v1::OutputOptions* output = spec.mutable_output();
  if (std::find(formats.begin(), formats.end(), FileFormat::kGlb) != formats.end() &&
      output->encoding() != v1::MESH_ENCODING_PLY && output->quantization_bits() > 16) {
    throw CliError(ExitCode::kUsage,
                   "--format glb holds positions of at most 16 bits (glTF's KHR_mesh_quantization), "
                   "not --quantization-bits " +
                       std::to_string(output->quantization_bits()) + ": use 16 or fewer, or another --format");
  }
  const bool draco =
      output->encoding() == v1::MESH_ENCODING_UNSPECIFIED || output->encoding() == v1::MESH_ENCODING_DRACO;
  if (draco && !formats.empty() && std::find(formats.begin(), formats.end(), FileFormat::kDrc) == formats.end()) {
    output->set_encoding(v1::MESH_ENCODING_DRACO_PIECES);
  }
}

}  // namespace surfacer::client
