// RunControl::triangles (core/util/triangle_limit.h): the polygonizers stop as soon as their triangles pass the
// limit, before building the rest of the mesh; the reservation hook always runs ahead of the triangles made and never
// past the limit; meshes within the limit are unchanged; the optimizer's subdivision obeys the limit; dense
// polygonization and red-green refinement cancel within a bound.
#include "core/util/triangle_limit.h"

#include <gtest/gtest.h>

#include <chrono>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "core/optimize/mesh_optimizer.h"
#include "core/optimize/refine.h"
#include "core/polygonize/polygonize.h"
#include "core/scene/scene.h"
#include "core/util/errors.h"
#include "core/util/run_control.h"
#include "tests/support/test_meshes.h"

namespace surfacer {
namespace {

using Clock = std::chrono::steady_clock;

// A gyroid sheet clipped to the unit sphere: its area grows as 1 / period, so fine periods make dense meshes.
FieldPtr gyroid_in_sphere(double period, double thickness) {
  return make_csg(CsgOp::kIntersection, {make_gyroid(period, thickness), make_sphere(Vec3::Zero(), 1.0)});
}

PolygonizeGrid grid_for(const Field& field, Polygonizer method, int cells) {
  PolygonizeOptions options;
  options.method = method;
  options.cells = cells;
  options.threads = 2;
  const FieldPtr fields[] = {std::shared_ptr<const Field>(&field, [](const Field*) {})};
  return resolve_grid(fields, options);
}

// A TriangleLimit whose hook records every count it is asked to cover.
struct RecordingLimit {
  TriangleLimit limit;
  std::mutex mutex;
  std::vector<std::int64_t> calls;
  explicit RecordingLimit(std::int64_t max) {
    limit.max_triangles = max;
    limit.name = "--test-limit";
    limit.reserve = [this](std::int64_t triangles) {
      std::lock_guard lock(mutex);
      calls.push_back(triangles);
    };
  }
};

// The count "stopped at N triangles" in a limit's message.
std::int64_t count_in(const std::string& message) {
  const auto at = message.find("stopped at ");
  return at == std::string::npos ? -1 : std::stoll(message.substr(at + 11));
}

struct LimitCase {
  Polygonizer method;
  double period, thickness;
  int cells;
  std::int64_t limit;
};

TEST(TriangleLimit, PolygonizersStopAsSoonAsTheyPassTheLimit) {
  const std::vector<LimitCase> cases = {
      {Polygonizer::kCubes, 0.1, 0.02, 200, 20'000},     {Polygonizer::kTiles, 0.1, 0.02, 200, 20'000},
      {Polygonizer::kCubes, 0.05, 0.01, 400, 100'000},   {Polygonizer::kTiles, 0.05, 0.01, 400, 100'000},
      {Polygonizer::kCubes, 0.02, 0.004, 1000, 100'000}, {Polygonizer::kTiles, 0.02, 0.004, 1000, 100'000},
      {Polygonizer::kCubes, 0.02, 0.004, 1000, 1'000},   {Polygonizer::kTiles, 0.02, 0.004, 1000, 300'000},
  };
  for (const LimitCase& c : cases) {
    SCOPED_TRACE(std::string(polygonizer_name(c.method)) + " cells " + std::to_string(c.cells) + " limit " +
                 std::to_string(c.limit));
    const FieldPtr field = gyroid_in_sphere(c.period, c.thickness);
    RecordingLimit recording(c.limit);
    RunControl control;
    control.triangles = &recording.limit;
    try {
      polygonize(*field, grid_for(*field, c.method, c.cells), control);
      ADD_FAILURE() << "no error past the limit";
    } catch (const Error& e) {
      const std::string message = e.what();
      EXPECT_EQ(e.kind(), ErrorKind::kResourceLimit) << message;
      EXPECT_EQ(e.field(), "--test-limit");
      EXPECT_NE(message.find("raise --test-limit"), std::string::npos) << message;
      EXPECT_NE(message.find(std::to_string(c.limit)), std::string::npos) << message;
      // Stopped right after passing it: at most a cell row (cubes) or a few blocks (tiles) beyond.
      const std::int64_t reached = count_in(message);
      EXPECT_GT(reached, c.limit) << message;
      EXPECT_LE(reached, c.limit + 100'000) << message;
    }
    ASSERT_FALSE(recording.calls.empty());
    for (std::size_t i = 0; i < recording.calls.size(); ++i) {
      EXPECT_LE(recording.calls[i], c.limit);
      if (i > 0) EXPECT_GT(recording.calls[i], recording.calls[i - 1]);
    }
  }
}

TEST(TriangleLimit, MeshesWithinTheLimitAreUnchangedAndCovered) {
  const FieldPtr field = gyroid_in_sphere(0.5, 0.1);
  for (const Polygonizer method : {Polygonizer::kCubes, Polygonizer::kTiles}) {
    for (const int cells : {24, 96}) {
      SCOPED_TRACE(std::string(polygonizer_name(method)) + " cells " + std::to_string(cells));
      const PolygonizeGrid grid = grid_for(*field, method, cells);
      const Mesh free = polygonize(*field, grid);
      const auto triangles = static_cast<std::int64_t>(free.triangles.size());
      ASSERT_GT(triangles, 0);
      RecordingLimit recording(triangles);  // exactly enough
      RunControl control;
      control.triangles = &recording.limit;
      const Mesh limited = polygonize(*field, grid, control);
      EXPECT_EQ(limited.vertices, free.vertices);
      ASSERT_EQ(limited.triangles.size(), free.triangles.size());
      EXPECT_TRUE(std::equal(limited.triangles.begin(), limited.triangles.end(), free.triangles.begin()));
      ASSERT_FALSE(recording.calls.empty());
      EXPECT_GE(recording.calls.back(), triangles);  // reserved before they were made
      EXPECT_LE(recording.calls.back(), triangles);  // and never past the limit
    }
  }
}

TEST(TriangleLimit, AHookThatRefusesStopsThePolygonizer) {
  const FieldPtr field = gyroid_in_sphere(0.05, 0.01);
  for (const Polygonizer method : {Polygonizer::kCubes, Polygonizer::kTiles}) {
    TriangleLimit limit;
    limit.max_triangles = std::int64_t{1} << 40;
    std::int64_t largest = 0;
    limit.reserve = [&](std::int64_t triangles) {
      if (triangles > 200'000) throw ResourceLimit("memory_budget", "no room for " + std::to_string(triangles));
      largest = std::max(largest, triangles);
    };
    RunControl control;
    control.triangles = &limit;
    try {
      polygonize(*field, grid_for(*field, method, 400), control);
      ADD_FAILURE() << polygonizer_name(method) << ": the refusal did not stop it";
    } catch (const Error& e) {
      EXPECT_EQ(e.field(), "memory_budget") << e.what();
    }
    EXPECT_GT(largest, 0);
  }
}

// The dense case without a limit: a cancel frees the caller within a generous bound (the contract says ~50 ms).
TEST(TriangleLimit, DensePolygonizationCancelsPromptly) {
  const FieldPtr field = gyroid_in_sphere(0.02, 0.004);
  for (const Polygonizer method : {Polygonizer::kCubes, Polygonizer::kTiles}) {
    CancelToken token;
    RunControl control;
    control.cancel = &token;
    std::thread canceller([&] {
      std::this_thread::sleep_for(std::chrono::milliseconds(150));
      token.cancel();
    });
    const auto start = Clock::now();
    bool cancelled = false;
    try {
      polygonize(*field, grid_for(*field, method, 1000), control);
    } catch (const Error& e) {
      cancelled = e.kind() == ErrorKind::kCancelled;
    }
    const double seconds = std::chrono::duration<double>(Clock::now() - start).count();
    canceller.join();
    EXPECT_TRUE(cancelled) << polygonizer_name(method);
    EXPECT_LT(seconds, 0.15 + 1.0) << polygonizer_name(method);
  }
}

// Subdivision under control.triangles alone caps rounds as triangle_budget does, with the same meshes.
TEST(TriangleLimit, OptimizerSubdivisionObeysTheLimit) {
  const FieldPtr field = make_torus(Vec3::Zero(), Vec3::UnitZ(), 0.6, 0.25);
  PolygonizeOptions start_options = default_start_polygonize();
  start_options.cells = 24;
  const FieldPtr fields[] = {field};
  const Mesh start = polygonize(*field, resolve_grid(fields, start_options));
  for (const std::int64_t extra : {300, 3000, 30000}) {
    const std::int64_t cap = static_cast<std::int64_t>(start.triangles.size()) + extra;
    MeshOptimizerOptions o;
    o.max_iterations = 16;
    o.subdivision_threshold = 1e-12;  // every triangle asks to be split
    o.subdivision_interval = 5;
    RecordingLimit recording(cap);
    RunControl control;
    control.triangles = &recording.limit;
    const Mesh limited = optimize_mesh(*field, start, o, {}, control);
    EXPECT_LE(static_cast<std::int64_t>(limited.triangles.size()), cap);
    EXPECT_GT(limited.triangles.size(), start.triangles.size());
    for (const std::int64_t call : recording.calls) EXPECT_LE(call, cap);
    o.triangle_budget = cap;
    const Mesh budgeted = optimize_mesh(*field, start, o);
    EXPECT_EQ(limited.vertices, budgeted.vertices);
    EXPECT_EQ(limited.triangles.size(), budgeted.triangles.size());
  }
}

// Red-green refinement of a large mesh, everything requested: a cancel lands inside it and frees the caller quickly.
TEST(TriangleLimit, RefinementCancelsPromptly) {
  Mesh mesh = testing::icosphere(8);  // 1.3 M triangles, split into 5.2 M
  optimizer_detail::RedGreenHierarchy hierarchy;
  hierarchy.reset(mesh.triangles.size());
  const std::vector<std::uint8_t> request(mesh.triangles.size(), 1);
  CancelToken token;
  RunControl control;
  control.cancel = &token;
  std::thread canceller([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    token.cancel();
  });
  const auto start = Clock::now();
  bool cancelled = false;
  try {
    optimizer_detail::refine_red_green(mesh.vertices, mesh.triangles, hierarchy, request, control);
  } catch (const Error& e) {
    cancelled = e.kind() == ErrorKind::kCancelled;
  }
  const double seconds = std::chrono::duration<double>(Clock::now() - start).count();
  canceller.join();
  EXPECT_TRUE(cancelled) << "the refinement ended before the cancel, in " << seconds << " s";
  EXPECT_LT(seconds, 0.1 + 1.0);
}

// A refinement whose result would not fit stops before building it and says so.
TEST(TriangleLimit, RefinementStopsBeforeBuildingPastTheLimit) {
  for (const std::int64_t spare : {0, 10, 100}) {
    Mesh mesh = testing::icosphere(3);
    const auto n = static_cast<std::int64_t>(mesh.triangles.size());
    optimizer_detail::RedGreenHierarchy hierarchy;
    hierarchy.reset(mesh.triangles.size());
    const std::vector<std::uint8_t> request(mesh.triangles.size(), 1);
    RecordingLimit recording(4 * n);
    RunControl control;
    control.triangles = &recording.limit;
    std::int64_t reserved = 0;
    EXPECT_FALSE(optimizer_detail::refine_red_green(mesh.vertices, mesh.triangles, hierarchy, request, control,
                                                    4 * n - 1 - spare, &reserved));
    EXPECT_TRUE(recording.calls.empty());  // nothing was built, so nothing reserved
    Mesh again = testing::icosphere(3);
    hierarchy.reset(again.triangles.size());
    EXPECT_TRUE(optimizer_detail::refine_red_green(again.vertices, again.triangles, hierarchy, request, control,
                                                   4 * n + spare, &reserved));
    EXPECT_EQ(static_cast<std::int64_t>(again.triangles.size()), 4 * n);
    ASSERT_EQ(recording.calls.size(), 1u);
    EXPECT_EQ(recording.calls[0], 4 * n);
    EXPECT_EQ(reserved, 4 * n);
  }
}

}  // namespace
}  // namespace surfacer
