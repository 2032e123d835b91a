// What the CLI writes besides frames: metrics columns in stats.csv, iterations.csv for optimize jobs, and the
// particles summary table.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "client/frame_writer.h"
#include "client/progress.h"
#include "client/summary.h"
#include "core/mesh/mesh_io.h"
#include "tests/support/files.h"

namespace surfacer::client {
namespace {

namespace fs = std::filesystem;
using surfacer::testing::fresh_temp_dir;
using surfacer::testing::read_file;

std::vector<std::string> lines_of(const std::string& text) {
  std::vector<std::string> lines;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) lines.push_back(line);
  return lines;
}

v1::FrameStats snapshot(int iteration, std::int64_t triangles, std::map<std::string, double> metrics) {
  v1::FrameStats s;
  s.set_iteration(iteration);
  s.set_triangles(triangles);
  s.set_vertices(triangles / 2 + 2);
  for (const auto& [k, v] : metrics) (*s.mutable_metrics())[k] = v;
  auto* t = s.add_timings();
  t->set_stage("optimize");
  t->set_seconds(0.5);
  return s;
}

TEST(OutputFiles, IterationsCsvOneRowPerSnapshotWithEveryMetricSorted) {
  std::map<int, v1::FrameStats> stats;
  stats[1] = snapshot(5, 900, {{"e_n", 0.02}, {"e_d", 1e-4}, {"max_distance", 0.01}});
  stats[0] = snapshot(0, 800, {{"e_d", 2.5e-3}, {"e_n", 0.125}, {"rms_distance", 0.004}});
  stats[2] = snapshot(10, 1000, {{"min_angle_degrees", 31.5}, {"e_d", 1.25e-6}});
  const auto lines = lines_of(iterations_csv(stats));
  ASSERT_EQ(lines.size(), 4u);
  EXPECT_EQ(lines[0], "frame,iteration,triangles,e_d,e_n,max_distance,min_angle_degrees,rms_distance");
  EXPECT_EQ(lines[1], "0,0,800,0.0025,0.125,,,0.004");
  EXPECT_EQ(lines[2], "1,5,900,0.0001,0.02,0.01,,");
  EXPECT_EQ(lines[3], "2,10,1000,1.25e-06,,,31.5,");
}

TEST(OutputFiles, StatsCsvGetsMetricColumnsAfterTheTimings) {
  std::map<int, v1::FrameStats> stats;
  stats[0] = snapshot(0, 10, {{"volume", 4.18}, {"active_nodes", 1200}});
  stats[1] = snapshot(0, 12, {{"particles", 5000}});
  const auto lines = lines_of(stats_csv(stats));
  ASSERT_EQ(lines.size(), 3u);
  EXPECT_EQ(lines[0],
            "frame,vertices,triangles,closed,manifold,euler,components,min_valence,min_angle,area,volume,optimize_s,"
            "total_s,active_nodes,particles,metric_volume");
  EXPECT_NE(lines[1].find(",0.500000,0.500000,1200,,4.18"), std::string::npos) << lines[1];
  EXPECT_NE(lines[2].find(",0.500000,0.500000,,5000,"), std::string::npos) << lines[2];
  // No metrics: the columns are as before.
  std::map<int, v1::FrameStats> plain;
  plain[0].set_triangles(3);
  EXPECT_EQ(lines_of(stats_csv(plain))[0],
            "frame,vertices,triangles,closed,manifold,euler,components,min_valence,min_angle,area,volume,total_s");
}

// A frame of a tetrahedron in lossless PLY, with the given stats.
ReceivedFrame tetra_frame(int index, const v1::FrameStats& stats) {
  Mesh mesh;
  mesh.vertices = {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, 1)};
  mesh.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  ReceivedFrame frame;
  frame.index = index;
  frame.encoding = v1::MESH_ENCODING_PLY;
  frame.bytes = write_ply(mesh, true);
  frame.stats = stats;
  return frame;
}

