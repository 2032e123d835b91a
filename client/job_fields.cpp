#include "client/job_fields.h"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <limits>
#include <optional>
#include <stdexcept>

#include "client/exit_codes.h"
#include "core/active/active_surface.h"
#include "core/mesh/decimate.h"
#include "core/mesh/mesh_codec.h"
#include "core/optimize/mesh_optimizer.h"
#include "core/particles/particle_surfacer.h"
#include "core/polygonize/polygonize.h"
#include "core/util/format.h"
#include "surfacer/v1/surfacer.pb.h"

namespace surfacer::client {
namespace {

namespace pb = google::protobuf;

CliError usage(const std::string& message) { return CliError(ExitCode::kUsage, message); }

std::string number(double v) { return format_number(v); }
std::string whole(std::int64_t v) { return std::to_string(v); }

// --- The tables: help texts here, defaults read from the engines' options structs ------------------------------------

std::vector<JobField> isosurface_fields() {
  const PolygonizeOptions defaults;
  return {
      {.path = "cells",
       .help = "cells along the longest axis of the bounds",
       .value_name = "N",
       .default_value = [=] { return whole(defaults.cells); }},
      {.path = "cell_size",
       .help = "edge of a cubic cell (cubes) or mean sample spacing (tiles), in scene units (instead of cells)",
       .value_name = "H"},
      {.path = "bounds",
       .help = "region to polygonize: x0,y0,z0,x1,y1,z1 (default: the scenes' own bounds, padded by " +
               number(PolygonizeOptions::kPadCells) + " cells)",
       .value_name = "BOX"},
      {.path = "method",
       .help = "polygonizer: tiles (Marching Tiles, every vertex of valence >= 5) or cubes (Marching Cubes)",
       .value_name = "NAME",
       .default_value = [=] { return std::string(polygonizer_name(defaults.method)); }},
  };
}

std::vector<JobField> output_fields() {
  const DracoOptions draco;
  return {
      {.path = "encoding",
       .help = "frames on the wire: draco (the default: small; one standard Draco mesh, as a .drc file holds), meshopt "
               "(meshoptimizer's codecs: "
               "~10x faster to encode and decode, ~3x larger: for fast networks) or raw (lossless binary PLY, double "
               "precision; also spelled ply); draco_pieces is Draco in pieces encoded and decoded on every core, which "
               "the CLI picks itself when it writes no .drc file, and the Python package for draco",
       .value_name = "CODEC",
       .words = {{"raw", "ply"}}},
      {.path = "normals", .help = "per-vertex normals in every frame"},
      {.path = "quantization_bits",
       .help = "position quantization of Draco and meshopt frames, in bits",
       .value_name = "B",
       .default_value = [=] { return whole(draco.quantization_bits); }},
      {.path = "draco_speed",
       .help = "Draco encoder speed, 0 (smallest frames) to 10 (fastest encode; about 8x larger)",
       .value_name = "S",
       .default_value = [=] { return whole(draco.speed); }},
      {.path = "quantization_bounds",
       .help = "the box every frame's positions are quantized on: x0,y0,z0,x1,y1,z1 (default: the job's bounds); give "
               "the whole sequence's box to make frames surfaced in parts (a Slurm array, Kubernetes pods) identical "
               "to one run's",
       .value_name = "BOX"},
      {.path = "decimate",
       .help = "error-bounded level of detail: fewer triangles, every original vertex within TOL (a length in scene "
               "units) of the result, kept vertices where the engine put them (particle frames stay faithful), no "
               "new angle below " +
               number(DecimateOptions{}.min_angle_degrees) + " degrees",
       .value_name = "TOL",
       .default_value = [] { return std::string("0: off"); }},
  };
}

std::vector<JobField> particles_fields() {
  const ParticleSurfacingOptions defaults;
  return {
      {.path = "r_inner",
       .help = "inner radius: every vertex stays at least this far from every particle (scene units); required "
               "unless derive_r_inner is set or the frames carry per-particle radii (then each particle's own, and "
               "the spacing follows the median radius unless r_inner is given)",
       .value_name = "R"},
      {.path = "derive_r_inner", .help = "derive r_inner from the mean nearest-neighbour spacing"},
      {.path = "r_outer",
       .help = "outer radius: every vertex stays within this distance of some particle (default " +
               number(ParticleSurfacingOptions::kDefaultOuterRatio) +
               " x r_inner; flat on a lattice of spacing d when r_outer^2 >= r_inner^2 + d^2/2)",
       .value_name = "R"},
      {.path = "spacing_factor",
       .help = "sample spacing of the initial tiling / r_inner",
       .value_name = "F",
       .default_value = [=] { return number(defaults.spacing_factor); }},
      {.path = "sweeps",
       .help = "shorthand for laplacian_sweeps,bilaplacian_sweeps,polish_sweeps",
       .value_name = "L,B,P",
       .default_value =
           [=] {
             return whole(defaults.laplacian_sweeps) + "," + whole(defaults.bilaplacian_sweeps) + "," +
                    whole(defaults.polish_sweeps);
           },
       .parts = {"laplacian_sweeps", "bilaplacian_sweeps", "polish_sweeps"}},
      {.path = "laplacian_sweeps",
       .help = "Gauss-Seidel sweeps of the Laplacian smoothing",
       .value_name = "N",
       .default_value = [=] { return whole(defaults.laplacian_sweeps); }},
      {.path = "bilaplacian_sweeps",
       .help = "Gauss-Seidel sweeps of the constrained Bilaplacian smoothing",
       .value_name = "N",
       .default_value = [=] { return whole(defaults.bilaplacian_sweeps); }},
      {.path = "polish_sweeps",
       .help = "sweeps of the final polish",
       .value_name = "N",
       .default_value = [=] { return whole(defaults.polish_sweeps); }},
      {.path = "relaxation",
       .help = "under-relaxation of the Laplacian sweeps",
       .value_name = "W",
       .default_value = [=] { return number(defaults.relaxation); }},
      {.path = "erosion",
       .help = "move vertices inward by EPS x r_inner at the end (default off)",
       .value_name = "EPS"},
      {.path = "unconstrained_polish",
       .help = "keep the thesis' polish: no final projection, so some vertices may end outside [r_inner, r_outer]"},
      {.path = "vertex_only_band",
       .help = "keep the thesis' band at the vertices only: the cusps of the r_outer spheres are not held (fuller "
               "surfaces; faces over particle lattices are not flat)"},
      {.path = "min_angle_degrees",
       .help = "repair triangles with a smaller angle, in degrees (0: no repair)",
       .value_name = "DEG",
       .aliases = {"min-angle"},
       .default_value = [=] { return number(defaults.min_angle_degrees); }},
      {.path = "container.box",
       .help = "keep the surface inside this box: x0,y0,z0,x1,y1,z1 (vertices outside are snapped to it)",
       .value_name = "BOX"},
      {.path = "min_particles_per_component",
       .help = "drop surface components around fewer particles than this (stray spray; 0 keeps all)",
       .value_name = "N",
       .aliases = {"min-particles"},
       .default_value = [=] { return whole(defaults.min_particles_per_component); }},
      {.path = "interpolate",
       .help = "particle attributes to carry onto the surface's vertices, by name (velocity,density), or all: "
               "interpolated from the particles within r_outer and written under the same names",
       .value_name = "NAMES"},
  };
}

std::vector<JobField> optimize_fields() {
  const MeshOptimizerOptions defaults;
  const PolygonizeOptions start = default_start_polygonize();
  return {
      {.path = "polygonize.cells",
       .help = "or polygonize the scene on the server: cells along the longest axis",
       .value_name = "N",
       .aliases = {"start-cells"},
       .default_value = [=] { return whole(start.cells); }},
      {.path = "polygonize.cell_size",
       .help = "or the start polygonization's cell size (instead of cells)",
       .value_name = "H",
       .aliases = {"start-cell-size"}},
      {.path = "polygonize.method",
       .help = "polygonizer of the start mesh: cubes or tiles",
       .value_name = "NAME",
       .aliases = {"start-method"},
       .default_value = [=] { return std::string(polygonizer_name(start.method)); }},
      {.path = "polygonize.bounds",
       .help = "region of the start polygonization: x0,y0,z0,x1,y1,z1 (default: the scene's bounds, padded)",
       .value_name = "BOX",
       .aliases = {"start-bounds"}},
      {.path = "max_iterations",
       .help = "stop after N iterations",
       .value_name = "N",
       .aliases = {"iterations"},
       .default_value = [=] { return whole(defaults.max_iterations); }},
      {.path = "tolerance", .help = "stop when E_d and E_n change by less than T (relative)", .value_name = "T"},
      {.path = "snapshot_every",
       .help = "stream a snapshot frame every K iterations (default: only the result)",
       .value_name = "K"},
      {.path = "flows",
       .help = "flows to run, comma-separated: d (distance), n (normal), t (tangential); sets d_flow, n_flow, "
               "t_flow (default d,n,t)",
       .value_name = "LIST",
       .parts = {"d_flow", "n_flow", "t_flow"},
       .member_set = true},
      {.path = "c_d",
       .help = "D-flow coefficient",
       .value_name = "X",
       .default_value = [=] { return number(defaults.c_d); }},
      {.path = "c_n",
       .help = "N-flow coefficient",
       .value_name = "X",
       .default_value = [=] { return number(defaults.c_n); }},
      {.path = "c_t",
       .help = "T-flow coefficient",
       .value_name = "X",
       .default_value = [=] { return number(defaults.c_t); }},
      {.path = "step_bound",
       .help = "D-flow step bound c in |C_D F_D| <= c sqrt(A(P))",
       .value_name = "C",
       .default_value = [=] { return number(defaults.step_bound); }},
      {.path = "modified_flows", .help = "local-energy gradient descent (paper section 3.1)"},
      {.path = "t_flow_iterations",
       .help = "run the T-flow for exactly N iterations (default: off once E_d stabilises)",
       .value_name = "N"},
      {.path = "subdivision_threshold",
       .help = "adaptive 1-to-4 subdivision where delta(T) exceeds THRESHOLD",
       .value_name = "THRESHOLD",
       .aliases = {"subdivide"}},
      {.path = "triangle_budget", .help = "stop subdividing at N triangles", .value_name = "N"},
  };
}

std::vector<JobField> active_fields() {
  return {
      {.path = "grid_spacing",
       .help = "spacing h of the potential's grid, in scene units (required)",
       .value_name = "H"},
      {.path = "bounds",
       .help = "domain hint x0,y0,z0,x1,y1,z1 (the grid is sparse and unbounded)",
       .value_name = "BOX"},
      {.path = "alpha",
       .help = "tracking strength, coat and morph only (default " + number(ActiveSurfaceOptions::kTrackingAlpha) +
               "; advect has no target to track)",
       .value_name = "X"},
      {.path = "beta",
       .help = "surface tension (advect: on top of the velocity, as gamma and delta)",
       .value_name = "X"},
      {.path = "gamma", .help = "area preservation", .value_name = "X"},
      {.path = "delta",
       .help = "volume preservation (advect: holds the volume the scheme would lose)",
       .value_name = "X"},
      {.path = "cfl",
       .help = "CFL number of the sub-steps",
       .value_name = "C",
       .default_value = [] { return number(*ActiveSurfaceOptions{}.cfl); }},
      {.path = "polygonizer",
       .help = "polygonizer of the frames: tiles or cubes",
       .value_name = "NAME",
       .default_value = [] { return std::string(polygonizer_name(ActiveSurfaceOptions{}.polygonizer)); }},
  };
}

std::vector<JobField> coat_fields() {
  return {
      {.path = "kernel_radius", .help = "R of the Wyvill kernel (1 - r^2/R^2)^3 (required)", .value_name = "R"},
      {.path = "iso",
       .help = "iso value T of the summed kernel field",
       .value_name = "T",
       .default_value = [] { return number(ParticleTargetOptions{}.iso); }},
      {.path = "substeps_per_frame",
       .help = "evolve each frame in exactly N sub-steps instead of CFL-sized ones (excludes cfl)",
       .value_name = "N",
       .aliases = {"substeps"}},
  };
}

std::vector<JobField> morph_fields() {
  const MorphOptions defaults;
  return {
      {.path = "tolerance",
       .help = "stop when max |df/dt| falls below X",
       .value_name = "X",
       .default_value = [=] { return number(defaults.tolerance); }},
      {.path = "max_frames",
       .help = "stop after N frames",
       .value_name = "N",
       .default_value = [=] { return whole(defaults.max_frames); }},
      {.path = "frame_time",
       .help = "simulated time between output frames",
       .value_name = "DT",
       .default_value = [=] { return number(defaults.frame_duration); }},
  };
}

std::vector<JobField> advect_fields() {
  return {
      {.path = "frame_interval", .help = "simulated time between frames (required)", .value_name = "DT"},
      {.path = "frames", .help = "number of frames (required)", .value_name = "N"},
      {.path = "error_compensation",
       .help = "back-and-forth error compensation of every sub-step (BFECC): less numerical loss, ~3x the work"},
      {.path = "enright.period",
       .help = "Enright period T (selects the Enright field)",
       .value_name = "T",
       .aliases = {"period"},
       .default_value = [] { return number(kEnrightPeriod); }},
      {.path = "grid.origin",
       .name = "velocity_origin",
       .help = "position of the velocity grid's first node",
       .value_name = "x,y,z"},
      {.path = "grid.spacing",
       .name = "velocity_spacing",
       .help = "the velocity grid's node spacing per axis",
       .value_name = "dx,dy,dz"},
      {.path = "velocity_dims",
       .help = "the velocity grid's nodes per axis (sets grid.nx, grid.ny, grid.nz)",
       .value_name = "nx,ny,nz",
       .parts = {"grid.nx", "grid.ny", "grid.nz"}},
  };
}

// --- Values from text
// -------------------------------------------------------------------------------------------------

std::vector<std::string> split(const std::string& text) {
  std::vector<std::string> items;
  std::size_t pos = 0;
  while (true) {
    const std::size_t comma = text.find(',', pos);
    items.push_back(text.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos));
    if (comma == std::string::npos) return items;
    pos = comma + 1;
  }
}

std::optional<double> parse_double(const std::string& text) {
  double value = 0;
  const char* end = text.data() + text.size();
  auto [ptr, ec] = std::from_chars(text.data(), end, value);
  if (text.empty() || ec != std::errc() || ptr != end || !std::isfinite(value)) return std::nullopt;
  return value;
}

std::optional<std::int64_t> parse_int(const std::string& text) {
  std::int64_t value = 0;
  const char* end = text.data() + text.size();
  auto [ptr, ec] = std::from_chars(text.data(), end, value);
  if (text.empty() || ec != std::errc() || ptr != end) return std::nullopt;
  return value;
}

// Numbers of a Bounds (6) or Vec3 (3) from "a,b,c".
std::vector<double> numbers(const std::string& text, std::size_t count, const std::string& name,
                            const std::string& example) {
  const std::vector<std::string> items = split(text);
  std::vector<double> values;
  for (const std::string& item : items) {
    const std::optional<double> v = parse_double(item);
    if (!v || items.size() != count) {
      throw usage(name + " \"" + text + "\" must be " + std::to_string(count) + " comma-separated numbers, e.g. " +
                  name + "=" + example);
    }
    values.push_back(*v);
  }
  return values;
}

// The enum's value names as the front ends spell them: POLYGONIZER_TILES of enum Polygonizer is "tiles".
std::string short_enum_name(const pb::EnumValueDescriptor& value) {
  std::string prefix;
  for (char c : value.type()->name()) {
    if (std::isupper(static_cast<unsigned char>(c)) && !prefix.empty()) prefix += '_';
    prefix += static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  }
  prefix += '_';
  std::string name = value.name().starts_with(prefix) ? value.name().substr(prefix.size()) : value.name();
  std::transform(name.begin(), name.end(), name.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return name;
}

void set_vec3(pb::Message& vec, const std::vector<double>& v, std::size_t at) {
  const pb::Reflection* r = vec.GetReflection();
  const pb::Descriptor* d = vec.GetDescriptor();
  r->SetDouble(&vec, d->FindFieldByName("x"), v[at]);
  r->SetDouble(&vec, d->FindFieldByName("y"), v[at + 1]);
  r->SetDouble(&vec, d->FindFieldByName("z"), v[at + 2]);
}

// Sets the scalar or Bounds/Vec3 field `fd` of `message` from `text`; an enum also takes `words` (JobField::words).
void set_value(pb::Message& message, const pb::FieldDescriptor* fd, const std::string& text, const std::string& name,
               const std::vector<std::pair<std::string, std::string>>& words) {
  const pb::Reflection* r = message.GetReflection();
  if (fd->is_repeated()) {
    if (fd->cpp_type() != pb::FieldDescriptor::CPPTYPE_STRING) {
      throw usage(name + ": the field " + fd->full_name() + " cannot be set from the command line");
    }
    r->ClearField(&message, fd);
    for (const std::string& item : split(text)) {
      if (item.empty()) throw usage(name + " \"" + text + "\" has an empty name");
      r->AddString(&message, fd, item);
    }
    return;
  }
  switch (fd->cpp_type()) {
    case pb::FieldDescriptor::CPPTYPE_DOUBLE:
    case pb::FieldDescriptor::CPPTYPE_FLOAT: {
      const std::optional<double> v = parse_double(text);
      if (!v) throw usage(name + " \"" + text + "\" is not a number");
      if (fd->cpp_type() == pb::FieldDescriptor::CPPTYPE_DOUBLE) {
        r->SetDouble(&message, fd, *v);
      } else {
        r->SetFloat(&message, fd, static_cast<float>(*v));
      }
      return;
    }
    case pb::FieldDescriptor::CPPTYPE_INT32:
    case pb::FieldDescriptor::CPPTYPE_INT64: {
      const std::optional<std::int64_t> v = parse_int(text);
      if (!v) throw usage(name + " \"" + text + "\" is not a whole number");
      if (fd->cpp_type() == pb::FieldDescriptor::CPPTYPE_INT64) {
        r->SetInt64(&message, fd, *v);
        return;
      }
      if (*v < std::numeric_limits<std::int32_t>::min() || *v > std::numeric_limits<std::int32_t>::max()) {
        throw usage(name + " \"" + text + "\" is beyond the range of a 32-bit whole number");
      }
      r->SetInt32(&message, fd, static_cast<std::int32_t>(*v));
      return;
    }
    case pb::FieldDescriptor::CPPTYPE_BOOL:
      if (text != "true" && text != "false") throw usage(name + " \"" + text + "\" is not true or false");
      r->SetBool(&message, fd, text == "true");
      return;
    case pb::FieldDescriptor::CPPTYPE_ENUM: {
      std::string known, wanted = text;
      for (const auto& [word, short_name] : words) {
        if (word == text) wanted = short_name;
        known += (known.empty() ? "" : " or ") + word;
      }
      for (int i = 0; i < fd->enum_type()->value_count(); ++i) {
        const pb::EnumValueDescriptor* value = fd->enum_type()->value(i);
        if (value->number() == 0) continue;  // UNSPECIFIED: the default, by leaving the field unset
        const std::string short_name = short_enum_name(*value);
        if (short_name == wanted) {
          r->SetEnumValue(&message, fd, value->number());
          return;
        }
        known += (known.empty() ? "" : " or ") + short_name;
      }
      throw usage(name + " must be " + known + ", not " + text);
    }
    case pb::FieldDescriptor::CPPTYPE_MESSAGE: {
      pb::Message* value = r->MutableMessage(&message, fd);
      const std::string type = fd->message_type()->name();
      if (type == "Bounds") {
        const auto v = numbers(text, 6, name, "-1,-1,-1,1,1,1 (x0,y0,z0,x1,y1,z1)");
        set_vec3(*value->GetReflection()->MutableMessage(value, value->GetDescriptor()->FindFieldByName("min")), v, 0);
        set_vec3(*value->GetReflection()->MutableMessage(value, value->GetDescriptor()->FindFieldByName("max")), v, 3);
        return;
      }
      if (type == "Vec3") {
        set_vec3(*value, numbers(text, 3, name, "0,0,0 (x,y,z)"), 0);
        return;
      }
      break;
    }
    default:
      break;
  }
  throw usage(name + ": the field " + fd->full_name() + " cannot be set from the command line");
}

// Refuses setting `fd` of `message` when another member of its oneof was set by the user (in `names`, below
// `prefix`, the request path of `message`).
void check_oneof(const pb::Message& message, const pb::FieldDescriptor* fd, const std::string& prefix,
                 const std::string& name, const std::map<std::string, std::string>& names) {
  const pb::OneofDescriptor* oneof = fd->containing_oneof();
  if (oneof == nullptr) return;
  const pb::FieldDescriptor* set = message.GetReflection()->GetOneofFieldDescriptor(message, oneof);
  if (set == nullptr || set == fd) return;
  const std::string other = prefix + "." + set->name();
  for (const auto& [path, other_name] : names) {
    if (path == other || path.starts_with(other + ".")) {
      if (other_name == name) return;
      throw usage(name + " and " + other_name + " both set the " + oneof->name() + " of " +
                  message.GetDescriptor()->name() + ": give one");
    }
  }
}

void set_path(v1::JobSpec& spec, JobTable table, const std::string& path, const std::string& text,
              const std::string& name, std::map<std::string, std::string>& names,
              const std::vector<std::pair<std::string, std::string>>& words = {}) {
  pb::Message& root = table_message(spec, table);
  const std::string base = table_path(table);
  // Each message on the way may be a oneof member (optimize's polygonize, advect's grid): check before creating.
  pb::Message* message = &root;
  std::string prefix = base;
  std::size_t pos = 0;
  while (true) {
    const std::size_t dot = path.find('.', pos);
    const std::string component = path.substr(pos, dot == std::string::npos ? std::string::npos : dot - pos);
    const pb::FieldDescriptor* fd = message->GetDescriptor()->FindFieldByName(component);
    if (fd == nullptr) throw std::logic_error("job field table: no field " + path + " in " + root.GetTypeName());
    check_oneof(*message, fd, prefix, name, names);
    if (dot == std::string::npos) {
      set_value(*message, fd, text, name, words);
      break;
    }
    message = message->GetReflection()->MutableMessage(message, fd);
    prefix += "." + component;
    pos = dot + 1;
  }
  names[base + "." + path] = name;
}

}  // namespace

const std::vector<JobField>& job_fields(JobTable table) {
  static const std::vector<JobField> isosurface = isosurface_fields();
  static const std::vector<JobField> particles = particles_fields();
  static const std::vector<JobField> optimize = optimize_fields();
  static const std::vector<JobField> active = active_fields();
  static const std::vector<JobField> coat = coat_fields();
  static const std::vector<JobField> morph = morph_fields();
  static const std::vector<JobField> advect = advect_fields();
  static const std::vector<JobField> output = output_fields();
  switch (table) {
    case JobTable::kIsosurface:
      return isosurface;
    case JobTable::kParticles:
      return particles;
    case JobTable::kOptimize:
      return optimize;
    case JobTable::kActive:
      return active;
    case JobTable::kCoat:
      return coat;
    case JobTable::kMorph:
      return morph;
    case JobTable::kAdvect:
      return advect;
    case JobTable::kOutput:
      return output;
  }
  return isosurface;
}

const JobField& job_field(JobTable table, const std::string& path) {
  const std::vector<JobField>& fields = job_fields(table);
  const auto it = std::find_if(fields.begin(), fields.end(), [&](const JobField& f) { return f.path == path; });
  if (it == fields.end()) throw std::logic_error("job field table: no field " + path + " in " + table_path(table));
  return *it;
}

std::string spelling(const JobField& field) { return field.name.empty() ? field.path : field.name; }

std::string table_path(JobTable table) {
  switch (table) {
    case JobTable::kIsosurface:
      return "spec.isosurface";
    case JobTable::kParticles:
      return "spec.particles";
    case JobTable::kOptimize:
      return "spec.optimize";
    case JobTable::kActive:
      return "spec.active";
    case JobTable::kCoat:
      return "spec.active.coat";
    case JobTable::kMorph:
      return "spec.active.morph";
    case JobTable::kAdvect:
      return "spec.active.advect";
    case JobTable::kOutput:
      return "spec.output";
  }
  return "spec";
}

google::protobuf::Message& table_message(v1::JobSpec& spec, JobTable table) {
  switch (table) {
    case JobTable::kIsosurface:
      return *spec.mutable_isosurface();
    case JobTable::kParticles:
      return *spec.mutable_particles();
    case JobTable::kOptimize:
      return *spec.mutable_optimize();
    case JobTable::kActive:
      return *spec.mutable_active();
    case JobTable::kCoat:
      return *spec.mutable_active()->mutable_coat();
    case JobTable::kMorph:
      return *spec.mutable_active()->mutable_morph();
    case JobTable::kAdvect:
      return *spec.mutable_active()->mutable_advect();
    case JobTable::kOutput:
      return *spec.mutable_output();
  }
  return spec;
}

namespace {

// The descriptor of the field at `path` below `table`'s message; null when there is none (a shorthand's own name).
const pb::FieldDescriptor* field_descriptor(JobTable table, const std::string& path) {
  v1::JobSpec spec;
  const pb::Message* message = &table_message(spec, table);
  const pb::FieldDescriptor* fd = nullptr;
  for (std::size_t pos = 0;;) {
    const std::size_t dot = path.find('.', pos);
    fd = message->GetDescriptor()->FindFieldByName(path.substr(pos, dot == std::string::npos ? dot : dot - pos));
    if (fd == nullptr || dot == std::string::npos) break;
    message = &message->GetReflection()->GetMessage(*message, fd);
    pos = dot + 1;
  }
  return fd;
}

// The Python annotation of one proto field's keyword value.
std::string python_field_type(const pb::FieldDescriptor& fd,
                              const std::vector<std::pair<std::string, std::string>>& words = {}) {
  switch (fd.cpp_type()) {
    case pb::FieldDescriptor::CPPTYPE_DOUBLE:
    case pb::FieldDescriptor::CPPTYPE_FLOAT:
      return "float";
    case pb::FieldDescriptor::CPPTYPE_INT32:
    case pb::FieldDescriptor::CPPTYPE_INT64:
    case pb::FieldDescriptor::CPPTYPE_UINT32:
    case pb::FieldDescriptor::CPPTYPE_UINT64:
      return "int";
    case pb::FieldDescriptor::CPPTYPE_BOOL:
      return "bool";
    case pb::FieldDescriptor::CPPTYPE_ENUM: {
      std::string names;
      const pb::EnumDescriptor* e = fd.enum_type();
      for (int i = 0; i < e->value_count(); ++i) {
        if (e->value(i)->number() == 0) continue;  // UNSPECIFIED: the default, not a value a user gives
        names += (names.empty() ? "" : ", ") + ("\"" + short_enum_name(*e->value(i)) + "\"");
      }
      for (const auto& word : words) names += ", \"" + word.first + "\"";
      return "Literal[" + names + "]";
    }
    case pb::FieldDescriptor::CPPTYPE_MESSAGE:  // Bounds and Vec3: x0,y0,z0,x1,y1,z1 and x,y,z
      return "Sequence[float]";
    default:
      return "str";
  }
}

}  // namespace

bool takes_words(JobTable table, const JobField& field) {
  if (field.member_set) return true;
  if (!field.parts.empty()) return false;
  const pb::FieldDescriptor* fd = field_descriptor(table, field.path);
  return fd != nullptr &&
         (fd->cpp_type() == pb::FieldDescriptor::CPPTYPE_ENUM || fd->cpp_type() == pb::FieldDescriptor::CPPTYPE_STRING);
}

std::string python_type(JobTable table, const JobField& field) {
  if (field.member_set) return "Union[str, Sequence[str]]";
  if (!field.parts.empty()) {
    const pb::FieldDescriptor* part = field_descriptor(table, field.parts.front());
    return "Sequence[" + (part ? python_field_type(*part) : std::string("float")) + "]";
  }
  const pb::FieldDescriptor* fd = field_descriptor(table, field.path);
  if (fd == nullptr) throw std::logic_error("job field table: no field " + field.path);
  const std::string type = python_field_type(*fd, field.words);
  return fd->is_repeated() ? "Union[" + type + ", Sequence[" + type + "]]" : type;
}

std::string cli_flag(const std::string& spelling) {
  std::string flag = "--" + spelling;
  std::replace(flag.begin(), flag.end(), '_', '-');
  std::replace(flag.begin(), flag.end(), '.', '-');
  return flag;
}

std::string keyword(const std::string& spelling) {
  std::string word = spelling;
  std::replace(word.begin(), word.end(), '-', '_');
  std::replace(word.begin(), word.end(), '.', '_');
  return word;
}

void set_job_field(v1::JobSpec& spec, JobTable table, const JobField& field, const std::string& text,
                   const std::string& name, std::map<std::string, std::string>& names) {
  if (field.parts.empty()) {
    set_path(spec, table, field.path, text, name, names, field.words);
    return;
  }
  const std::vector<std::string> items = split(text);
  if (field.member_set) {
    std::vector<bool> on(field.parts.size(), false);
    std::string known;
    for (const std::string& part : field.parts) known += (known.empty() ? "" : ", ") + part.substr(0, 1);
    for (const std::string& item : items) {
      const auto it = std::find_if(field.parts.begin(), field.parts.end(),
                                   [&](const std::string& part) { return item.size() == 1 && part[0] == item[0]; });
      if (it == field.parts.end()) {
        throw usage(name + " \"" + text + "\": \"" + item + "\" is not one of " + known);
      }
      on[static_cast<std::size_t>(it - field.parts.begin())] = true;
    }
    for (std::size_t i = 0; i < field.parts.size(); ++i) {
      set_path(spec, table, field.parts[i], on[i] ? "true" : "false", name, names);
    }
    return;
  }
  if (items.size() != field.parts.size()) {
    throw usage(name + " \"" + text + "\" has " + std::to_string(items.size()) + " values; it needs " +
                std::to_string(field.parts.size()) + " (" + field.value_name + ")");
  }
  for (std::size_t i = 0; i < items.size(); ++i) set_path(spec, table, field.parts[i], items[i], name, names);
}

std::string name_of_field(const std::map<std::string, std::string>& names, const std::string& request_path,
                          bool python) {
  // The path and its enclosing fields, nearest first: "a.b[2].c" -> "a.b[2].c", "a.b[2]", "a.b", "a".
  for (std::string path = request_path; !path.empty();) {
    const auto it = names.find(path);
    if (it != names.end()) return it->second;
    const std::size_t cut = path.find_last_of(".[");
    if (cut == std::string::npos) break;
    path.resize(cut);
  }
  for (JobTable table : {JobTable::kCoat, JobTable::kMorph, JobTable::kAdvect, JobTable::kIsosurface,
                         JobTable::kParticles, JobTable::kOptimize, JobTable::kActive, JobTable::kOutput}) {
    const std::string base = table_path(table) + ".";
    if (!request_path.starts_with(base)) continue;
    // Fields first, then the shorthands that set them.
    for (const bool shorthand : {false, true}) {
      for (const JobField& field : job_fields(table)) {
        if (field.parts.empty() == shorthand) continue;
        const std::vector<std::string> paths = shorthand ? field.parts : std::vector<std::string>{field.path};
        for (const std::string& path : paths) {
          const std::string full = base + path;
          if (request_path == full || request_path.starts_with(full + ".")) {
            return python ? keyword(spelling(field)) : cli_flag(spelling(field));
          }
        }
      }
    }
  }
  return "";
}

std::string names_below(const std::map<std::string, std::string>& names, const std::string& request_path) {
  std::string given;
  for (const auto& [path, name] : names) {
    const bool below = path == request_path || path.starts_with(request_path + ".");
    if (below && (", " + given + ", ").find(", " + name + ", ") == std::string::npos) {
      given += (given.empty() ? "" : ", ") + name;
    }
  }
  return given;
}

}  // namespace surfacer::client
