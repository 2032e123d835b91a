// Every bundled example scene polygonizes to a closed, manifold, outward-oriented mesh through the service.
#include <gtest/gtest.h>

#include <filesystem>

#include "core/mesh/mesh_checks.h"
#include "core/mesh/mesh_codec.h"
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

}  // namespace
}  // namespace surfacer::testing
