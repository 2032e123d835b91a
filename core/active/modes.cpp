// Velocity fields, particle targets and the one-shot coat / morph / advect helpers of core/active/active_surface.h.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <optional>
#include <string>
#include <string_view>

#include "core/active/active_surface.h"
#include "core/util/checks.h"
#include "core/util/errors.h"
#include "core/util/format.h"

namespace surfacer {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr int kCellCorners = 8;  // corner k of a grid cell at offset (k & 1, (k >> 1) & 1, k >> 2)

ActiveFrame make_frame(const ActiveSurface& surface, const ActiveFrameStats& stats, int index,
                       const RunControl& control) {
  ActiveFrame frame;
  frame.mesh = surface.polygonize(control);
  frame.stats = stats;
  frame.index = index;
  return frame;
}

// --- Mode checkpoints: "SAMD" u32 version, u8 mode, i32 next frame, then ActiveSurface::save_state() ------------
enum class Mode : std::uint8_t { kCoat = 1, kMorph = 2, kAdvect = 3 };
constexpr char kModeMagic[4] = {'S', 'A', 'M', 'D'};
constexpr std::uint32_t kModeVersion = 1;
// Byte offsets of the header's fields.
constexpr std::size_t kModeVersionAt = sizeof(kModeMagic);
constexpr std::size_t kModeAt = kModeVersionAt + sizeof(std::uint32_t);
constexpr std::size_t kModeNextFrameAt = kModeAt + sizeof(Mode);
constexpr std::size_t kModeHeader = kModeNextFrameAt + sizeof(std::int32_t);

void validate_checkpoints(const ActiveCheckpoints& c) {
  if (c.every < 1) {
    throw InvalidInput("checkpoints.every", "checkpoints.every (" + std::to_string(c.every) + ") must be >= 1");
  }
}

// After frame next_frame - 1 (not the last one) was emitted.
void checkpoint(const ActiveCheckpoints& c, Mode mode, int next_frame, const ActiveSurface& surface) {
  if (!c.save || next_frame % c.every != 0) return;
  std::string state(kModeHeader, '\0');
  std::memcpy(state.data(), kModeMagic, sizeof(kModeMagic));
  std::memcpy(state.data() + kModeVersionAt, &kModeVersion, sizeof(kModeVersion));
  state[kModeAt] = static_cast<char>(mode);
  const std::int32_t next = next_frame;
  std::memcpy(state.data() + kModeNextFrameAt, &next, sizeof(next));
  state += surface.save_state();
  c.save(next_frame, std::move(state));
}

struct Resumed {
  ActiveSurface surface;
  int next_frame;
};

// The surface of c.resume_state, for a run of `mode` whose frames are 0 .. last_frame.
Resumed resume(const ActiveCheckpoints& c, Mode mode, int last_frame, const ActiveSurfaceOptions& options,
               const RunControl& control) {
  const std::string& state = *c.resume_state;
  auto bad = [](const std::string& why) {
    throw InvalidInput("resume_state", "resume_state is not a checkpoint of this run (" + why + "); start over");
  };
  if (state.size() < kModeHeader || std::memcmp(state.data(), kModeMagic, sizeof(kModeMagic)) != 0) {
    bad("not an active-surface mode checkpoint");
  }
  std::uint32_t version;
  std::memcpy(&version, state.data() + kModeVersionAt, sizeof(version));
  if (version != kModeVersion) bad("version " + std::to_string(version));
  if (static_cast<Mode>(state[kModeAt]) != mode) bad("saved by another mode");
  std::int32_t next;
  std::memcpy(&next, state.data() + kModeNextFrameAt, sizeof(next));
  if (next < 1 || next > last_frame) {
    bad("next frame " + std::to_string(next) + " is outside 1.." + std::to_string(last_frame));
  }
  try {
    return {ActiveSurface::from_state(std::string_view(state).substr(kModeHeader), options, control), next};
  } catch (const Error& e) {
    if (e.kind() != ErrorKind::kInvalidInput || e.field() != "state") throw;
    bad(e.what());
  }
  throw Internal("unreachable");  // bad() throws
}

}  // namespace

