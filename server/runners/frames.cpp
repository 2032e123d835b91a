#include "server/runners/frames.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <future>
#include <latch>
#include <memory>
#include <optional>
#include <system_error>
#include <thread>

#include "core/mesh/frame_codec.h"
#include "core/mesh/grid_cleanup.h"
#include "core/mesh/mesh_codec.h"
#include "core/util/errors.h"
#include "core/util/thread_pool.h"

namespace surfacer::server {
namespace {

// One Draco mesh encoded beside the checks, by whichever thread claims it first: a pool thread (the task is posted
// as soon as the frame is made) or, when none has taken it by the end of the checks, a thread started for it (at most
// kMaxEncodeThreads at once; past them, the frame's own thread), so the frame's own thread only waits, and gives up
// at a cancel (Draco's encoder cannot be stopped). The encoder's copy of
// the mesh is made by the thread that claimed it, so it is held only while it is encoded; a pool thread's encoding may
// outlive a cancelled frame, which waits only for that copy (`copied`) before its mesh goes.
struct SideEncoding {
  SideEncoding(const Mesh& mesh, const DracoOptions& options) : mesh(mesh), options(options) {}
  const Mesh& mesh;  // valid until `copied` by the thread that claimed it
  const DracoOptions options;
  std::atomic<bool> claimed{false};
  std::latch copied{1};
  std::promise<std::string> bytes;
  // Encodes unless another thread claimed it; true when this call did.
  bool run() {
    if (claimed.exchange(true, std::memory_order_acq_rel)) return false;
    try {
      std::optional<DracoEncoder> encoder;
      try {
        encoder.emplace(mesh, options);
      } catch (...) {
        copied.count_down();
        throw;
      }
      copied.count_down();
      bytes.set_value(encoder->encode());
    } catch (...) {
      bytes.set_exception(std::current_exception());
    }
    return true;
  }
  // Called by the frame's own thread on its way out: when no thread has claimed it, none will; else waits for the
  // claiming thread's copy of the mesh.
  void leave() {
    if (claimed.exchange(true, std::memory_order_acq_rel)) copied.wait();
  }
};

// Encodes on threads started for them (FrameMaker::make) running at once, at most. Each holds its copy of a frame's
// mesh until Draco returns, also after the frame was cancelled, so their number bounds that memory; past it the
// frame's own thread encodes, and a cancel then waits for Draco.
constexpr int kMaxEncodeThreads = 4;
std::atomic<int> encode_threads{0};

}  // namespace

double StageTimer::now() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

void fill_mesh_check(const MeshReport& r, v1::MeshCheck& out) {
  out.set_closed(r.closed);
  out.set_edge_manifold(r.edge_manifold);
  out.set_vertex_manifold(r.vertex_manifold);
  out.set_oriented(r.oriented);
  out.set_euler_characteristic(r.euler_characteristic);
  out.set_components(r.components);
  out.set_boundary_edges(r.boundary_edges);
  out.set_non_manifold_edges(r.non_manifold_edges);
  out.set_degenerate_triangles(r.degenerate_triangles);
  for (auto v : r.valence_histogram) out.add_valence_histogram(v);
  out.set_min_valence(r.min_valence);
  out.set_max_valence(r.max_valence);
  out.set_min_angle_degrees(r.min_angle_degrees);
  out.set_max_angle_degrees(r.max_angle_degrees);
  out.set_area(r.area);
  out.set_volume(r.volume);
}

FrameMaker::FrameMaker(FrameEncoding encoding, std::int64_t max_triangles, int threads)
    : encoding_(std::move(encoding)), max_triangles_(max_triangles), threads_(std::max(1, threads)) {}

double FrameMaker::vertex_margin() const {
  const std::optional<QuantizationGrid> grid = encoding_.grid();
  return grid ? kMarginSteps * grid->step() : 0.0;
}

FrameOutput FrameMaker::make(Mesh mesh, StageTimer& timer, const RunControl& control) const {
  if (static_cast<std::int64_t>(mesh.triangles.size()) > max_triangles_) {
    throw ResourceLimit("max_triangles", "the mesh has " + std::to_string(mesh.triangles.size()) +
                                             " triangles, over the server's limit of " +
                                             std::to_string(max_triangles_) +
                                             "; lower the resolution or start the server with a larger "
                                             "--max-triangles");
  }
  const FrameCodecOptions& options = encoding_.options;
  FrameOutput out;
  out.encoding = encoding_.mesh_encoding();
  const std::optional<QuantizationGrid> grid = encoding_.grid();
  StageTimer check_timer, encode_timer;
  GridCleanupReport cleanup;
  if (grid) {
    control.report("grid_cleanup", 0.0);
    GridCleanupOptions cleanup_options;
    cleanup_options.threads = threads_;
    cleanup = check_timer.run("grid_cleanup", [&] { return clean_on_grid(mesh, *grid, cleanup_options, control); });
  }
  // Every position is put on its grid point, so that the checks (area and volume included) see what a decoder
  // reads and the encoder, quantizing the same points again, reproduces them exactly.
  if (grid) snap_to_grid(mesh.vertices, *grid, threads_);
  MeshReport report;
  auto check = [&] {
    control.report("check", 0.0);
    report = check_timer.run("check", [&] { return check_mesh(mesh, threads_, control, sliver_degrees_); });
  };
  if (options.codec == FrameCodec::kDraco && mesh.triangles.size() > options.max_piece_triangles) {
    // One Draco mesh, on a pool thread while the checks run on the others (SideEncoding).
    out.bytes = encode_timer.run("encode", [&] {
      auto side = std::make_shared<SideEncoding>(mesh, options.draco);
      std::future<std::string> encoded = side->bytes.get_future();
      surfacer::post([side] { side->run(); });
      try {
        check();
        control.report("encode", 0.0);
        // No pool thread has taken it (each is busy, e.g. with a cancelled job's encode, which Draco cannot stop): a
        // thread of its own encodes it, so this one can still give up at a cancel (up to kMaxEncodeThreads of them).
        if (!side->claimed.load(std::memory_order_acquire)) {
          bool started = false;
          if (encode_threads.fetch_add(1, std::memory_order_relaxed) < kMaxEncodeThreads) {
            try {
              std::thread([side] {
                side->run();
                encode_threads.fetch_sub(1, std::memory_order_relaxed);
              }).detach();
              started = true;
            } catch (const std::system_error&) {  // no thread to be had: encoded here
            }
          }
          if (!started) {
            encode_threads.fetch_sub(1, std::memory_order_relaxed);
            side->run();
          }
        }
        while (encoded.wait_for(std::chrono::milliseconds(10)) != std::future_status::ready) control.check();
      } catch (...) {
        side->leave();  // cancelled: a pool thread that has not begun skips it
        throw;
      }
      return encoded.get();
    });
  } else {
    // The checks, then the encoding, each on every one of the threads: run side by side as two items, each would get
    // one thread only, since a pool thread waiting for its items does not run the other item's pieces.
    check();
    control.report("encode", 0.0);
    out.bytes = encode_timer.run("encode", [&] { return encode_frame(mesh, options, threads_, control); });
  }
  out.stats.set_vertices(static_cast<std::int64_t>(mesh.vertices.size()));
  out.stats.set_triangles(static_cast<std::int64_t>(mesh.triangles.size()));
  fill_mesh_check(report, *out.stats.mutable_check());
  if (sliver_degrees_ > 0.0) {
    (*out.stats.mutable_metrics())["slivers_left"] = static_cast<double>(report.triangles_below_angle);
  }
  if (grid) {
    auto& metrics = *out.stats.mutable_metrics();
    metrics["grid_degenerate_found"] = static_cast<double>(cleanup.degenerate_found);
    metrics["grid_coincident_found"] = static_cast<double>(cleanup.coincident_found);
    metrics["grid_nudges"] = static_cast<double>(cleanup.nudges);
    metrics["grid_left"] = static_cast<double>(cleanup.degenerate_left + cleanup.coincident_left);
  }
  auto add_timing = [&](const std::string& stage, double seconds) {
    auto* t = out.stats.add_timings();
    t->set_stage(stage);
    t->set_seconds(seconds);
  };
  for (const StageTimer* t : {&timer, &encode_timer, &check_timer}) {
    for (const auto& [stage, seconds] : t->timings()) add_timing(stage, seconds);
  }
  return out;
}

}  // namespace surfacer::server
