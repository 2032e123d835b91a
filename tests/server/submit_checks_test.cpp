// What SubmitJob refuses at once, through a real server on a loopback port: enum values the schema does not know,
// values out of range or not finite (enumerated over every numeric field of one spec per job and mode), frame
// counts over --max-frames (every job type and mode), text fields over their limits, scenes nested deeper than the
// limit. Every refusal names the field; nothing accepted fails later for a reason submit could have seen. GetServerInfo
// tells the limits.
#include <google/protobuf/util/json_util.h>
#include <grpcpp/generic/generic_stub.h>
#include <gtest/gtest.h>

#include <future>
#include <limits>

#include "tests/server/test_client.h"
#include "wire/protocol.h"
#include "wire/request_limits.h"

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

TEST(SubmitChecks, ValuesThatOnlyFailedWhenRunAreRefusedAtSubmitWithTheirPath) {
  LoopbackServer s;
  const auto bad = grpc::StatusCode::INVALID_ARGUMENT;
  expect_refused(*s.stub, isosurface_of(R"({"root": {"sphere": {"radius": 1e308}}})"), bad,
                 "spec.isosurface.scenes[0].root.sphere.radius (1e+308) is beyond +-1e+12");
  expect_refused(*s.stub, isosurface_of(R"({"root": {"blobs": {"kernel": "KERNEL_BLINN", "blobbiness": 1e308,
                     "points": [{"radius": 1}]}}})"),
                 bad, "spec.isosurface.scenes[0].root.blobs.blobbiness (1e+308) must be in (0, 100]");
  v1::JobSpec active;
  active.mutable_active()->set_grid_spacing(0.1);
  *active.mutable_active()->mutable_morph()->mutable_from() = scene_from_json(R"({"root": {"sphere": {"radius": 1}}})");
  *active.mutable_active()->mutable_morph()->mutable_to() = scene_from_json(R"({"root": {"sphere": {"radius": 1}}})");
  active.mutable_active()->set_cfl(1e9);
  expect_refused(*s.stub, active, bad, "spec.active.cfl (1e+09) must be in (0, 1]");
  active.mutable_active()->clear_cfl();
  active.mutable_active()->set_alpha(std::numeric_limits<double>::infinity());
  expect_refused(*s.stub, active, bad, "spec.active.alpha (inf) must be finite");
  active.mutable_active()->clear_alpha();
  active.mutable_active()->mutable_morph()->set_tolerance(std::numeric_limits<double>::quiet_NaN());
  expect_refused(*s.stub, active, bad, "spec.active.morph.tolerance");
}

// Without bounds an unbounded scene is refused at submit, naming the node that makes it so, however deep; with
// bounds it runs.
TEST(SubmitChecks, UnboundedScenesNameTheNodeThatMakesThemSo) {
  LoopbackServer s;
  const auto bad = grpc::StatusCode::INVALID_ARGUMENT;
  // A plane under a union stays unbounded; one under an intersection with a sphere does not.
  expect_refused(*s.stub, isosurface_of(R"({"root": {"union": {"children": [
      {"intersection": {"children": [{"plane": {"normal": {"z": 1}}}, {"sphere": {"radius": 1}}]}},
      {"transform": {"translate": {"x": 3}, "child": {"gyroid": {"period": 1, "thickness": 0.1}}}}]}}})"),
                 bad,
                 "spec.isosurface.bounds are needed: spec.isosurface.scenes[0].root.union.children[1].transform."
                 "child.gyroid is unbounded");
  // Two sets of blobs tend to their iso (0.5) far away; a blend of radius 4 lowers that by 1 there.
  const std::string wide = R"({"root": {"union": {"blend": "BLEND_SMOOTH", "radius": 4, "children": [
      {"sphere": {"radius": 1}},
      {"blobs": {"points": [{"center": {"x": 2}, "radius": 1}]}},
      {"blobs": {"points": [{"center": {"x": -2}, "radius": 1}]}}]}}})";
  expect_refused(*s.stub, isosurface_of(wide), bad, "spec.isosurface.scenes[0].root.union is unbounded");
  expect_refused(*s.stub, isosurface_of(wide), bad, "spec.isosurface.scenes[0].root.union.children[1].blobs");
  v1::JobSpec bounded = isosurface_of(wide);
  auto* box = bounded.mutable_isosurface()->mutable_bounds();
  box->mutable_min()->set_x(-3), box->mutable_min()->set_y(-3), box->mutable_min()->set_z(-3);
  box->mutable_max()->set_x(3), box->mutable_max()->set_y(3), box->mutable_max()->set_z(3);
  std::string id;
  EXPECT_TRUE(submit(*s.stub, bounded, &id).ok());
  // A radius of 1 dips by at most 0.25 < 0.5: bounded.
  std::string narrow = wide;
  const std::string radius = "\"radius\": 4";
  narrow.replace(narrow.find(radius), radius.size(), "\"radius\": 1");
  EXPECT_TRUE(submit(*s.stub, isosurface_of(narrow), &id).ok());
}