Vec3 enright_velocity(const Vec3& p, double t, double period) {
  // sin(2 a) = 2 sin(a) cos(a): three sincos instead of six sines.
  double sx, cx, sy, cy, sz, cz;
  sincos(kPi * p.x(), &sx, &cx);
  sincos(kPi * p.y(), &sy, &cy);
  sincos(kPi * p.z(), &sz, &cz);
  const double s2x = 2.0 * sx * cx, s2y = 2.0 * sy * cy, s2z = 2.0 * sz * cz;
  const double c = std::cos(kPi * t / period);
  return Vec3(2.0 * sx * sx * s2y * s2z * c, -s2x * sy * sy * s2z * c, -s2x * s2y * sz * sz * c);
}

SeparableVelocity enright_separable_velocity(double period) {
  SeparableVelocity v;
  v.spatial = [](const Vec3& p) { return enright_velocity(p, 0.0, 1.0); };
  v.time_scale = [period](double t) { return std::cos(kPi * t / period); };
  return v;
}

void VelocityGrid::validate_geometry() const {
  if (!spacing.allFinite() || !(spacing.array() > 0.0).all()) {
    throw InvalidInput("spacing", "velocity grid spacing must be finite and > 0 on every axis");
  }
  if (!origin.allFinite()) throw InvalidInput("origin", "velocity grid origin must be finite");
  if (std::min({nx, ny, nz}) < 2 || std::max({nx, ny, nz}) > kMaxPointsPerAxis) {
    throw InvalidInput("nx", "velocity grid needs 2 to " + std::to_string(kMaxPointsPerAxis) +
                                 " points per axis (nx, ny, nz = " + std::to_string(nx) + ", " + std::to_string(ny) +
                                 ", " + std::to_string(nz) + ")");
  }
}

void VelocityGrid::validate() const {
  validate_geometry();
  const std::size_t expected = std::size_t{3} * nx * ny * nz;
  if (values.size() != expected) {
    throw InvalidInput("values", "velocity grid has " + std::to_string(values.size()) +
                                     " floats; expected 3 * nx * ny * nz = " + std::to_string(expected) +
                                     " (u, v, w per point, x fastest)");
  }
  // As a scene's sampled grid: a NaN or infinite velocity would carry the surface nowhere (empty frames).
  for (std::size_t i = 0; i < values.size(); ++i) {
    if (!std::isfinite(values[i])) {
      const std::size_t node = i / 3;
      throw InvalidInput("values", "velocity grid value " + std::to_string(i) + " (component " + "uvw"[i % 3] +
                                       " of node " + std::to_string(node % nx) + "," + std::to_string(node / nx % ny) +
                                       "," + std::to_string(node / nx / ny) + ") is " +
                                       (std::isnan(values[i]) ? "NaN" : "infinite") + "; give finite velocities");
    }
  }
}

Vec3 VelocityGrid::operator()(const Vec3& p) const {
  const int n[3] = {nx, ny, nz};
  int i0[3];
  double t[3];
  for (int a = 0; a < 3; ++a) {
    double u = (p[a] - origin[a]) / spacing[a];
    if (!(u > 0.0)) u = 0.0;  // also NaN
    if (u > n[a] - 1) u = n[a] - 1;
    i0[a] = std::min(static_cast<int>(u), n[a] - 2);
    t[a] = u - i0[a];
  }
  Vec3 r = Vec3::Zero();
  for (int k = 0; k < kCellCorners; ++k) {
    double w = 1.0;
    std::size_t idx = 0;
    for (int a = 2; a >= 0; --a) {
      const int bit = (k >> a) & 1;
      w *= bit ? t[a] : 1.0 - t[a];
      idx = idx * n[a] + (i0[a] + bit);
    }
    const float* v = values.data() + 3 * idx;
    r += w * Vec3(v[0], v[1], v[2]);
  }
  return r;
}

VelocityFn make_velocity_fn(const std::shared_ptr<const VelocityGrid>& grid) {
  if (!grid) throw InvalidInput("velocity", "velocity grid is null");
  grid->validate();
  return [grid](const Vec3& p, double) { return (*grid)(p); };
}

SeparableVelocity make_separable_velocity(const std::shared_ptr<const VelocityGrid>& grid) {
  if (!grid) throw InvalidInput("velocity", "velocity grid is null");
  grid->validate();
  SeparableVelocity v;
  v.spatial = [grid](const Vec3& p) { return (*grid)(p); };
  return v;
}

