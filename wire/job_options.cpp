#include "wire/job_options.h"

#include "core/util/checks.h"
#include "core/util/errors.h"
#include "wire/enums.h"
#include "wire/output.h"
#include "wire/scene.h"

namespace surfacer::wire {

Polygonizer to_polygonizer(int value, Polygonizer unspecified, const std::string& field) {
  require_known_enum(v1::Polygonizer_descriptor(), value, field);
  switch (value) {
    case v1::POLYGONIZER_TILES:
      return Polygonizer::kTiles;
    case v1::POLYGONIZER_CUBES:
      return Polygonizer::kCubes;
    default:
      return unspecified;
  }
}

v1::Polygonizer to_wire(Polygonizer polygonizer) {
  return polygonizer == Polygonizer::kCubes ? v1::POLYGONIZER_CUBES : v1::POLYGONIZER_TILES;
}

namespace {

// Bounds, resolution and method of a polygonization request (IsosurfaceJob and Polygonize share the fields).
template <class Request>
PolygonizeOptions polygonize_request(const Request& request, PolygonizeOptions options, const std::string& path) {
  options.method = to_polygonizer(request.method(), options.method, path + ".method");
  if (request.has_bounds()) options.bounds = to_aabb(request.bounds(), path + ".bounds");
  if (request.resolution_case() == Request::kCells) options.cells = request.cells();
  if (request.resolution_case() == Request::kCellSize) options.cell_size = request.cell_size();
  with_path(path, [&] { validate(options); });
  return options;
}

}  // namespace

PolygonizeOptions isosurface_options(const v1::IsosurfaceJob& job, bool normals, const std::string& path) {
  PolygonizeOptions options;
  options.normals = normals;
  return polygonize_request(job, options, path);
}

std::vector<FieldPtr> isosurface_fields(const v1::IsosurfaceJob& job, const UploadLookup& uploads,
                                        const std::string& path) {
  std::vector<FieldPtr> fields;
  fields.reserve(job.scenes_size());
  for (int i = 0; i < job.scenes_size(); ++i) {
    std::string unbounded;
    fields.push_back(field_from_scene(job.scenes(i), path + ".scenes[" + std::to_string(i) + "]", uploads, &unbounded));
    if (!job.has_bounds() && !unbounded.empty()) {
      throw InvalidInput(path + ".bounds", path + ".bounds are needed: " + unbounded);
    }
  }
  return fields;
}

PolygonizeOptions start_polygonize_options(const v1::Polygonize& start, const std::string& path) {
  return polygonize_request(start, default_start_polygonize(), path);
}

ParticleSurfacingOptions particle_options(const v1::ParticlesJob& job, bool normals, const std::string& path) {
  ParticleSurfacingOptions options;
  if (job.has_r_inner()) options.r_inner = job.r_inner();
  options.derive_r_inner = job.derive_r_inner();
  if (job.has_r_outer()) options.r_outer = job.r_outer();
  if (job.has_spacing_factor()) options.spacing_factor = job.spacing_factor();
  if (job.has_laplacian_sweeps()) options.laplacian_sweeps = job.laplacian_sweeps();
  if (job.has_bilaplacian_sweeps()) options.bilaplacian_sweeps = job.bilaplacian_sweeps();
  if (job.has_polish_sweeps()) options.polish_sweeps = job.polish_sweeps();
  if (job.has_relaxation()) options.relaxation = job.relaxation();
  if (job.has_erosion()) options.erosion = job.erosion();
  if (job.has_unconstrained_polish()) options.unconstrained_polish = job.unconstrained_polish();
  if (job.has_vertex_only_band()) options.vertex_only_band = job.vertex_only_band();
  if (job.has_min_angle_degrees()) options.min_angle_degrees = job.min_angle_degrees();
  if (job.container().has_box()) options.container_box = to_aabb(job.container().box(), path + ".container.box");
  options.min_particles_per_component = job.min_particles_per_component();
  options.normals = normals;
  with_path(path, [&] { validate(options); });
  return options;
}

FieldPtr container_solid(const v1::ParticlesJob& job, const UploadLookup& uploads, const std::string& path) {
  if (!job.container().has_solid()) return nullptr;
  return field_from_scene(job.container().solid(), path + ".container.solid", uploads);
}

void require_r_inner_frame(const v1::ParticlesJob& job, std::size_t index, bool frame_has_radii) {
  try {
    require_r_inner_source(frame_has_radii, job.has_r_inner(), job.derive_r_inner());
  } catch (const Error& e) {
    const Error placed = at_path(e, "spec.particles");
    throw Error(placed.kind(), placed.field(),
                std::string(placed.what()) + " (frame " + std::to_string(index) + " has none)");
  }
}

Aabb particles_job_box(const v1::ParticlesJob& job, std::span<const ParticleSummary> frames,
                       const std::function<std::vector<Vec3>()>& first_frame) {
  const std::string path = "spec.particles";
  Aabb box;
  double max_radius = 0.0;
  for (std::size_t i = 0; i < frames.size(); ++i) {
    box = i == 0 ? frames[i].bounds : merged(box, frames[i].bounds);
    max_radius = std::max(max_radius, frames[i].max_radius);
    require_r_inner_frame(job, i, frames[i].max_radius > 0.0);
  }
  const std::optional<double> r_inner = job.has_r_inner() ? std::optional<double>(job.r_inner()) : std::nullopt;
  const std::optional<double> r_outer = job.has_r_outer() ? std::optional<double>(job.r_outer()) : std::nullopt;
  std::optional<Aabb> container;
  if (job.container().has_box()) container = to_aabb(job.container().box(), path + ".container.box");
  try {
    return particle_sequence_box(box, max_radius, r_inner, r_outer, first_frame, container);
  } catch (const Error& e) {
    // Deriving r_inner for the box reads frame 0: what it refuses there is that frame's.
    if (e.kind() == ErrorKind::kInvalidInput && e.field() == "r_inner") throw at_path(e, path + ".frames[0]");
    throw;
  }
}

MeshOptimizerOptions optimizer_options(const v1::OptimizeJob& job, bool normals, const std::string& path) {
  MeshOptimizerOptions options;
  if (job.has_d_flow()) options.d_flow = job.d_flow();
  if (job.has_n_flow()) options.n_flow = job.n_flow();
  if (job.has_t_flow()) options.t_flow = job.t_flow();
  if (job.has_c_d()) options.c_d = job.c_d();
  if (job.has_c_n()) options.c_n = job.c_n();
  if (job.has_c_t()) options.c_t = job.c_t();
  if (job.has_step_bound()) options.step_bound = job.step_bound();
  options.modified_flows = job.modified_flows();
  if (job.has_t_flow_iterations()) options.t_flow_iterations = job.t_flow_iterations();
  if (job.has_max_iterations()) options.max_iterations = job.max_iterations();
  if (job.has_tolerance()) options.tolerance = job.tolerance();
  if (job.has_subdivision_threshold()) options.subdivision_threshold = job.subdivision_threshold();
  if (job.has_triangle_budget()) options.triangle_budget = job.triangle_budget();
  if (job.has_snapshot_every()) options.snapshot_every = job.snapshot_every();
  options.normals = normals;
  with_path(path, [&] { validate(options); });
  return options;
}

ActiveSurfaceOptions active_options(const v1::ActiveJob& job, bool normals, const std::string& path) {
  ActiveSurfaceOptions options;
  // The request calls the engine's h grid_spacing, and has no default for it.
  with_path(path, [&] { require_length("grid_spacing", job.grid_spacing(), "the potential's grid spacing h"); });
  options.h = job.grid_spacing();
  if (job.has_bounds()) options.domain = to_aabb(job.bounds(), path + ".bounds");
  const bool tracking = job.mode_case() == v1::ActiveJob::kCoat || job.mode_case() == v1::ActiveJob::kMorph;
  if (job.has_alpha()) {
    options.alpha = job.alpha();
  } else if (tracking) {
    options.alpha = ActiveSurfaceOptions::kTrackingAlpha;
  }
  if (job.has_beta()) options.beta = job.beta();
  if (job.has_gamma()) options.gamma = job.gamma();
  if (job.has_delta()) options.delta = job.delta();
  if (job.has_cfl()) options.cfl = job.cfl();
  if (job.has_advect()) options.error_compensation = job.advect().error_compensation();
  if (job.coat().has_substeps_per_frame()) {
    // A fixed number of sub-steps per frame instead of the CFL-sized ones (each still no longer than the stability
    // bound allows).
    if (job.has_cfl()) {
      throw InvalidInput(path + ".cfl", path + ".cfl and " + path +
                                            ".coat.substeps_per_frame are both set; give one (cfl sizes each sub-step, "
                                            "substeps_per_frame fixes their number)");
    }
    options.cfl.reset();
    options.substeps_per_frame = job.coat().substeps_per_frame();
    with_path(path + ".coat", [&] { require_count("substeps_per_frame", options.substeps_per_frame, 1, 100000); });
  }
  options.polygonizer = to_polygonizer(job.polygonizer(), options.polygonizer, path + ".polygonizer");
  options.normals = normals;
  try {
    validate(options);
    if (job.mode_case() == v1::ActiveJob::kAdvect) validate_advect(options);
  } catch (const Error& e) {
    // The engine's domain is the request's bounds, at its grid spacing.
    if (e.field() == "domain") {
      throw Error(e.kind(), path + ".bounds",
                  path + ".bounds at grid_spacing " + format_number(options.h) + ": " + e.what());
    }
    if (e.kind() == ErrorKind::kInvalidInput) throw at_path(e, path);
    throw;
  }
  return options;
}

namespace {

// Runs validate() of a mode's options; an InvalidInput it throws is placed at `path`.mode with the request's name
// for the field (`renames`: engine name -> request name), or at `path` itself for the job-wide alpha.
template <class F>
void validate_mode(const std::string& path, const std::string& mode,
                   std::initializer_list<std::pair<std::string_view, std::string_view>> renames, F&& validate_options) {
  try {
    validate_options();
  } catch (const Error& e) {
    if (e.kind() != ErrorKind::kInvalidInput) throw;
    if (e.field() == "alpha") throw at_path(e, path);
    for (const auto& [engine, request] : renames) {
      if (e.field() != engine) continue;
      std::string message = e.what();
      if (message.starts_with(engine)) message = std::string(request) + message.substr(engine.size());
      throw at_path(Error(e.kind(), std::string(request), message), path + "." + mode);
    }
    throw at_path(e, path + "." + mode);
  }
}

}  // namespace

CoatOptions coat_options(const v1::ActiveCoat& coat, const ActiveSurfaceOptions& options, const std::string& path) {
  CoatOptions out;
  out.kernel.radius = coat.kernel_radius();
  if (coat.has_iso()) out.kernel.iso = coat.iso();
  validate_mode(path, "coat", {{"kernel.radius", "kernel_radius"}, {"kernel.iso", "iso"}},
                [&] { validate(out, options); });
  return out;
}

MorphOptions morph_options(const v1::ActiveMorph& morph, const ActiveSurfaceOptions& options, const std::string& path) {
  MorphOptions out;
  if (morph.has_tolerance()) out.tolerance = morph.tolerance();
  if (morph.has_max_frames()) out.max_frames = morph.max_frames();
  if (morph.has_frame_time()) out.frame_duration = morph.frame_time();
  validate_mode(path, "morph", {{"frame_duration", "frame_time"}}, [&] { validate(out, options); });
  return out;
}

AdvectOptions advect_options(const v1::ActiveAdvect& advect, const std::string& path) {
  AdvectOptions out;
  out.frame_interval = advect.frame_interval();
  out.frames = advect.frames();
  validate_mode(path, "advect", {}, [&] { validate(out); });
  return out;
}

VelocityGrid velocity_grid_geometry(const v1::VelocityGrid& grid, const std::string& path) {
  VelocityGrid out;
  out.origin = to_vec3(grid.origin());
  out.spacing = to_vec3(grid.spacing());
  out.nx = grid.nx();
  out.ny = grid.ny();
  out.nz = grid.nz();
  with_path(path, [&] { out.validate_geometry(); });
  return out;
}

void check_job_options(const v1::JobSpec& spec) {
  const bool normals = spec.output().normals();
  switch (spec.kind_case()) {
    case v1::JobSpec::kIsosurface:
      isosurface_options(spec.isosurface(), normals, "spec.isosurface");
      break;
    case v1::JobSpec::kParticles:
      particle_options(spec.particles(), normals, "spec.particles");
      break;
    case v1::JobSpec::kOptimize:
      optimizer_options(spec.optimize(), normals, "spec.optimize");
      if (spec.optimize().has_polygonize()) {
        start_polygonize_options(spec.optimize().polygonize(), "spec.optimize.polygonize");
      }
      break;
    case v1::JobSpec::kActive: {
      const v1::ActiveJob& job = spec.active();
      const ActiveSurfaceOptions options = active_options(job, normals, "spec.active");
      if (job.has_coat()) coat_options(job.coat(), options, "spec.active");
      if (job.has_morph()) morph_options(job.morph(), options, "spec.active");
      if (job.has_advect()) {
        advect_options(job.advect(), "spec.active");
        if (job.advect().has_grid()) velocity_grid_geometry(job.advect().grid(), "spec.active.advect.grid");
      }
      break;
    }
    case v1::JobSpec::KIND_NOT_SET:
      break;
  }
  // The output's codec, bits and box; the job's own box is the runners' (any valid box serves the check).
  frame_encoding(spec.output(), Aabb{Vec3::Zero(), Vec3::Ones()}, "spec.output");
}

}  // namespace surfacer::wire
