#include "client/job_spec.h"

#include <google/protobuf/util/json_util.h>

#include <algorithm>
#include <fstream>
#include <sstream>

#include "client/exit_codes.h"
#include "client/job_fields.h"
#include "client/output_files.h"
#include "client/particle_files.h"
#include "core/mesh/frame_codec.h"
#include "core/mesh/mesh_io.h"
#include "core/util/errors.h"
#include "core/util/format.h"
#include "wire/job_options.h"
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

// The job's particle frames (particles or active coat).
google::protobuf::RepeatedPtrField<v1::ParticleFrame>& particle_frames(v1::JobSpec& spec) {
  return spec.has_particles() ? *spec.mutable_particles()->mutable_frames()
                              : *spec.mutable_active()->mutable_coat()->mutable_frames();
}

// The particle frames of `options` (particles, active coat): one empty frame per file in the spec, one pending upload
// each; a frame without radii needs r_inner or derive_r_inner, checked as each is read (wire::require_r_inner_frame).
std::vector<std::filesystem::path> add_particles(const JobOptions& options, PreparedJob& prepared,
                                                 const InMemoryInputs& in_memory) {
  v1::JobSpec& spec = prepared.spec;
  const ParticleInputFiles inputs = particle_inputs_of(options.particles, in_memory);
  const auto& files = inputs.files;
  prepared.frame_numbers = output_numbers(inputs.numbers);
  for (std::size_t i = 0; i < files.size(); ++i) particle_frames(spec).Add();
  const std::string r_inner_name = name_of_field(options.names, "spec.particles.r_inner", options.keywords);
  for (std::size_t i = 0; i < files.size(); ++i) {
    const int index = static_cast<int>(i);
    const std::filesystem::path& file = files[i];
    const auto it = in_memory.particles.find(file.string());
    const ParticleFrame* frame = it == in_memory.particles.end() ? nullptr : &it->second;  // outlives the upload
    PendingUpload upload;
    upload.description = "particle frame " + std::to_string(index) + " (" + file.string() + ")";
    upload.frame = index;
    upload.read = [file, frame, index, r_inner_name](v1::JobSpec& spec, const InputLimits& limits) {
      std::vector<std::string> attributes;
      if (spec.has_particles())
        attributes.assign(spec.particles().interpolate().begin(), spec.particles().interpolate().end());
      ParticleRecords records = frame != nullptr ? pack_particle_records(*frame, file.string(), limits, attributes)
                                                 : read_particle_records(file, limits, attributes);
      particle_frames(spec)[index].clear_attributes();
      for (const auto& [attribute, components] : records.attributes) {
        v1::ParticleAttribute* a = particle_frames(spec)[index].add_attributes();
        a->set_name(attribute);
        a->set_components(components);
      }
      if (spec.has_particles()) {
        try {
          wire::require_r_inner_frame(spec.particles(), static_cast<std::size_t>(index), records.with_radius);
        } catch (const Error& e) {
          throw CliError(ExitCode::kUsage, r_inner_name + ": " + e.what() + ": " + file.string());
        }
      }
      particle_frames(spec)[index].set_with_radius(records.with_radius);
      UploadData data;
      data.name = file.filename().string();
      data.bytes = std::move(records.bytes);
      data.particles = records.count;
      data.detail = std::to_string(records.count) + " particles" + (records.with_radius ? " with radii" : "");
      return data;
    };
    upload.set_id = [index](v1::JobSpec& spec, const std::string& id) {
      particle_frames(spec)[index].set_upload_id(id);
    };
    prepared.uploads.push_back(std::move(upload));
  }
  return files;
}

void build_optimize(const JobOptions& options, PreparedJob& prepared, const InMemoryInputs& in_memory) {
  v1::JobSpec& spec = prepared.spec;
  v1::OptimizeJob* job = spec.mutable_optimize();
  *job->mutable_scene() = scene_of(options.scenes.at(0), in_memory);
  if (options.start_mesh) {
    const std::filesystem::path file = *options.start_mesh;
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
    job->mutable_polygonize();  // set even when empty: the server's start defaults
  }
  spec.set_name(options.scenes.at(0).stem().string());
}