FieldPtr make_particle_target(std::span<const Vec3> particles, const ParticleTargetOptions& options) {
  if (particles.empty()) throw InvalidInput("particles", "the particle frame is empty; give at least one particle");
  validate(options);
  std::vector<PointSkeleton> points(particles.size());
  for (std::size_t i = 0; i < particles.size(); ++i) {
    if (!particles[i].allFinite()) {
      throw InvalidInput("particles[" + std::to_string(i) + "]", "particle " + std::to_string(i) + " is not finite");
    }
    points[i].center = particles[i];
    points[i].radius = options.radius;
    points[i].strength = 1.0;
  }
  BlobOptions blob;
  blob.kernel = options.kernel;
  blob.iso = options.iso;
  return make_blobs(points, {}, blob);
}

void validate(const ParticleTargetOptions& options) {
  // The kernels are blobs (core/scene/scene.h): radii in [1e-150, kMaxCoordinate], iso in (0, kMaxCoordinate].
  require_range("radius", options.radius, 1e-150, kMaxCoordinate, "the kernel's support R");
  require_range_open_low("iso", options.iso, 0.0, kMaxCoordinate, "the default is 0.5");
}

void validate(const CoatOptions& coat, const ActiveSurfaceOptions& options) {
  with_path("kernel", [&] { validate(coat.kernel); });
  if (!(coat.frame_duration > 0.0) || !std::isfinite(coat.frame_duration)) {
    throw InvalidInput("frame_duration", "frame_duration must be finite and > 0; the default is 1");
  }
  if (!(options.alpha > 0.0)) {
    throw InvalidInput("alpha", "coating needs alpha > 0 (the tracking speed per unit of kernel potential)");
  }
  validate_checkpoints(coat.checkpoints);
}

int coat_particles(std::span<const std::vector<Vec3>> frames, const CoatOptions& coat,
                   const ActiveSurfaceOptions& options, const ActiveFrameSink& sink, const RunControl& control) {
  if (frames.empty()) throw InvalidInput("frames", "no particle frames; give at least one");
  validate(coat, options);
  const int last = static_cast<int>(frames.size()) - 1;
  std::optional<ActiveSurface> surface;
  int emitted = 0;
  int next = 1;
  if (coat.checkpoints.resume_state != nullptr) {
    Resumed r = resume(coat.checkpoints, Mode::kCoat, last, options, control);
    surface.emplace(std::move(r.surface));
    next = r.next_frame;
  } else {
    FieldPtr target = make_particle_target(frames[0], coat.kernel);
    surface.emplace(*target, options, control);
    surface->set_target(target);
    sink(make_frame(*surface, surface->stats(), 0, control));
    emitted = 1;
    if (last > 0) checkpoint(coat.checkpoints, Mode::kCoat, 1, *surface);
  }
  for (int i = next; i <= last; ++i) {
    control.check();
    try {
      surface->set_target(make_particle_target(frames[i], coat.kernel));
    } catch (const Error& e) {
      throw Error(e.kind(), "frames[" + std::to_string(i) + "]." + e.field(),
                  "frames[" + std::to_string(i) + "]: " + e.what());
    }
    const ActiveFrameStats stats = surface->advance(coat.frame_duration, control);
    sink(make_frame(*surface, stats, i, control));
    ++emitted;
    if (i < last) checkpoint(coat.checkpoints, Mode::kCoat, i + 1, *surface);
    control.report("coat", static_cast<double>(i) / static_cast<double>(last));
  }
  return emitted;
}

void validate(const MorphOptions& morph, const ActiveSurfaceOptions& options) {
  if (!(morph.frame_duration > 0.0) || !std::isfinite(morph.frame_duration)) {
    throw InvalidInput("frame_duration", "frame_duration must be finite and > 0");
  }
  if (morph.max_frames < 1) throw InvalidInput("max_frames", "max_frames must be >= 1");
  if (!(morph.tolerance >= 0.0) || !std::isfinite(morph.tolerance)) {
    throw InvalidInput("tolerance", "tolerance must be finite and >= 0");
  }
  if (!(options.alpha > 0.0)) throw InvalidInput("alpha", "a morph needs alpha > 0 (the tracking speed)");
  validate_checkpoints(morph.checkpoints);
}