TEST(OutputFiles, WriterRewritesIterationsCsvForOptimizeJobsOnly) {
  const fs::path dir = fresh_temp_dir("outputs");
  {
    FrameWriter writer(FrameOutputOptions{dir / "opt", {}});
    writer.set_job_kind("optimize");
    writer.write(tetra_frame(1, snapshot(5, 4, {{"e_d", 0.5}})));
    EXPECT_EQ(lines_of(read_file(dir / "opt" / "iterations.csv")).size(), 2u);
    writer.write(tetra_frame(0, snapshot(0, 4, {{"e_d", 1.0}, {"e_n", 0.25}})));
    const auto lines = lines_of(read_file(dir / "opt" / "iterations.csv"));
    ASSERT_EQ(lines.size(), 3u);
    EXPECT_EQ(lines[0], "frame,iteration,triangles,e_d,e_n");
    EXPECT_EQ(lines[1], "0,0,4,1,0.25");
    EXPECT_EQ(lines[2], "1,5,4,0.5,");
    EXPECT_TRUE(writer.wrote_iterations());
    EXPECT_EQ(writer.stats().size(), 2u);
  }
  {
    FrameWriter writer(FrameOutputOptions{dir / "iso", {}});
    writer.set_job_kind("isosurface");
    writer.write(tetra_frame(0, snapshot(0, 4, {})));
    EXPECT_FALSE(fs::exists(dir / "iso" / "iterations.csv"));
    EXPECT_FALSE(writer.wrote_iterations());
    EXPECT_TRUE(fs::exists(dir / "iso" / "stats.csv"));
  }
  fs::remove_all(dir);
}

TEST(OutputFiles, FrameLineShowsIterationAndKeyMetrics) {
  ReceivedFrame frame;
  frame.index = 2;
  frame.stats = snapshot(10, 8312, {{"e_d", 1.25e-7}, {"e_n", 0.0031}, {"rms_distance", 0.1}});
  frame.stats.mutable_check()->set_closed(true);
  frame.stats.mutable_check()->set_edge_manifold(true);
  frame.stats.mutable_check()->set_vertex_manifold(true);
  EXPECT_EQ(frame_summary(frame, 0), "frame 2: 8312 triangles, closed, iteration 10, e_d 1.25e-07, e_n 0.0031, 0.50 s");
  frame.stats = snapshot(0, 10, {{"particles", 5000}});
  frame.stats.mutable_check()->set_boundary_edges(3);
  EXPECT_EQ(frame_summary(frame, 4),
            "frame 2/4: 10 triangles, open (3 boundary edges), non-manifold, particles 5000, 0.50 s");
}

TEST(OutputFiles, ParticlesSummaryTable) {
  std::map<int, v1::FrameStats> stats;
  stats[0] = snapshot(0, 2000, {{"particles", 12000}});
  stats[1] = snapshot(0, 3000, {});  // no metric: the uploaded count
  stats[1].mutable_timings(0)->set_seconds(1.5);
  const std::string table = particles_summary_table(stats, {{1, 15000}}, 4.0);
  const auto lines = lines_of(table);
  ASSERT_EQ(lines.size(), 5u) << table;
  EXPECT_EQ(lines[0], "frame  particles  triangles  seconds");
  EXPECT_EQ(lines[1], "    0      12000       2000    0.500");
  EXPECT_EQ(lines[2], "    1      15000       3000    1.500");
  EXPECT_EQ(lines[3], "total      27000       5000    2.000");
  EXPECT_EQ(lines[4], "2 frames, 1.000 s per frame on the server, 2.000 s per frame wall-clock (4.0 s in all)");

  const std::string unknown = particles_summary_table(stats, {}, 0);
  EXPECT_NE(unknown.find("    1          -       3000"), std::string::npos) << unknown;
  EXPECT_NE(unknown.find("total          -"), std::string::npos) << unknown;
}

}  // namespace
}  // namespace surfacer::client
