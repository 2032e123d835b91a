// Every bundled example scene polygonizes to a closed, manifold, outward-oriented mesh through the service, and the
// bundled particle set surfaces to one.
#include <gtest/gtest.h>

#include <filesystem>

#include "core/mesh/mesh_checks.h"
#include "core/mesh/mesh_codec.h"
#include "core/particles/particle_io.h"
#include "tests/server/test_client.h"
#include "tests/support/mesh_expectations.h"

namespace surfacer::testing {
namespace {

TEST(Examples, EverySceneGivesAClosedMesh) {
  server::ServerOptions options;
  options.listen = "";
  auto server = server::SurfacerServer::start(options);
  auto stub = v1::Surfacer::NewStub(server->in_process_channel());
  int scenes = 0;
  for (const auto& entry : std::filesystem::directory_iterator(SURFACER_SOURCE_DIR "/examples/scenes")) {
    if (entry.path().extension() != ".json") continue;
    ++scenes;
    SCOPED_TRACE(entry.path().filename().string());
    std::string id;
    const auto status = submit(*stub, isosurface_spec({scene_from_file(entry.path())}, 64), &id);
    ASSERT_TRUE(status.ok()) << status.error_message();
    const auto result = watch_job(*stub, id);
    ASSERT_EQ(result.frames.size(), 1u) << result.final_job.error().message();
    const auto report = check_mesh(decode_draco(result.frames.at(0).bytes));
    EXPECT_GT(report.area, 0.0);
    EXPECT_TRUE(mesh_has(report, kClosed | kEdgeManifold | kOriented | kPositiveVolume));
  }
  EXPECT_GE(scenes, 5);
}

TEST(Examples, TheParticleSetGivesAClosedFaithfulSurface) {
  server::ServerOptions options;
  options.listen = "";
  auto server = server::SurfacerServer::start(options);
  auto stub = v1::Surfacer::NewStub(server->in_process_channel());
  const ParticleFrame particles = read_particles(SURFACER_SOURCE_DIR "/examples/particles/drop_in_pool.bin.gz");
  ASSERT_GT(particles.positions.size(), 10000u);
  std::string bytes;
  for (const Vec3& p : particles.positions) {
    for (int c = 0; c < 3; ++c) {
      const float f = static_cast<float>(p[c]);
      bytes.append(reinterpret_cast<const char*>(&f), sizeof f);
    }
  }
  v1::JobSpec spec;
  spec.mutable_particles()->add_frames()->set_upload_id(upload(*stub, bytes));
  spec.mutable_particles()->set_r_inner(0.006);  // as scripts/demo.sh runs it
  std::string id;
  ASSERT_TRUE(submit(*stub, spec, &id).ok());
  const auto result = watch_job(*stub, id);
  ASSERT_EQ(result.frames.size(), 1u) << result.final_job.error().message();
  const auto report = check_mesh(decode_draco(result.frames.at(0).bytes));
  EXPECT_TRUE(mesh_has(report, kClosed | kEdgeManifold | kOriented | kPositiveVolume));
  EXPECT_EQ(report.components, 2);  // the pool and the droplet above it
  EXPECT_EQ(result.frames.at(0).header.stats().metrics().at("faithful_fraction_final"), 1.0);
}

}  // namespace
}  // namespace surfacer::testing