// A sphere inside `levels` nested nodes, alternating unions and transforms.
v1::Scene nested_scene(int levels) {
  v1::Scene scene;
  v1::Node* node = scene.mutable_root();
  for (int i = 0; i < levels; ++i) {
    if (i % 2 == 0) {
      auto* csg = node->mutable_union_();
      csg->add_children()->mutable_sphere()->set_radius(0.5);
      node = csg->add_children();
    } else {
      auto* transform = node->mutable_transform();
      transform->mutable_translate()->set_x(0.01);
      node = transform->mutable_child();
    }
  }
  node->mutable_sphere()->set_radius(1);
  return scene;
}

TEST(SubmitChecks, ScenesNestedPastTheLimitGetOneMessageHoweverDeep) {
  LoopbackServer s;
  std::string id;
  // At the limit (the root plus 32 nested levels): accepted and run.
  ASSERT_TRUE(submit(*s.stub, isosurface_spec({nested_scene(wire::kMaxSceneDepth - 1)}, 16), &id).ok());
  EXPECT_EQ(watch_job(*s.stub, id).final_job.state(), v1::JOB_STATE_SUCCEEDED);
  // One level more, and far more than protobuf's parser takes (100 messages): the same message naming the limit.
  for (int levels : {wire::kMaxSceneDepth, 60, 2000}) {
    const grpc::Status status = submit(*s.stub, isosurface_spec({nested_scene(levels)}, 16), &id);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << levels << ": " << status.error_message();
    EXPECT_NE(status.error_message().find(wire::scene_too_deep()), std::string::npos) << status.error_message();
    EXPECT_NE(status.error_message().find("32 levels"), std::string::npos) << status.error_message();
  }
  // In a particles job's container too.
  v1::JobSpec spec;
  auto* particles = spec.mutable_particles();
  for (float v : {0.f, 0.f, 0.f}) particles->add_frames()->add_positions(v);
  particles->set_r_inner(0.1);
  *particles->mutable_container()->mutable_solid() = nested_scene(40);
  expect_refused(*s.stub, spec, grpc::StatusCode::INVALID_ARGUMENT,
                 "spec.particles.container.solid.root: " + wire::scene_too_deep());
  // Bytes that are no request at all.
  grpc::GenericStub generic(s.channel);
  grpc::ClientContext context;
  const std::string garbage = "\x0a\xff\xff\xff\x7f";
  grpc::Slice slice(garbage);
  grpc::ByteBuffer request(&slice, 1), response;
  std::promise<grpc::Status> done;
  generic.UnaryCall(&context, "/surfacer.v1.Surfacer/SubmitJob", grpc::StubOptions(), &request, &response,
                    [&done](grpc::Status status) { done.set_value(std::move(status)); });
  const grpc::Status status = done.get_future().get();
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(status.error_message().find("not a valid surfacer.v1.SubmitJobRequest"), std::string::npos)
      << status.error_message();
}

