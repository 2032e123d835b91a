#include "server/runners/frames.h"

#include <chrono>
#include <future>

#include "core/mesh/mesh_codec.h"
#include "core/mesh/mesh_io.h"
#include "core/util/errors.h"

namespace surfacer::server {

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

FrameOutput make_frame(const Mesh& mesh, const FrameEncoding& encoding, std::int64_t max_triangles, StageTimer& timer) {
  if (static_cast<std::int64_t>(mesh.triangles.size()) > max_triangles) {
    throw ResourceLimit("max_triangles", "the mesh has " + std::to_string(mesh.triangles.size()) +
                                             " triangles, over the server's limit of " + std::to_string(max_triangles) +
                                             "; lower the resolution or start the server with a larger "
                                             "--max-triangles");
  }
  FrameOutput out;
  out.encoding = encoding.encoding;
  double check_seconds = 0.0;
  // The checks run beside the (single-threaded) encoder.
  std::future<MeshReport> report_future = std::async(std::launch::async, [&] {
    StageTimer check_timer;
    MeshReport r = check_timer.run("check", [&] { return check_mesh(mesh); });
    check_seconds = check_timer.timings().front().second;
    return r;
  });
  timer.run("encode", [&] {
    out.bytes = encoding.encoding == v1::MESH_ENCODING_PLY ? write_ply(mesh, /*double_precision=*/true)
                                                           : encode_draco(mesh, encoding.draco);
  });
  const MeshReport report = report_future.get();
  out.stats.set_vertices(static_cast<std::int64_t>(mesh.vertices.size()));
  out.stats.set_triangles(static_cast<std::int64_t>(mesh.triangles.size()));
  fill_mesh_check(report, *out.stats.mutable_check());
  auto add_timing = [&](const std::string& stage, double seconds) {
    auto* t = out.stats.add_timings();
    t->set_stage(stage);
    t->set_seconds(seconds);
  };
  for (const auto& [stage, seconds] : timer.timings()) add_timing(stage, seconds);
  add_timing("check", check_seconds);
  return out;
}

}  // namespace surfacer::server
