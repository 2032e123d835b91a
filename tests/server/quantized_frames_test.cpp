// Frames are clean on their quantization grid and their stats describe the mesh delivered (docs/ALGORITHMS.md §5
// "Clean on the grid"): across the example scenes, both polygonizers, several resolutions, 10..16 bits and the three
// quantizing codecs, the decoded mesh has no zero-area triangle and no two vertices at one position, is closed and
// manifold when the lossless (PLY) frame is, and the frame's check equals a fresh check of the decoded mesh.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include "core/mesh/frame_codec.h"
#include "core/mesh/mesh_checks.h"
#include "core/util/parallel.h"
#include "tests/server/test_client.h"
#include "tests/support/mesh_expectations.h"

namespace surfacer::testing {
namespace {

// Referenced vertices that share their position with another referenced vertex.
std::int64_t coincident_vertices(const Mesh& mesh) {
  std::vector<char> used(mesh.vertices.size(), 0);
  for (const Triangle& t : mesh.triangles) {
    for (const std::uint32_t v : t) used[v] = 1;
  }
  std::vector<std::array<double, 3>> points;
  for (std::size_t v = 0; v < mesh.vertices.size(); ++v) {
    if (used[v]) points.push_back({mesh.vertices[v][0], mesh.vertices[v][1], mesh.vertices[v][2]});
  }
  std::sort(points.begin(), points.end());
  std::int64_t count = 0;
  for (std::size_t i = 1; i < points.size(); ++i) count += points[i] == points[i - 1];
  return count;
}

// Triangles whose decoded corners span no area (exactly, in the decoded float coordinates).
std::int64_t zero_area_triangles(const Mesh& mesh) {
  std::int64_t count = 0;
  for (const Triangle& t : mesh.triangles) {
    const Vec3 &a = mesh.vertices[t[0]], &b = mesh.vertices[t[1]], &c = mesh.vertices[t[2]];
    count += !((b - a).cross(c - a).squaredNorm() > 0.0);
  }
  return count;
}

void expect_same_check(const v1::MeshCheck& stats, const MeshReport& fresh) {
  EXPECT_EQ(stats.closed(), fresh.closed);
  EXPECT_EQ(stats.edge_manifold(), fresh.edge_manifold);
  EXPECT_EQ(stats.vertex_manifold(), fresh.vertex_manifold);
  EXPECT_EQ(stats.oriented(), fresh.oriented);
  EXPECT_EQ(stats.euler_characteristic(), fresh.euler_characteristic);
  EXPECT_EQ(stats.components(), fresh.components);
  EXPECT_EQ(stats.boundary_edges(), fresh.boundary_edges);
  EXPECT_EQ(stats.non_manifold_edges(), fresh.non_manifold_edges);
  EXPECT_EQ(stats.degenerate_triangles(), fresh.degenerate_triangles);
  EXPECT_EQ(std::vector<std::int64_t>(stats.valence_histogram().begin(), stats.valence_histogram().end()),
            fresh.valence_histogram);
  EXPECT_EQ(stats.min_valence(), fresh.min_valence);
  EXPECT_EQ(stats.max_valence(), fresh.max_valence);
  // The decoder may order the triangles differently: sums agree to rounding.
  EXPECT_NEAR(stats.min_angle_degrees(), fresh.min_angle_degrees, 1e-9);
  EXPECT_NEAR(stats.max_angle_degrees(), fresh.max_angle_degrees, 1e-9);
  EXPECT_NEAR(stats.area(), fresh.area, 1e-9 * std::abs(fresh.area));
  EXPECT_NEAR(stats.volume(), fresh.volume, 1e-9 * std::abs(fresh.volume) + 1e-12);
}

// Runs every example scene with both polygonizers at each of `cells`, then each of `bits` with each of `encodings`.
void expect_clean_frames(const std::vector<int>& cells_list, const std::vector<int>& bits_list,
                         const std::vector<v1::MeshEncoding>& encodings) {
  server::ServerOptions options;
  options.listen = "";
  auto server = server::SurfacerServer::start(options);
  auto stub = v1::Surfacer::NewStub(server->in_process_channel());
  const int threads = 1;
  std::map<std::string, v1::Scene> scenes;
  for (const auto& entry : std::filesystem::directory_iterator(SURFACER_SOURCE_DIR "/examples/scenes")) {
    if (entry.path().extension() == ".json") scenes[entry.path().stem().string()] = scene_from_file(entry.path());
  }
  ASSERT_GE(scenes.size(), 5u);
  auto run = [&](v1::JobSpec spec) {
    std::string id;
    const grpc::Status status = submit(*stub, spec, &id);
    EXPECT_TRUE(status.ok()) << status.error_message();
    WatchResult result = watch_job(*stub, id);
    EXPECT_EQ(result.frames.size(), 1u) << result.final_job.error().message();
    return result.frames.at(0);
  };
  int frames = 0;
  for (const auto& [name, scene] : scenes) {
    for (const v1::Polygonizer method : {v1::POLYGONIZER_CUBES, v1::POLYGONIZER_TILES}) {
      for (const int cells : cells_list) {
        v1::JobSpec spec = isosurface_spec({scene}, cells);
        spec.mutable_isosurface()->set_method(method);
        v1::JobSpec lossless = spec;
        lossless.mutable_output()->set_encoding(v1::MESH_ENCODING_PLY);
        const MeshReport source = check_mesh(decode_frame(run(lossless).bytes, FrameCodec::kPly, threads));
        for (const int bits : bits_list) {
          for (const v1::MeshEncoding encoding : encodings) {
            SCOPED_TRACE(name + (method == v1::POLYGONIZER_CUBES ? " cubes " : " tiles ") + std::to_string(cells) +
                         " cells, " + std::to_string(bits) + " bits, encoding " + std::to_string(encoding));
            spec.mutable_output()->set_quantization_bits(bits);
            spec.mutable_output()->set_encoding(encoding);
            const ReceivedFrame frame = run(spec);
            const FrameCodec codec = encoding == v1::MESH_ENCODING_DRACO          ? FrameCodec::kDraco
                                     : encoding == v1::MESH_ENCODING_DRACO_PIECES ? FrameCodec::kDracoPieces
                                                                                  : FrameCodec::kMeshopt;
            const Mesh decoded = decode_frame(frame.bytes, codec, threads);
            const MeshReport fresh = check_mesh(decoded);
            // Clean as decoded: no zero-area triangle, no two vertices at one position, and as closed and
            // manifold as the lossless frame; nothing left that the frame would have to report.
            EXPECT_EQ(zero_area_triangles(decoded), 0);
            EXPECT_EQ(fresh.degenerate_triangles, 0);
            EXPECT_EQ(coincident_vertices(decoded), 0);
            EXPECT_EQ(frame.header.stats().metrics().at("grid_left"), 0.0);
            if (source.closed && source.edge_manifold && source.vertex_manifold) {
              EXPECT_TRUE(mesh_has(fresh, kClosedManifold));
            }
            EXPECT_EQ(frame.header.stats().vertices(), static_cast<std::int64_t>(decoded.vertices.size()));
            EXPECT_EQ(frame.header.stats().triangles(), static_cast<std::int64_t>(decoded.triangles.size()));
            expect_same_check(frame.header.stats().check(), fresh);
            ++frames;
          }
        }
      }
    }
  }
  EXPECT_GE(frames, static_cast<int>(2 * scenes.size() * cells_list.size() * bits_list.size() * encodings.size()));
}

// The active and optimize engines' frames alike: an Enright advection of a sphere polygonized by either method
// (the active engine's own polygonizers, with the same margin) and an optimization of csg_block with snapshots, at 10
// and 14 bits, every frame clean as decoded and equal to its stats.
TEST(QuantizedFrames, ActiveAndOptimizeFramesAreCleanToo) {
  server::ServerOptions options;
  options.listen = "";
  auto server = server::SurfacerServer::start(options);
  auto stub = v1::Surfacer::NewStub(server->in_process_channel());
  const int threads = 1;
  const v1::Scene sphere = scene_from_file(SURFACER_SOURCE_DIR "/examples/scenes/sphere.json");
  const v1::Scene block = scene_from_file(SURFACER_SOURCE_DIR "/examples/scenes/csg_block.json");
  std::vector<std::pair<std::string, v1::JobSpec>> specs;
  for (const v1::Polygonizer method : {v1::POLYGONIZER_CUBES, v1::POLYGONIZER_TILES}) {
    v1::JobSpec spec;
    auto* job = spec.mutable_active();
    job->set_grid_spacing(0.03);
    job->set_polygonizer(method);
    *job->mutable_advect()->mutable_shape() = sphere;
    job->mutable_advect()->mutable_enright();
    job->mutable_advect()->set_frames(2);
    job->mutable_advect()->set_frame_interval(0.3);
    specs.emplace_back(method == v1::POLYGONIZER_CUBES ? "advect cubes" : "advect tiles", spec);
  }
  {
    v1::JobSpec spec;
    auto* job = spec.mutable_optimize();
    *job->mutable_scene() = block;
    job->mutable_polygonize()->set_cells(24);
    job->set_max_iterations(20);
    job->set_snapshot_every(10);
    specs.emplace_back("optimize", spec);
  }
  int frames = 0;
  for (auto& [name, spec] : specs) {
    for (const int bits : {10, 14}) {
      SCOPED_TRACE(name + ", " + std::to_string(bits) + " bits");
      spec.mutable_output()->set_quantization_bits(bits);
      std::string id;
      const grpc::Status status = submit(*stub, spec, &id);
      ASSERT_TRUE(status.ok()) << status.error_message();
      const WatchResult result = watch_job(*stub, id);
      ASSERT_GE(result.frames.size(), 2u) << result.final_job.error().message();
      for (const auto& [index, frame] : result.frames) {
        const Mesh decoded = decode_frame(frame.bytes, FrameCodec::kDraco, threads);
        const MeshReport fresh = check_mesh(decoded);
        EXPECT_EQ(zero_area_triangles(decoded), 0);
        EXPECT_EQ(coincident_vertices(decoded), 0);
        EXPECT_EQ(frame.header.stats().metrics().at("grid_left"), 0.0);
        EXPECT_TRUE(mesh_has(fresh, kClosedManifold));
        expect_same_check(frame.header.stats().check(), fresh);
        ++frames;
      }
    }
  }
  EXPECT_GE(frames, 12);
}

TEST(QuantizedFrames, AreCleanOnTheirGridAndDescribedByTheirStats) {
  expect_clean_frames({20, 48, 96}, {10, 12, 14, 16},
                      {v1::MESH_ENCODING_DRACO, v1::MESH_ENCODING_DRACO_PIECES, v1::MESH_ENCODING_MESHOPT});
}

}  // namespace
}  // namespace surfacer::testing
