#include "client/job_spec.h"

#include <google/protobuf/util/json_util.h>

#include <fstream>
#include <sstream>

#include "client/exit_codes.h"

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

template <typename Message>
Message parse_json_file(const std::filesystem::path& path, const char* what) {
  const std::string text = read_text_file(path, what);
  Message message;
  google::protobuf::util::JsonParseOptions options;
  options.ignore_unknown_fields = false;
  auto status = google::protobuf::util::JsonStringToMessage(text, &message, options);
  if (!status.ok()) {
    throw CliError(ExitCode::kUsage, std::string(what) + " " + path.string() + " is not a valid " +
                                         Message::descriptor()->full_name() +
                                         " in protobuf JSON: " + std::string(status.message()));
  }
  return message;
}

void set_vec3(v1::Vec3* v, double x, double y, double z) {
  v->set_x(x);
  v->set_y(y);
  v->set_z(z);
}

}  // namespace

v1::Scene read_scene_file(const std::filesystem::path& path) { return parse_json_file<v1::Scene>(path, "scene file"); }

v1::JobSpec read_job_spec_file(const std::filesystem::path& path) {
  return parse_json_file<v1::JobSpec>(path, "job spec file");
}

v1::JobSpec build_job_spec(const JobOptions& options) {
  v1::JobSpec spec;
  if (options.spec) {
    spec = read_job_spec_file(*options.spec);
  } else if (options.isosurface) {
    const IsosurfaceOptions& iso = *options.isosurface;
    v1::IsosurfaceJob* job = spec.mutable_isosurface();
    for (const auto& path : iso.scenes) *job->add_scenes() = read_scene_file(path);
    if (iso.bounds) {
      const auto& b = *iso.bounds;
      set_vec3(job->mutable_bounds()->mutable_min(), b[0], b[1], b[2]);
      set_vec3(job->mutable_bounds()->mutable_max(), b[3], b[4], b[5]);
    }
    if (iso.cell_size) {
      job->set_cell_size(*iso.cell_size);
    } else {
      job->set_cells(iso.cells.value_or(128));
    }
    if (iso.method) {
      if (*iso.method != "cubes") throw CliError(ExitCode::kUsage, "--method must be: cubes");
      job->set_method(v1::POLYGONIZER_CUBES);
    }
    if (!iso.scenes.empty()) {
      std::string name = iso.scenes.front().stem().string();
      if (iso.scenes.size() > 1) name += " (+" + std::to_string(iso.scenes.size() - 1) + " more)";
      spec.set_name(name);
    }
  } else {
    throw CliError(ExitCode::kUsage, "no job given: use a job type (isosurface) or --spec FILE");
  }

  if (options.name) spec.set_name(*options.name);
  v1::OutputOptions* output = spec.mutable_output();
  if (options.raw) output->set_encoding(v1::MESH_ENCODING_PLY);
  if (options.normals) output->set_normals(true);
  if (options.quantization_bits) output->set_quantization_bits(*options.quantization_bits);
  return spec;
}

}  // namespace surfacer::client