TEST(SubmitChecks, TextFieldsOverTheirLimitsAreRefusedAndNeverEchoed) {
  LoopbackServer s;
  const auto bad = grpc::StatusCode::INVALID_ARGUMENT;
  const std::string huge(3 << 20, 'n');  // brings the request near gRPC's 4 MiB
  auto spec = isosurface_of(R"({"root": {"sphere": {"radius": 1}}})");
  spec.set_name(huge);
  expect_refused(*s.stub, spec, bad, "spec.name is 3145728 bytes; the limit is 1024 bytes");
  spec.set_name(std::string(wire::kMaxNameBytes, 'n'));
  spec.mutable_isosurface()->mutable_scenes(0)->set_name(std::string(wire::kMaxNameBytes + 1, 's'));
  expect_refused(*s.stub, spec, bad, "spec.isosurface.scenes[0].name is 1025 bytes");
  auto grid = isosurface_of(R"({"root": {"grid": {"spacing": {"x": 1, "y": 1, "z": 1}, "nx": 2, "ny": 2, "nz": 2}}})");
  grid.mutable_isosurface()->mutable_scenes(0)->mutable_root()->mutable_grid()->set_upload_id(huge);
  expect_refused(*s.stub, grid, bad,
                 "spec.isosurface.scenes[0].root.grid.upload_id is 3145728 bytes; ids are at most 64");
  // A name at the limit is accepted, and so is every reply that carries it.
  std::string id;
  spec.mutable_isosurface()->mutable_scenes(0)->clear_name();
  ASSERT_TRUE(submit(*s.stub, spec, &id).ok());
  EXPECT_EQ(watch_job(*s.stub, id).final_job.name().size(), wire::kMaxNameBytes);

  // Ids in Get/Watch/Cancel: a huge one is refused without being echoed, an unknown one quoted short.
  for (const std::string& job_id : {huge, std::string(60, 'j')}) {
    grpc::Status status;
    get_job(*s.stub, job_id, &status);
    EXPECT_EQ(status.error_code(), job_id.size() > wire::kMaxIdBytes ? bad : grpc::StatusCode::NOT_FOUND);
    EXPECT_LT(status.error_message().size(), 200u) << status.error_message().substr(0, 300);
    const auto watched = watch_job(*s.stub, job_id);
    EXPECT_LT(watched.status.error_message().size(), 200u);
    EXPECT_FALSE(watched.status.ok());
    status = cancel_job(*s.stub, job_id);
    EXPECT_FALSE(status.ok());
    EXPECT_LT(status.error_message().size(), 200u);
  }
  // An unknown upload id is quoted short too.
  grid.mutable_isosurface()->mutable_scenes(0)->mutable_root()->mutable_grid()->set_upload_id(std::string(64, 'u'));
  const grpc::Status status = submit(*s.stub, grid, &id);
  EXPECT_EQ(status.error_code(), bad);
  EXPECT_LT(status.error_message().size(), 250u) << status.error_message();
}

std::vector<v1::Job> list_page(v1::Surfacer::Stub& stub, int page_size, const std::string& token, std::string* next,
                               grpc::Status* status = nullptr, std::vector<v1::JobState> states = {}) {
  grpc::ClientContext context;
  v1::ListJobsRequest request;
  request.set_page_size(page_size);
  request.set_page_token(token);
  for (v1::JobState state : states) request.add_states(state);
  v1::ListJobsResponse response;
  const grpc::Status s = stub.ListJobs(&context, request, &response);
  if (status) *status = s;
  if (next) *next = response.next_page_token();
  return {response.jobs().begin(), response.jobs().end()};
}

TEST(SubmitChecks, ListJobsComesInPagesOldestFirst) {
  LoopbackServer s;
  std::vector<std::string> ids;
  for (int i = 0; i < 7; ++i) {
    std::string id;
    ASSERT_TRUE(submit(*s.stub, isosurface_of(R"({"root": {"sphere": {"radius": 1}}})", 8), &id).ok());
    ids.push_back(id);
  }
  for (const auto& id : ids) watch_job(*s.stub, id);
  std::vector<std::string> seen;
  std::string token, next;
  int pages = 0;
  do {
    const auto jobs = list_page(*s.stub, 3, token, &next);
    EXPECT_LE(jobs.size(), 3u);
    for (const auto& job : jobs) seen.push_back(job.id());
    token = next;
    ++pages;
  } while (!token.empty() && pages < 10);
  EXPECT_EQ(pages, 3);
  EXPECT_EQ(seen, ids);
  // The default page holds them all; a filter pages the same way.
  EXPECT_EQ(list_page(*s.stub, 0, "", &next).size(), 7u);
  EXPECT_TRUE(next.empty());
  EXPECT_EQ(list_page(*s.stub, 5, "", &next, nullptr, {v1::JOB_STATE_SUCCEEDED}).size(), 5u);
  EXPECT_EQ(list_page(*s.stub, 5, next, &next, nullptr, {v1::JOB_STATE_SUCCEEDED}).size(), 2u);
  // Bad sizes and tokens.
  grpc::Status status;
  list_page(*s.stub, -1, "", &next, &status);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(status.error_message().find("page_size"), std::string::npos);
  list_page(*s.stub, 3, std::string(1 << 20, 't'), &next, &status);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(status.error_message().find("page_token"), std::string::npos);
  EXPECT_LT(status.error_message().size(), 200u);
}