// The velocity grid's values: a file whose size the grid's dimensions fix, uploaded as is.
void add_velocity_grid(const std::filesystem::path& file, PreparedJob& prepared) {
  const v1::VelocityGrid& g = prepared.spec.active().advect().grid();
  require_file(file, "--velocity-grid");
  const std::uint64_t nodes = static_cast<std::uint64_t>(std::max(g.nx(), 0)) *
                              static_cast<std::uint64_t>(std::max(g.ny(), 0)) *
                              static_cast<std::uint64_t>(std::max(g.nz(), 0));
  const std::uint64_t expected = nodes * 3 * sizeof(float);
  std::error_code ec;
  const std::uintmax_t size = std::filesystem::file_size(file, ec);
  const std::string dims = std::to_string(g.nx()) + "," + std::to_string(g.ny()) + "," + std::to_string(g.nz());
  if (ec || size != expected) {
    throw CliError(ExitCode::kUsage, "--velocity-grid " + file.string() + ": " +
                                         (ec ? ec.message()
                                             : "has " + std::to_string(size) + " bytes; --velocity-dims " + dims +
                                                   " needs " + std::to_string(nodes) +
                                                   " nodes x 3 float32 = " + std::to_string(expected) + " bytes"));
  }
  PendingUpload upload;
  upload.description = "velocity grid (" + file.string() + ")";
  const std::string detail =
      std::to_string(g.nx()) + "x" + std::to_string(g.ny()) + "x" + std::to_string(g.nz()) + " nodes";
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
}