int morph_shapes(const Field& from, FieldPtr to, const MorphOptions& morph, const ActiveSurfaceOptions& options,
                 const ActiveFrameSink& sink, const RunControl& control) {
  if (!to) throw InvalidInput("to", "the target shape is null");
  validate(morph, options);
  const int last = morph.max_frames - 1;
  std::optional<ActiveSurface> surface;
  int emitted = 0;
  int next = 1;
  if (morph.checkpoints.resume_state != nullptr) {
    if (last < 1) throw InvalidInput("resume_state", "a one-frame morph has no frame to resume at; start over");
    Resumed r = resume(morph.checkpoints, Mode::kMorph, last, options, control);
    surface.emplace(std::move(r.surface));
    next = r.next_frame;
    surface->set_target(std::move(to));
  } else {
    surface.emplace(from, options, control);
    surface->set_target(std::move(to));
    sink(make_frame(*surface, surface->stats(), 0, control));
    emitted = 1;
    if (last > 0) checkpoint(morph.checkpoints, Mode::kMorph, 1, *surface);
  }
  for (int i = next; i <= last; ++i) {
    const ActiveFrameStats stats = surface->advance(morph.frame_duration, control);
    sink(make_frame(*surface, stats, i, control));
    ++emitted;
    control.report("morph", static_cast<double>(i) / last);
    if (stats.max_dfdt < morph.tolerance) break;
    if (i < last) checkpoint(morph.checkpoints, Mode::kMorph, i + 1, *surface);
  }
  return emitted;
}

void validate_advect(const ActiveSurfaceOptions& options) {
  if (options.alpha > 0.0) {
    throw InvalidInput("alpha", "alpha (" + format_number(options.alpha) +
                                    ") tracks a target, and an advected shape has none; leave alpha at 0 (beta, "
                                    "gamma and delta act on top of the advection)");
  }
}

namespace {

template <class Velocity>
int advect_impl(const Field& shape, Velocity velocity, const AdvectOptions& advect, const ActiveSurfaceOptions& options,
                const ActiveFrameSink& sink, const RunControl& control) {
  validate(advect);
  validate_advect(options);
  std::optional<ActiveSurface> surface;
  int emitted = 0;
  int next = 1;
  if (advect.checkpoints.resume_state != nullptr) {
    Resumed r = resume(advect.checkpoints, Mode::kAdvect, advect.frames, options, control);
    surface.emplace(std::move(r.surface));
    next = r.next_frame;
    surface->set_velocity(std::move(velocity));  // keeps the restored step bound
  } else {
    surface.emplace(shape, options, control);
    surface->set_velocity(std::move(velocity));
    sink(make_frame(*surface, surface->stats(), 0, control));
    emitted = 1;
    checkpoint(advect.checkpoints, Mode::kAdvect, 1, *surface);
  }
  for (int i = next; i <= advect.frames; ++i) {
    const ActiveFrameStats stats = surface->advance(advect.frame_interval, control);
    sink(make_frame(*surface, stats, i, control));
    ++emitted;
    if (i < advect.frames) checkpoint(advect.checkpoints, Mode::kAdvect, i + 1, *surface);
    control.report("advect", static_cast<double>(i) / advect.frames);
  }
  return emitted;
}

}  // namespace

void validate(const AdvectOptions& advect) {
  if (!(advect.frame_interval > 0.0) || !std::isfinite(advect.frame_interval)) {
    throw InvalidInput("frame_interval", "frame_interval must be finite and > 0");
  }
  if (advect.frames < 1) throw InvalidInput("frames", "frames must be >= 1");
  validate_checkpoints(advect.checkpoints);
}

int advect_shape(const Field& shape, VelocityFn velocity, const AdvectOptions& advect,
                 const ActiveSurfaceOptions& options, const ActiveFrameSink& sink, const RunControl& control) {
  if (!velocity) throw InvalidInput("velocity", "no velocity field given");
  return advect_impl(shape, std::move(velocity), advect, options, sink, control);
}

int advect_shape(const Field& shape, SeparableVelocity velocity, const AdvectOptions& advect,
                 const ActiveSurfaceOptions& options, const ActiveFrameSink& sink, const RunControl& control) {
  if (!velocity.spatial) throw InvalidInput("velocity", "no velocity field given");
  return advect_impl(shape, std::move(velocity), advect, options, sink, control);
}

}  // namespace surfacer
