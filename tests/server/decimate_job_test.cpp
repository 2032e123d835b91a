// The output option `decimate` through a real server on a loopback port: particle frames stay faithful and carry
// their interpolated attributes, isosurfaces lose triangles, bad values are refused naming the field.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "core/mesh/frame_codec.h"
#include "core/mesh/mesh_checks.h"
#include "tests/server/test_client.h"
#include "tests/support/mesh_expectations.h"
#include "tests/support/test_meshes.h"
#include "wire/output.h"

namespace surfacer::testing {
namespace {

// Particle ball of spacing d, jittered (particle_ball), as inline float32 positions of `frame` with a density
// attribute (attribute 0) that varies across the ball; returns the particles as stored.
std::vector<Vec3> add_ball(v1::ParticleFrame& frame, double radius, double d, unsigned seed) {
  std::vector<Vec3> points = particle_ball(Vec3::Zero(), radius, d, seed);
  for (Vec3& q : points) {
    q = q.cast<float>().cast<double>();
    for (int a = 0; a < 3; ++a) frame.add_positions(static_cast<float>(q[a]));
    frame.mutable_attributes(0)->add_values(static_cast<float>(1.0 + q.x()));
  }
  return points;
}

std::int64_t triangles_of(const v1::JobSpec& spec, LoopbackServer& s, v1::FrameStats* stats, Mesh* mesh) {
  std::string id;
  EXPECT_TRUE(submit(*s.stub, spec, &id).ok());
  const auto result = watch_job(*s.stub, id);
  EXPECT_EQ(result.states.back(), v1::JOB_STATE_SUCCEEDED) << result.final_job.error().message();
  if (result.frames.size() != 1) return -1;
  *stats = result.frames.at(0).header.stats();
  *mesh = decode_frame(result.frames.at(0).bytes, *wire::frame_codec(spec.output().encoding()), 1);
  return stats->triangles();
}

TEST(DecimateJob, ParticleFramesKeepEveryVertexFaithfulAndTheirAttributes) {
  LoopbackServer s;
  const double d = 0.05, r_inner = 0.03, r_outer = 0.06;
  v1::JobSpec spec;
  auto* job = spec.mutable_particles();
  auto* frame = job->add_frames();
  auto* density = frame->add_attributes();
  density->set_name("density");
  density->set_components(1);
  const std::vector<Vec3> particles = add_ball(*frame, 0.4, d, 5);
  job->set_r_inner(r_inner);
  job->set_r_outer(r_outer);
  job->set_min_angle_degrees(10.0);
  job->add_interpolate("density");
  spec.mutable_output()->set_encoding(v1::MESH_ENCODING_PLY);
  v1::FrameStats plain_stats, stats;
  Mesh plain, mesh;
  const std::int64_t before = triangles_of(spec, s, &plain_stats, &plain);
  spec.mutable_output()->set_decimate(0.1 * r_inner);
  const std::int64_t after = triangles_of(spec, s, &stats, &mesh);
  ASSERT_GT(after, 0);
  EXPECT_EQ(stats.metrics().at("triangles_before_decimate"), static_cast<double>(before));
  EXPECT_LT(after * 2, before);
  EXPECT_TRUE(std::any_of(stats.timings().begin(), stats.timings().end(),
                          [](const auto& t) { return t.stage() == "decimate"; }));
  EXPECT_FALSE(plain_stats.metrics().contains("triangles_before_decimate"));
  const MeshReport report = check_mesh(mesh);
  EXPECT_TRUE(mesh_has(report, kClosedManifold));
  EXPECT_GE(report.min_angle_degrees, 10.0 - 1e-6);
  // Every vertex in the band, and its density the one interpolated at that vertex without decimation.
  ASSERT_EQ(mesh.attributes.size(), 1u);
  ASSERT_EQ(mesh.attributes[0].count(), mesh.vertices.size());
  std::size_t unfaithful = 0, unmatched = 0;
  for (std::size_t v = 0; v < mesh.vertices.size(); ++v) {
    double nearest = std::numeric_limits<double>::infinity();
    for (const Vec3& p : particles) nearest = std::min(nearest, (p - mesh.vertices[v]).norm());
    if (nearest < r_inner * (1 - 1e-6) || nearest > r_outer * (1 + 1e-6)) ++unfaithful;
    const auto same = std::find(plain.vertices.begin(), plain.vertices.end(), mesh.vertices[v]);
    if (same == plain.vertices.end() ||
        plain.attributes[0].values[static_cast<std::size_t>(same - plain.vertices.begin())] !=
            mesh.attributes[0].values[v]) {
      ++unmatched;
    }
  }
  EXPECT_EQ(unfaithful, 0u);
  EXPECT_EQ(unmatched, 0u);
}

TEST(DecimateJob, IsosurfacesLoseTrianglesAndBadValuesNameTheField) {
  LoopbackServer s;
  v1::JobSpec spec = isosurface_spec({scene_from_json(R"({"root": {"sphere": {"radius": 1}}})")}, 48);
  v1::FrameStats stats;
  Mesh mesh;
  spec.mutable_output()->set_decimate(0.003);
  const std::int64_t after = triangles_of(spec, s, &stats, &mesh);
  EXPECT_LT(after * 3, static_cast<std::int64_t>(stats.metrics().at("triangles_before_decimate")));
  EXPECT_TRUE(mesh_has(check_mesh(mesh), kClosedManifold));
  for (const double bad : {-0.1, std::nan(""), std::numeric_limits<double>::infinity()}) {
    spec.mutable_output()->set_decimate(bad);
    const auto status = submit(*s.stub, spec, nullptr);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(status.error_message().find("spec.output.decimate"), std::string::npos) << status.error_message();
  }
}

}  // namespace
}  // namespace surfacer::testing