TEST(SubmitChecks, GetServerInfoTellsTheLimitsBeforeAnythingIsSent) {
  auto options = LoopbackServer::default_options();
  options.limits.max_particles = 1234;
  options.limits.max_upload_bytes = 56789;
  options.limits.max_frames = 17;
  LoopbackServer s(options);
  grpc::ClientContext context;
  v1::ServerInfo info;
  ASSERT_TRUE(s.stub->GetServerInfo(&context, v1::GetServerInfoRequest(), &info).ok());
  EXPECT_FALSE(info.version().empty());
  const v1::ServerLimits& limits = info.limits();
  EXPECT_EQ(limits.max_particles(), 1234);
  EXPECT_EQ(limits.max_upload_bytes(), 56789);
  EXPECT_EQ(limits.max_frames(), 17);
  EXPECT_EQ(limits.max_grid_cells(), options.limits.max_grid_cells);
  EXPECT_EQ(limits.max_triangles(), options.limits.max_triangles);
  EXPECT_EQ(limits.max_chunk_bytes(), static_cast<int>(wire::kMaxChunkBytes));
  EXPECT_EQ(limits.max_name_bytes(), static_cast<int>(wire::kMaxNameBytes));
  EXPECT_EQ(limits.max_id_bytes(), static_cast<int>(wire::kMaxIdBytes));
  EXPECT_EQ(limits.max_scene_depth(), wire::kMaxSceneDepth);
  EXPECT_EQ(limits.max_list_page_size(), wire::kMaxListPageSize);
}

TEST(SubmitChecks, EveryJobTypeAndModeCountsItsFramesAgainstMaxFrames) {
  auto options = LoopbackServer::default_options();
  options.limits.max_frames = 4;
  LoopbackServer s(options);
  const auto over = grpc::StatusCode::RESOURCE_EXHAUSTED;
  auto spec_of = [](const std::string& json) {
    v1::JobSpec spec;
    EXPECT_TRUE(google::protobuf::util::JsonStringToMessage(json, &spec).ok()) << json;
    return spec;
  };
  const std::string sphere = R"({"root": {"sphere": {"radius": 0.4}}})";
  const std::string frame = R"({"positions": [0,0,0, 0.1,0,0, 0,0.1,0, 0,0,0.1]})";
  auto repeat = [](const std::string& item, int n) {
    std::string out;
    for (int i = 0; i < n; ++i) out += (i ? "," : "") + item;
    return out;
  };
  const std::vector<std::pair<std::string, std::string>> refused = {
      {R"({"isosurface": {"cells": 8, "scenes": [)" + repeat(sphere, 5) + "]}}", "spec.isosurface.scenes"},
      {R"({"particles": {"rInner": 0.06, "frames": [)" + repeat(frame, 5) + "]}}", "spec.particles.frames"},
      {R"({"optimize": {"scene": )" + sphere + R"(, "maxIterations": 1000000, "snapshotEvery": 1}})",
       "spec.optimize.snapshot_every"},
      {R"({"active": {"gridSpacing": 0.1, "coat": {"kernelRadius": 0.3, "frames": [)" + repeat(frame, 5) + "]}}}",
       "spec.active.coat.frames"},
      {R"({"active": {"gridSpacing": 0.1, "morph": {"from": )" + sphere + R"(, "to": )" + sphere +
           R"(, "maxFrames": 5}}})",
       "spec.active.morph.max_frames"},
      {R"({"active": {"gridSpacing": 0.1, "morph": {"from": )" + sphere + R"(, "to": )" + sphere + "}}}",
       "spec.active.morph.max_frames"},  // the default, 100
      {R"({"active": {"gridSpacing": 0.1, "advect": {"shape": )" + sphere +
           R"(, "enright": {}, "frameInterval": 0.01, "frames": 4}}})",
       "spec.active.advect.frames"},  // the initial frame and 4 more
  };
  for (const auto& [json, field] : refused) {
    std::string id;
    const grpc::Status status = submit(*s.stub, spec_of(json), &id);
    EXPECT_EQ(status.error_code(), over) << field << ": " << status.error_message();
    EXPECT_NE(status.error_message().find(field), std::string::npos) << status.error_message();
    EXPECT_NE(status.error_message().find("--max-frames"), std::string::npos) << status.error_message();
  }
  // At the limit: accepted, and no more frames than it come.
  for (const std::string& json : {R"({"isosurface": {"cells": 8, "scenes": [)" + repeat(sphere, 4) + "]}}",
                                  R"({"active": {"gridSpacing": 0.1, "advect": {"shape": )" + sphere +
                                      R"(, "enright": {}, "frameInterval": 0.01, "frames": 3}}})"}) {
    std::string id;
    ASSERT_TRUE(submit(*s.stub, spec_of(json), &id).ok()) << json;
    const auto result = watch_job(*s.stub, id);
    EXPECT_EQ(result.final_job.state(), v1::JOB_STATE_SUCCEEDED) << result.final_job.error().message();
    EXPECT_LE(result.frames.size(), 4u);
  }
}

}  // namespace
}  // namespace surfacer::testing
