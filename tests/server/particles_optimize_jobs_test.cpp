// The particles and optimize jobs through a real server on a loopback port.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <map>
#include <random>

#include "core/mesh/frame_codec.h"
#include "core/mesh/mesh_checks.h"
#include "core/mesh/mesh_codec.h"
#include "core/mesh/mesh_repair.h"
#include "tests/server/test_client.h"
#include "tests/support/mesh_expectations.h"
#include "tests/support/test_meshes.h"
#include "wire/output.h"

namespace surfacer::testing {
namespace {

std::string as_float32(const std::vector<Vec3>& points) {
  std::string bytes(points.size() * 3 * sizeof(float), '\0');
  auto* f = reinterpret_cast<float*>(bytes.data());
  for (std::size_t i = 0; i < points.size(); ++i) {
    f[3 * i] = static_cast<float>(points[i].x());
    f[3 * i + 1] = static_cast<float>(points[i].y());
    f[3 * i + 2] = static_cast<float>(points[i].z());
  }
  return bytes;
}

TEST(ParticlesJob, EachFrameIsAClosedSurfaceFaithfulToItsParticles) {
  LoopbackServer s;
  const double d = 0.05, r_inner = 0.05, r_outer = 0.1;
  std::vector<std::vector<Vec3>> frames = {particle_ball(Vec3(0, 0, 0), 0.3, d, 1),
                                           particle_ball(Vec3(0.2, 0, 0), 0.25, d, 2),
                                           particle_ball(Vec3(0, 0.1, 0), 0.35, d, 3)};
  v1::JobSpec spec;
  auto* job = spec.mutable_particles();
  for (const auto& f : frames) job->add_frames()->set_upload_id(upload(*s.stub, as_float32(f)));
  job->set_r_inner(r_inner);
  job->set_r_outer(r_outer);
  spec.mutable_output()->set_quantization_bits(16);
  std::string id;
  ASSERT_TRUE(submit(*s.stub, spec, &id).ok());
  const auto result = watch_job(*s.stub, id);
  ASSERT_EQ(result.states.back(), v1::JOB_STATE_SUCCEEDED) << result.final_job.error().message();
  ASSERT_EQ(result.frames.size(), 3u);
  for (int i = 0; i < 3; ++i) {
    SCOPED_TRACE(i);
    const auto& frame = result.frames.at(i);
    const Mesh mesh = decode_draco(frame.bytes);
    const auto report = check_mesh(mesh);
    EXPECT_TRUE(mesh_has(report, kClosed | kEdgeManifold | kOriented));
    EXPECT_EQ(report.components, 1);
    const auto& metrics = frame.header.stats().metrics();
    EXPECT_EQ(metrics.at("particles"), static_cast<double>(frames[i].size()));
    EXPECT_GE(metrics.at("initial_min_valence"), 5.0);
    EXPECT_GT(metrics.at("faithful_fraction"), 0.999);
    // Every final vertex is faithful (the polish ends with a projection), up to the 16-bit quantization.
    EXPECT_EQ(metrics.at("faithful_fraction_final"), 1.0);
    EXPECT_LE(metrics.at("max_violation_final"), 1e-3 * r_inner);
    const double tolerance = 1e-3 * r_inner + draco_max_error(Aabb::of(mesh.vertices), 16);
    for (const auto& v : mesh.vertices) {
      const double dist = nearest_point_distance(frames[i], v);
      EXPECT_GT(dist, r_inner - tolerance);
      EXPECT_LT(dist, r_outer + tolerance);
    }
    std::vector<std::string> stages;
    for (const auto& t : frame.header.stats().timings()) stages.push_back(t.stage());
    EXPECT_NE(std::find(stages.begin(), stages.end(), "bilaplacian"), stages.end());
  }
}

// Thin wavy sheets, one particle thick, from the default quantization down to a coarse one (10 bits: edges of 5-10 grid
// steps, where a repair by angles alone leaves zero-area triangles): the sliver repair knows the job's grid, so no
// decoded triangle has zero area, whatever the codec that quantizes. (At 9 bits some are left: the repair moves no
// vertex.)
TEST(ParticlesJob, NoTriangleCollapsesOnTheJobsQuantizationGrid) {
  LoopbackServer s;
  for (const int bits : {10, 12, 14}) {
    for (const auto encoding : {v1::MESH_ENCODING_DRACO, v1::MESH_ENCODING_MESHOPT}) {
      SCOPED_TRACE(v1::MeshEncoding_Name(encoding) + " at " + std::to_string(bits) + " bits");
      std::vector<Vec3> sheet;
      const double d = 0.01;
      for (int i = 0; i < 40; ++i)
        for (int j = 0; j < 40; ++j)
          sheet.emplace_back(i * d, j * d, 0.02 * std::sin(0.3 * i + 0.1 * bits) * std::cos(0.2 * j));
      v1::JobSpec spec;
      spec.mutable_particles()->add_frames()->set_upload_id(upload(*s.stub, as_float32(sheet)));
      spec.mutable_particles()->set_r_inner(0.5 * d);
      spec.mutable_output()->set_quantization_bits(bits);
      spec.mutable_output()->set_encoding(encoding);
      std::string id;
      ASSERT_TRUE(submit(*s.stub, spec, &id).ok());
      const auto result = watch_job(*s.stub, id);
      ASSERT_EQ(result.states.back(), v1::JOB_STATE_SUCCEEDED) << result.final_job.error().message();
      const auto& frame = result.frames.at(0);
      const Mesh mesh = decode_frame(frame.bytes, *wire::frame_codec(encoding), 2);
      ASSERT_GT(mesh.triangles.size(), 1000u);
      std::size_t zero_area = 0;
      for (const auto& t : mesh.triangles) {
        const Vec3 a = mesh.vertices[t[0]], b = mesh.vertices[t[1]], c = mesh.vertices[t[2]];
        zero_area += (b - a).cross(c - a).squaredNorm() == 0.0;
      }
      EXPECT_EQ(zero_area, 0u);
      EXPECT_TRUE(mesh_has(check_mesh(mesh), kClosed | kEdgeManifold | kOriented));
      EXPECT_EQ(frame.header.stats().metrics().at("slivers_left"), 0.0);
    }
  }
}

// slivers_left is what a reader finds: the triangles of the decoded frame with an angle below the job's
// min_angle_degrees, after the frame's grid cleanup and any decimation, on random clouds at coarse and fine grids.
// Decimation adds none: its new triangles keep the job's threshold (when above its own 10 degrees) on the grid.
TEST(ParticlesJob, SliversLeftCountsTheDecodedFramesTrianglesBelowTheThreshold) {
  LoopbackServer s;
  const double r_inner = 0.04;
  int with_slivers = 0;
  std::map<std::pair<double, int>, double> left_undecimated;  // by (threshold, bits), for the current seed
  for (const unsigned seed : {1u, 2u}) {
    std::mt19937 random(seed);
    std::uniform_real_distribution<double> coordinate(0.0, 0.5);
    std::vector<Vec3> cloud(400);
    for (Vec3& p : cloud) p = Vec3(coordinate(random), coordinate(random), coordinate(random));
    const std::string upload_id = upload(*s.stub, as_float32(cloud));
    for (const double threshold : {1.0, 10.0, 25.0}) {
      for (const double decimate : {0.0, 0.1 * r_inner}) {
        for (const int bits : {10, 14}) {
          SCOPED_TRACE("seed " + std::to_string(seed) + ", " + std::to_string(threshold) + " degrees, decimate " +
                       std::to_string(decimate) + ", " + std::to_string(bits) + " bits");
          v1::JobSpec spec;
          spec.mutable_particles()->add_frames()->set_upload_id(upload_id);
          spec.mutable_particles()->set_r_inner(r_inner);
          spec.mutable_particles()->set_min_angle_degrees(threshold);
          spec.mutable_output()->set_quantization_bits(bits);
          spec.mutable_output()->set_decimate(decimate);
          std::string id;
          ASSERT_TRUE(submit(*s.stub, spec, &id).ok());
          const auto result = watch_job(*s.stub, id);
          ASSERT_EQ(result.states.back(), v1::JOB_STATE_SUCCEEDED) << result.final_job.error().message();
          const auto& frame = result.frames.at(0);
          const Mesh mesh = decode_draco(frame.bytes);
          ASSERT_GT(mesh.triangles.size(), 1000u);
          // Counted here at a hair's breadth on either side of the threshold: the server's count lies between.
          std::int64_t below_less = 0, below_more = 0;
          for (const auto& t : mesh.triangles) {
            const double smallest = min_angle_degrees(mesh.vertices[t[0]], mesh.vertices[t[1]], mesh.vertices[t[2]]);
            below_less += smallest < threshold - 1e-9;
            below_more += smallest < threshold + 1e-9;
          }
          const double left = frame.header.stats().metrics().at("slivers_left");
          EXPECT_GE(left, static_cast<double>(below_less));
          EXPECT_LE(left, static_cast<double>(below_more));
          with_slivers += left > 0;
          if (decimate == 0.0) {
            left_undecimated[{threshold, bits}] = left;
          } else {
            EXPECT_LT(static_cast<double>(mesh.triangles.size()),
                      0.5 * frame.header.stats().metrics().at("triangles_before_decimate"));
            EXPECT_LE(left, left_undecimated.at({threshold, bits}));
          }
        }
      }
    }
  }
  EXPECT_GT(with_slivers, 0);  // the cases reach frames that keep some
}

TEST(ParticlesJob, DerivedRadiusKeepsTheSurfaceInsideTheQuantizationBox) {
  LoopbackServer s;
  // A plain cubic lattice ball: the derived r_inner is the lattice spacing, and the surface reaches r_outer beyond
  // the outermost particles, which the job's quantization box must hold.
  std::vector<Vec3> ball;
  for (int i = -5; i <= 5; ++i)
    for (int j = -5; j <= 5; ++j)
      for (int k = -5; k <= 5; ++k) {
        const Vec3 p = Vec3(i, j, k) * 0.05;
        if (p.norm() <= 0.25) ball.push_back(p);
      }
  v1::JobSpec spec;
  spec.mutable_particles()->add_frames()->set_upload_id(upload(*s.stub, as_float32(ball)));
  spec.mutable_particles()->set_derive_r_inner(true);
  std::string id;
  ASSERT_TRUE(submit(*s.stub, spec, &id).ok());
  const auto result = watch_job(*s.stub, id);
  ASSERT_EQ(result.states.back(), v1::JOB_STATE_SUCCEEDED) << result.final_job.error().message();
  EXPECT_NEAR(result.frames.at(0).header.stats().metrics().at("r_inner"), 0.05, 0.005);
  EXPECT_TRUE(check_mesh(decode_draco(result.frames.at(0).bytes)).closed);
}

// One particles job over an uploaded frame at r_inner, with `set` applied to its spec; its watched result.
template <class Set>
auto run_particles_job(LoopbackServer& s, const std::string& upload_id, double r_inner, Set&& set) {
  v1::JobSpec spec;
  spec.mutable_particles()->add_frames()->set_upload_id(upload_id);
  spec.mutable_particles()->set_r_inner(r_inner);
  set(*spec.mutable_particles());
  std::string id;
  EXPECT_TRUE(submit(*s.stub, spec, &id).ok());
  auto result = watch_job(*s.stub, id);
  EXPECT_EQ(result.frames.size(), 1u) << result.final_job.error().message();
  return result;
}

// The thesis' polish on request: without the final projection some vertices end outside the band, as reported;
// by default none does.
TEST(ParticlesJob, UnconstrainedPolishIsTheThesisPolish) {
  LoopbackServer s;
  const std::string ball = upload(*s.stub, as_float32(particle_ball(Vec3(0, 0, 0), 0.3, 0.05, 4)));
  auto faithful_final = [&](bool unconstrained) {
    const auto result = run_particles_job(s, ball, 0.05, [&](v1::ParticlesJob& job) {
      if (unconstrained) job.set_unconstrained_polish(true);
    });
    return result.frames.empty() ? -1.0 : result.frames.at(0).header.stats().metrics().at("faithful_fraction_final");
  };
  EXPECT_EQ(faithful_final(false), 1.0);
  EXPECT_LT(faithful_final(true), 1.0);
}

// The thesis' band on request: no cusp held, a fuller surface; by default the cusps of the r_outer spheres are held
// (the frame metric counts the vertices they lowered).
TEST(ParticlesJob, VertexOnlyBandIsTheThesisBand) {
  LoopbackServer s;
  const std::string ball = upload(*s.stub, as_float32(particle_ball(Vec3(0, 0, 0), 0.3, 0.05, 4)));
  const auto held = run_particles_job(s, ball, 0.03, [](v1::ParticlesJob&) {});
  const auto thesis = run_particles_job(s, ball, 0.03, [](v1::ParticlesJob& job) { job.set_vertex_only_band(true); });
  ASSERT_EQ(held.frames.size(), 1u);
  ASSERT_EQ(thesis.frames.size(), 1u);
  const auto& held_metrics = held.frames.at(0).header.stats().metrics();
  const auto& thesis_metrics = thesis.frames.at(0).header.stats().metrics();
  EXPECT_GT(held_metrics.at("cusp_vertices"), 0.0);
  EXPECT_EQ(thesis_metrics.at("cusp_vertices"), 0.0);
  EXPECT_EQ(held_metrics.at("faithful_fraction_final"), 1.0);
  EXPECT_EQ(thesis_metrics.at("faithful_fraction_final"), 1.0);
  EXPECT_LT(check_mesh(decode_draco(held.frames.at(0).bytes)).volume,
            check_mesh(decode_draco(thesis.frames.at(0).bytes)).volume);
}

TEST(ParticlesJob, BadParticlesAndOptionsNameTheField) {
  server::ServerOptions options = LoopbackServer::default_options();
  options.limits.max_particles = 100;
  LoopbackServer s(options);
  auto expect = [&](const v1::JobSpec& spec, grpc::StatusCode code, const std::string& mention) {
    const auto status = submit(*s.stub, spec, nullptr);
    EXPECT_EQ(status.error_code(), code) << status.error_message();
    EXPECT_NE(status.error_message().find(mention), std::string::npos) << status.error_message();
  };
  v1::JobSpec spec;
  auto* frame = spec.mutable_particles()->add_frames();
  for (float v : {0.f, 0.f, 0.f, 0.1f, 0.f, std::nanf("")}) frame->add_positions(v);
  spec.mutable_particles()->set_r_inner(0.05);
  expect(spec, grpc::StatusCode::INVALID_ARGUMENT, "spec.particles.frames[0]");

  frame->clear_positions();
  for (float v : {0.f, 0.f, 0.f, 0.1f, 0.f, 0.f}) frame->add_positions(v);
  spec.mutable_particles()->set_r_outer(0.01);  // below r_inner
  expect(spec, grpc::StatusCode::INVALID_ARGUMENT, "r_outer");

  spec.mutable_particles()->clear_r_outer();
  spec.mutable_particles()->clear_r_inner();  // neither r_inner nor derive_r_inner
  expect(spec, grpc::StatusCode::INVALID_ARGUMENT, "r_inner");

  spec.mutable_particles()->set_r_inner(0.05);
  for (const double angle : {-1.0, 31.0, std::nan("")}) {
    spec.mutable_particles()->set_min_angle_degrees(angle);
    expect(spec, grpc::StatusCode::INVALID_ARGUMENT, "spec.particles.min_angle_degrees");
  }
  spec.mutable_particles()->clear_min_angle_degrees();
  frame->clear_positions();
  for (int i = 0; i < 3 * 101; ++i) frame->add_positions(static_cast<float>(i));
  expect(spec, grpc::StatusCode::RESOURCE_EXHAUSTED, "--max-particles");

  // derive_r_inner with particles that all coincide (or one particle): refused at submit, naming the frame, not
  // failed later with a zero cell size.
  spec.mutable_particles()->clear_r_inner();
  spec.mutable_particles()->set_derive_r_inner(true);
  for (const int n : {1, 2, 50}) {
    frame->clear_positions();
    for (int i = 0; i < 3 * n; ++i) frame->add_positions(0.25f);
    expect(spec, grpc::StatusCode::INVALID_ARGUMENT, "spec.particles.frames[0]");
    expect(spec, grpc::StatusCode::INVALID_ARGUMENT, "set r_inner");
  }
  spec.mutable_particles()->set_derive_r_inner(false);
  spec.mutable_particles()->set_r_inner(0.05);

  frame->clear_positions();
  frame->set_upload_id(upload(*s.stub, std::string(10, 'x')));  // not whole float32 records
  expect(spec, grpc::StatusCode::INVALID_ARGUMENT, "upload_id");
}

// Uploaded records x y z, velocity (3) and density (1): the attributes named by interpolate come back as vertex
// attributes of the frames in every encoding (the default Draco, Draco pieces, meshopt, raw PLY), a constant density
// exactly, the velocity (linear in x) within r_outer x |grad|, and the same values, bit for bit, in each.
TEST(ParticlesJob, InterpolatedAttributesTravelInEveryEncoding) {
  LoopbackServer s;
  const double r_inner = 0.05, r_outer = 0.1;
  const std::vector<Vec3> ball = particle_ball(Vec3(0, 0, 0), 0.3, 0.05, 4);
  std::string bytes;
  auto put = [&](double v) {
    const float f = static_cast<float>(v);
    bytes.append(reinterpret_cast<const char*>(&f), sizeof f);
  };
  for (const Vec3& p : ball) {
    for (int a = 0; a < 3; ++a) put(p[a]);
    put(3.0 * p.x());
    put(0.0);
    put(-1.0);
    put(997.0);
  }
  v1::JobSpec spec;
  auto* job = spec.mutable_particles();
  auto* frame = job->add_frames();
  frame->set_upload_id(upload(*s.stub, bytes));
  auto* velocity = frame->add_attributes();
  velocity->set_name("velocity");
  velocity->set_components(3);
  auto* density = frame->add_attributes();
  density->set_name("density");
  density->set_components(1);
  job->set_r_inner(r_inner);
  job->set_r_outer(r_outer);
  job->add_interpolate("density");
  job->add_interpolate("velocity");
  // One quantization grid, given: the raw frame's values at each of its points, which every other encoding must give
  // back at that point.
  auto* bounds = spec.mutable_output()->mutable_quantization_bounds();
  for (auto* corner : {bounds->mutable_min(), bounds->mutable_max()}) {
    const double c = corner == bounds->mutable_min() ? -1.0 : 1.0;
    corner->set_x(c);
    corner->set_y(c);
    corner->set_z(c);
  }
  spec.mutable_output()->set_quantization_bits(14);
  const QuantizationGrid grid = QuantizationGrid::of(Aabb{Vec3::Constant(-1), Vec3::Constant(1)}, 14);
  std::map<std::array<std::uint32_t, 3>, std::vector<float>> raw;
  for (const v1::MeshEncoding encoding : {v1::MESH_ENCODING_PLY, v1::MESH_ENCODING_UNSPECIFIED,
                                          v1::MESH_ENCODING_DRACO_PIECES, v1::MESH_ENCODING_MESHOPT}) {
    SCOPED_TRACE(v1::MeshEncoding_Name(encoding));
    spec.mutable_output()->set_encoding(encoding);
    std::string id;
    ASSERT_TRUE(submit(*s.stub, spec, &id).ok());
    const auto result = watch_job(*s.stub, id);
    ASSERT_EQ(result.states.back(), v1::JOB_STATE_SUCCEEDED) << result.final_job.error().message();
    const std::optional<FrameCodec> codec = wire::frame_codec(encoding);
    ASSERT_TRUE(codec);
    const Mesh mesh = decode_frame(result.frames.at(0).bytes, *codec, 1);
    ASSERT_EQ(mesh.attributes.size(), 2u);
    EXPECT_EQ(mesh.attributes[0].name, "density");  // in the order interpolate names them
    EXPECT_EQ(mesh.attributes[1].name, "velocity");
    ASSERT_EQ(mesh.attributes[0].count(), mesh.vertices.size());
    ASSERT_EQ(mesh.attributes[1].components, 3);
    ASSERT_EQ(mesh.attributes[1].count(), mesh.vertices.size());
    std::size_t matched = 0;
    for (std::size_t v = 0; v < mesh.vertices.size(); ++v) {
      ASSERT_EQ(mesh.attributes[0].values[v], 997.0f);
      EXPECT_LE(std::abs(mesh.attributes[1].values[3 * v] - 3.0 * mesh.vertices[v].x()), 3.0 * r_outer + 1e-4);
      ASSERT_EQ(mesh.attributes[1].values[3 * v + 2], -1.0f);
      const std::vector<float> values(mesh.attributes[1].values.begin() + 3 * v,
                                      mesh.attributes[1].values.begin() + 3 * v + 3);
      const auto point = grid.quantize(mesh.vertices[v]);
      if (encoding == v1::MESH_ENCODING_PLY) {
        raw[point] = values;
      } else if (const auto it = raw.find(point); it != raw.end()) {
        EXPECT_EQ(it->second, values) << "vertex " << v;
        ++matched;
      }
    }
    if (encoding != v1::MESH_ENCODING_PLY) EXPECT_GT(matched, mesh.vertices.size() / 2);
  }

  // A name the frame lacks names the frame and what it has; a record size that leaves out an attribute names it.
  job->add_interpolate("foam");
  const auto missing = submit(*s.stub, spec, nullptr);
  EXPECT_EQ(missing.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(missing.error_message().find("spec.particles.frames[0] has no attribute \"foam\""), std::string::npos)
      << missing.error_message();
  EXPECT_NE(missing.error_message().find("velocity, density"), std::string::npos) << missing.error_message();
  job->clear_interpolate();
  job->add_interpolate("all");
  // Components that make the records fail to divide the upload (28 bytes per particle as uploaded).
  for (const int c : {1, 2, 4}) {
    if (ball.size() * 7 % static_cast<std::size_t>(4 + c) != 0) {
      velocity->set_components(c);
      break;
    }
  }
  ASSERT_NE(velocity->components(), 3);
  const auto short_records = submit(*s.stub, spec, nullptr);
  EXPECT_EQ(short_records.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(short_records.error_message().find("attribute values"), std::string::npos) << short_records.error_message();
}

TEST(OptimizeJob, SphereToCubeSnapshotsConvergeAndStayManifold) {
  LoopbackServer s;
  v1::JobSpec spec;
  auto* job = spec.mutable_optimize();
  *job->mutable_scene() = scene_from_json(R"({"root": {"box": {"half_size": {"x": 1, "y": 1, "z": 1}}}})");
  // Start from a sphere: upload its Marching Cubes mesh as PLY.
  {
    v1::JobSpec sphere = isosurface_spec({scene_from_json(R"({"root": {"sphere": {"radius": 1.2}}})")}, 24);
    sphere.mutable_isosurface()->set_method(v1::POLYGONIZER_CUBES);
    sphere.mutable_output()->set_encoding(v1::MESH_ENCODING_PLY);
    std::string sphere_id;
    ASSERT_TRUE(submit(*s.stub, sphere, &sphere_id).ok());
    job->set_mesh_upload_id(upload(*s.stub, watch_job(*s.stub, sphere_id).frames.at(0).bytes));
  }
  job->set_max_iterations(60);
  job->set_snapshot_every(20);
  std::string id;
  const auto status = submit(*s.stub, spec, &id);
  ASSERT_TRUE(status.ok()) << status.error_message();
  const auto result = watch_job(*s.stub, id);
  ASSERT_EQ(result.states.back(), v1::JOB_STATE_SUCCEEDED) << result.final_job.error().message();
  ASSERT_GE(result.frames.size(), 4u);  // iterations 0, 20, 40, 60
  EXPECT_EQ(result.final_job.frames_total(), static_cast<int>(result.frames.size()));
  const auto& first = result.frames.at(0).header.stats();
  const auto& last = result.frames.at(static_cast<int>(result.frames.size()) - 1).header.stats();
  EXPECT_EQ(first.iteration(), 0);
  EXPECT_EQ(last.iteration(), 60);
  EXPECT_LT(last.metrics().at("e_d"), first.metrics().at("e_d") / 100.0);
  EXPECT_LT(last.metrics().at("e_n"), first.metrics().at("e_n"));
  for (const auto& [index, frame] : result.frames) {
    EXPECT_TRUE(mesh_has(check_mesh(decode_draco(frame.bytes)), kClosed | kEdgeManifold | kOriented))
        << "snapshot " << index;
  }
}

TEST(OptimizeJob, PolygonizedStartAndBadUploadErrors) {
  LoopbackServer s;
  v1::JobSpec spec;
  auto* job = spec.mutable_optimize();
  *job->mutable_scene() = scene_from_json(R"({"root": {"box": {"half_size": {"x": 1, "y": 0.5, "z": 0.5}}}})");
  job->mutable_polygonize()->set_cells(20);
  job->set_max_iterations(10);
  std::string id;
  ASSERT_TRUE(submit(*s.stub, spec, &id).ok());
  const auto result = watch_job(*s.stub, id);
  ASSERT_EQ(result.frames.size(), 1u);
  EXPECT_TRUE(check_mesh(decode_draco(result.frames.at(0).bytes)).closed);

  job->set_mesh_upload_id(upload(*s.stub, "ply\nthis is not a mesh\n"));
  const auto status = submit(*s.stub, spec, nullptr);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(status.error_message().find("spec.optimize.mesh_upload_id"), std::string::npos) << status.error_message();
}

}  // namespace
}  // namespace surfacer::testing
