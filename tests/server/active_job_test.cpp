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

}  // namespace
}  // namespace surfacer::testing