// The job's inputs read into its spec (scenes) or made pending uploads, and its default name.
void build_inputs(const JobOptions& options, PreparedJob& prepared, const InMemoryInputs& in_memory) {
  v1::JobSpec& spec = prepared.spec;
  switch (spec.kind_case()) {
    case v1::JobSpec::kIsosurface:
      for (const auto& path : options.scenes) *spec.mutable_isosurface()->add_scenes() = scene_of(path, in_memory);
      spec.set_name(first_and_more(options.scenes, ""));
      break;
    case v1::JobSpec::kParticles: {
      if (options.container_scene) {
        *spec.mutable_particles()->mutable_container()->mutable_solid() = scene_of(*options.container_scene, in_memory);
      }
      spec.set_name(first_and_more(add_particles(options, prepared, in_memory), "frames"));
      break;
    }
    case v1::JobSpec::kOptimize:
      build_optimize(options, prepared, in_memory);
      break;
    case v1::JobSpec::kActive: {
      v1::ActiveJob* job = spec.mutable_active();
      if (job->has_coat()) {
        spec.set_name("coat " + first_and_more(add_particles(options, prepared, in_memory), "frames"));
      } else if (job->has_morph()) {
        *job->mutable_morph()->mutable_from() = scene_of(options.scenes.at(0), in_memory);
        *job->mutable_morph()->mutable_to() = scene_of(options.scenes.at(1), in_memory);
        spec.set_name("morph " + options.scenes.at(0).stem().string() + " -> " + options.scenes.at(1).stem().string());
      } else {
        *job->mutable_advect()->mutable_shape() = scene_of(options.scenes.at(0), in_memory);
        if (options.velocity_grid) add_velocity_grid(*options.velocity_grid, prepared);
        spec.set_name("advect " + options.scenes.at(0).stem().string());
      }
      break;
    }
    case v1::JobSpec::KIND_NOT_SET:
      throw CliError(ExitCode::kUsage,
                     "no job given: use a job type (isosurface, particles, optimize, active) or --spec FILE");
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

void check_job(const JobOptions& options) {
  const v1::JobSpec& spec = options.spec;
  if (spec.has_active() && spec.active().has_advect()) {
    // A velocity grid is a file and its geometry (origin, spacing, dims), given together.
    const bool python = options.keywords;
    const std::string file = python ? "velocity_grid" : "--velocity-grid";
    if (options.velocity_grid) {
      for (const char* part : {"origin", "spacing", "nx"}) {
        if (options.names.count(std::string("spec.active.advect.grid.") + part) == 0) {
          throw CliError(ExitCode::kUsage, file + (python ? " needs velocity_origin, velocity_spacing and "
                                                            "velocity_dims"
                                                          : " needs --velocity-origin x,y,z, --velocity-spacing "
                                                            "dx,dy,dz and --velocity-dims nx,ny,nz"));
        }
      }
    } else if (spec.active().advect().has_grid()) {
      throw CliError(ExitCode::kUsage, names_below(options.names, "spec.active.advect.grid") +
                                           " describes a velocity grid: give its values with " + file);
    }
  }
  try {
    wire::check_job_options(spec);
  } catch (const Error& e) {
    if (e.kind() != ErrorKind::kInvalidInput) throw;
    const std::string name = name_of_field(options.names, e.field(), options.keywords);
    throw CliError(ExitCode::kUsage, (name.empty() ? "" : name + ": ") + e.what());
  }
}

PreparedJob prepare_job(const JobOptions& options, const InMemoryInputs& in_memory) {
  PreparedJob prepared;
  v1::JobSpec& spec = prepared.spec;
  if (options.spec_file) {
    spec = read_job_spec_file(*options.spec_file);
    spec.mutable_output()->MergeFrom(options.spec.output());  // the output flags override the file's
  } else {
    check_job(options);
    spec = options.spec;
    build_inputs(options, prepared, in_memory);
  }
  if (options.name) {
    spec.set_name(*options.name);
  } else if (spec.name().size() > wire::kMaxNameBytes) {
    spec.set_name(utf8_prefix(spec.name(), wire::kMaxNameBytes));  // a name made from long file names
  }
  try {
    wire::check_request_limits(spec, "spec");
  } catch (const Error& e) {
    throw CliError(ExitCode::kUsage, std::string(e.what()) + (options.name ? " (--name)" : ""));
  }
  return prepared;
}

std::optional<int> frames_before_run(const v1::JobSpec& spec) {
  if (spec.has_isosurface()) return spec.isosurface().scenes_size();
  if (spec.has_particles()) return spec.particles().frames_size();
  if (spec.has_optimize()) return spec.optimize().snapshot_every() > 0 ? std::nullopt : std::optional<int>(1);
  if (spec.has_active() && spec.active().has_coat()) return spec.active().coat().frames_size();
  return std::nullopt;
}

namespace {

// Draco frames come in pieces, unless a standard .drc file is written from the stream (see job_spec.h).
void ask_for_pieces_unless_drc(v1::OutputOptions& output, bool writes_drc) {
  const bool draco = output.encoding() == v1::MESH_ENCODING_UNSPECIFIED || output.encoding() == v1::MESH_ENCODING_DRACO;
  if (draco && !writes_drc) output.set_encoding(v1::MESH_ENCODING_DRACO_PIECES);
}

}  // namespace

void fit_encoding_to_memory(v1::JobSpec& spec) { ask_for_pieces_unless_drc(*spec.mutable_output(), false); }

void fit_encoding_to_files(v1::JobSpec& spec, const std::vector<FileFormat>& formats) {
  v1::OutputOptions* output = spec.mutable_output();
  if (spec.has_particles() && spec.particles().interpolate_size() > 0) {
    // Every encoding carries them; OBJ and VDB files have no place for them.
    for (FileFormat format : formats) {
      if (format != FileFormat::kObj && format != FileFormat::kVdb) continue;
      throw CliError(ExitCode::kUsage, std::string("--interpolate with --format ") + file_format_name(format) +
                                           ": only ply, vtk, vtu, drc, glb and gltf files carry the interpolated "
                                           "attributes");
    }
  }
  if (std::find(formats.begin(), formats.end(), FileFormat::kGlb) != formats.end() &&
      output->encoding() != v1::MESH_ENCODING_PLY) {
    try {
      check_gltf_quantization_bits(output->quantization_bits());
    } catch (const Error& e) {
      throw CliError(ExitCode::kUsage, "--format glb with --quantization-bits " +
                                           std::to_string(output->quantization_bits()) + ": " + e.what());
    }
  }
  // With no format asked for, the pieces go to a .glb as they come (default_format, client/frame_writer.h): a .drc
  // only when glTF cannot hold the grid.
  const int bits = output->has_quantization_bits() ? output->quantization_bits() : DracoOptions{}.quantization_bits;
  const bool glb_holds_grid = bits <= kMaxGltfQuantizationBits;
  const bool writes_drc =
      formats.empty() ? !glb_holds_grid : std::find(formats.begin(), formats.end(), FileFormat::kDrc) != formats.end();
  ask_for_pieces_unless_drc(*output, writes_drc);
}

}  // namespace surfacer::client
