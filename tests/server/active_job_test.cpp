// The active job through a real server on a loopback port.
#include <gtest/gtest.h>

#include "core/mesh/mesh_checks.h"
#include "core/mesh/mesh_codec.h"
#include "tests/server/test_client.h"

namespace surfacer::testing {
namespace {

TEST(ActiveJob, MorphStreamsFramesWithMetrics) {
  LoopbackServer s;
  v1::JobSpec spec;
  auto* job = spec.mutable_active();
  *job->mutable_morph()->mutable_from() = scene_from_json(R"({"root": {"sphere": {"radius": 0.5}}})");
  *job->mutable_morph()->mutable_to() =
      scene_from_json(R"({"root": {"box": {"half_size": {"x": 0.45, "y": 0.45, "z": 0.45}}}})");
  job->mutable_morph()->set_max_frames(3);
  job->set_grid_spacing(0.05);
  std::string id;
  const auto status = submit(*s.stub, spec, &id);
  ASSERT_TRUE(status.ok()) << status.error_message();
  const auto result = watch_job(*s.stub, id);
  ASSERT_EQ(result.states.back(), v1::JOB_STATE_SUCCEEDED) << result.final_job.error().message();
  ASSERT_GE(result.frames.size(), 2u);
  for (const auto& [index, frame] : result.frames) {
    const auto report = check_mesh(decode_draco(frame.bytes));
    EXPECT_TRUE(report.closed) << index;
    const auto& m = frame.header.stats().metrics();
    EXPECT_GT(m.at("volume"), 0.0);
    EXPECT_GT(m.at("active_nodes"), 0.0);
    EXPECT_EQ(m.at("components"), 1.0);
  }
}

TEST(ActiveJob, BadModeIsInvalidArgument) {
  LoopbackServer s;
  v1::JobSpec spec;
  spec.mutable_active()->set_grid_spacing(0.05);
  auto status = submit(*s.stub, spec, nullptr);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(status.error_message().find("spec.active"), std::string::npos);
  spec.mutable_active()->set_grid_spacing(-1);
  *spec.mutable_active()->mutable_morph()->mutable_from() = scene_from_json(R"({"root": {"sphere": {"radius": 1}}})");
  status = submit(*s.stub, spec, nullptr);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(status.error_message().find("spec.active.grid_spacing"), std::string::npos);
}

// A spacing too fine for the region the surface occupies is refused at submit, naming grid_spacing, for morphs and
// advections, from just past the grid's reach to far past what a 64-bit node count holds; never run and then failed
// as a shape without a surface.
TEST(ActiveJob, SpacingTooFineForTheShapeIsRefusedAtSubmit) {
  LoopbackServer s;
  for (const double radius : {1.0, 1e4, 1e8}) {
    for (const double cells_per_radius : {3e6, 1e12, 1e20}) {
      const std::string sphere = R"({"root": {"sphere": {"radius": )" + std::to_string(radius) + "}}}";
      const double h = std::max(1e-12, radius / cells_per_radius);
      for (const bool morph : {true, false}) {
        SCOPED_TRACE(sphere + " h " + ::testing::PrintToString(h) + (morph ? " morph" : " advect"));
        v1::JobSpec spec;
        auto* job = spec.mutable_active();
        job->set_grid_spacing(h);
        if (morph) {
          *job->mutable_morph()->mutable_from() = scene_from_json(sphere);
          *job->mutable_morph()->mutable_to() = scene_from_json(sphere);
        } else {
          *job->mutable_advect()->mutable_shape() = scene_from_json(sphere);
          job->mutable_advect()->mutable_enright();
          job->mutable_advect()->set_frames(2);
          job->mutable_advect()->set_frame_interval(0.1);
        }
        const auto status = submit(*s.stub, spec, nullptr);
        EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << status.error_message();
        EXPECT_NE(status.error_message().find("spec.active.grid_spacing"), std::string::npos) << status.error_message();
        EXPECT_NE(status.error_message().find("coarsen"), std::string::npos) << status.error_message();
      }
    }
  }
}

}  // namespace
}  // namespace surfacer::testing
