// Each job message -> its engine's options, one function per job. Only the fields a request sets override the
// defaults of core's options structs (the defaults live there, once); every result is checked by the engine's own
// validate(), its errors placed at the request path ("spec.particles.r_outer (0.004) must exceed r_inner ...").
// Unknown enum values are refused, naming the field. What depends on the server (limits, frame counts) is checked
// by the server's job runners.
#pragma once

#include <functional>
#include <span>
#include <string>
#include <vector>

#include "core/active/active_surface.h"
#include "core/optimize/mesh_optimizer.h"
#include "core/particles/particle_surfacer.h"
#include "core/polygonize/polygonize.h"
#include "surfacer/v1/surfacer.pb.h"
#include "wire/particle_frames.h"

namespace surfacer::wire {

class UploadLookup;

// v1::Polygonizer -> core; POLYGONIZER_UNSPECIFIED gives `unspecified`. Throws InvalidInput(field) for other values.
Polygonizer to_polygonizer(int value, Polygonizer unspecified, const std::string& field);
v1::Polygonizer to_wire(Polygonizer polygonizer);

// IsosurfaceJob (path "spec.isosurface"): method, bounds, cells or cell_size.
PolygonizeOptions isosurface_options(const v1::IsosurfaceJob& job, bool normals, const std::string& path);
// The fields of an IsosurfaceJob's scenes, one per frame. Without job.bounds an unbounded scene is refused, naming
// the node that makes it so ("spec.isosurface.bounds are needed: ...root.plane is unbounded; ...").
std::vector<FieldPtr> isosurface_fields(const v1::IsosurfaceJob& job, const UploadLookup& uploads,
                                        const std::string& path);
// OptimizeJob.polygonize: the start mesh the job makes itself (defaults: default_start_polygonize()).
PolygonizeOptions start_polygonize_options(const v1::Polygonize& start, const std::string& path);
// ParticlesJob: radii, sweeps, relaxation, erosion, container box. The container's solid is a scene (its uploads are
// looked up): container_solid() builds it, null when the job has none.
ParticleSurfacingOptions particle_options(const v1::ParticlesJob& job, bool normals, const std::string& path);
FieldPtr container_solid(const v1::ParticlesJob& job, const UploadLookup& uploads, const std::string& path);
// The quantization box of a particles job (core particle_sequence_box over the union of the frames' summaries, with
// the job's radii and container box). `first_frame` gives frame 0's positions, needed only when r_inner is derived.
// Throws InvalidInput("spec.particles.r_inner") when a frame has no radii and the job gives neither r_inner nor
// derive_r_inner (require_r_inner_frame).
Aabb particles_job_box(const v1::ParticlesJob& job, std::span<const ParticleSummary> frames,
                       const std::function<std::vector<Vec3>()>& first_frame);

// Frame `index` of a particles job: core's require_r_inner_source at "spec.particles.r_inner", naming the frame.
void require_r_inner_frame(const v1::ParticlesJob& job, std::size_t index, bool frame_has_radii);

// OptimizeJob: flows, coefficients, schedule, subdivision, snapshots.
MeshOptimizerOptions optimizer_options(const v1::OptimizeJob& job, bool normals, const std::string& path);
// ActiveJob: grid spacing, domain, motion coefficients (alpha defaults to kTrackingAlpha in coat and morph), cfl,
// polygonizer.
ActiveSurfaceOptions active_options(const v1::ActiveJob& job, bool normals, const std::string& path);
// The active job's mode (path "spec.active"), each validated with the job's `options` (the engine's names become the
// request's: kernel_radius, iso, frame_time; alpha is the job's).
CoatOptions coat_options(const v1::ActiveCoat& coat, const ActiveSurfaceOptions& options, const std::string& path);
MorphOptions morph_options(const v1::ActiveMorph& morph, const ActiveSurfaceOptions& options, const std::string& path);
AdvectOptions advect_options(const v1::ActiveAdvect& advect, const std::string& path);

// A VelocityGrid (path "spec.active.advect.grid") with its origin, spacing and dimensions, checked by core's
// validate_geometry(); its values are an upload, for the caller to read. Throws InvalidInput at `path`.
VelocityGrid velocity_grid_geometry(const v1::VelocityGrid& grid, const std::string& path);

// Every engine option of `spec` and its output options, checked by the functions above and frame_encoding() as the
// job runners check them at submit, without the data: scenes, particle frames, start meshes and velocity grids are the
// runners' to check. The client calls it before it reads or uploads anything, so a bad value is refused with the
// server's own message (the field at its request path, "spec.particles.r_outer (0.05) must exceed r_inner (0.1);
// ..."). Throws InvalidInput.
void check_job_options(const v1::JobSpec& spec);

}  // namespace surfacer::wire
