#include "tests/support/mesh_expectations.h"

#include <algorithm>
#include <exception>
#include <sstream>

#include "core/mesh/mesh_io.h"
#include "tests/support/process.h"

namespace surfacer::testing {

void expect_same_topology(const MeshReport& a, const MeshReport& b, const std::string& what) {
  SCOPED_TRACE(what);
  EXPECT_EQ(a.closed, b.closed);
  EXPECT_EQ(a.edge_manifold, b.edge_manifold);
  EXPECT_EQ(a.vertex_manifold, b.vertex_manifold);
  EXPECT_EQ(a.oriented, b.oriented);
  EXPECT_EQ(a.euler_characteristic, b.euler_characteristic);
  EXPECT_EQ(a.components, b.components);
  EXPECT_EQ(a.boundary_edges, b.boundary_edges);
  EXPECT_EQ(a.non_manifold_edges, b.non_manifold_edges);
  EXPECT_EQ(a.valence_histogram, b.valence_histogram);
  EXPECT_EQ(a.min_valence, b.min_valence);
  EXPECT_EQ(a.max_valence, b.max_valence);
}

std::vector<std::array<std::array<std::uint32_t, 3>, 3>> quantized_triangles(const Mesh& m,
                                                                             const QuantizationGrid& grid) {
  using GridPoint = std::array<std::uint32_t, 3>;
  std::vector<std::array<GridPoint, 3>> out;
  for (const Triangle& t : m.triangles) {
    if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) continue;
    std::array<GridPoint, 3> q = {grid.quantize(m.vertices[t[0]]), grid.quantize(m.vertices[t[1]]),
                                  grid.quantize(m.vertices[t[2]])};
    std::array<GridPoint, 3> best = q;
    for (int r = 1; r < 3; ++r) {
      std::rotate(q.begin(), q.begin() + 1, q.end());
      best = std::min(best, q);
    }
    out.push_back(best);
  }
  std::sort(out.begin(), out.end());
  return out;
}

namespace fs = std::filesystem;

::testing::AssertionResult mesh_has(const MeshReport& r, unsigned properties, int min_valence) {
  std::ostringstream failed;
  auto require = [&](unsigned property, bool holds, const auto& what) {
    if ((properties & property) != 0 && !holds) failed << (failed.tellp() > 0 ? "; " : "") << what;
  };
  require(kClosed, r.closed, "not closed: " + std::to_string(r.boundary_edges) + " boundary edges");
  require(kOpen, !r.closed, "closed: no boundary edge");
  require(kEdgeManifold, r.edge_manifold,
          "not edge-manifold: " + std::to_string(r.non_manifold_edges) + " edges with more than two triangles");
  require(kVertexManifold, r.vertex_manifold, "not vertex-manifold");
  require(kOriented, r.oriented, "not oriented");
  require(kNoDegenerateTriangles, r.degenerate_triangles == 0,
          std::to_string(r.degenerate_triangles) + " degenerate triangles");
  require(kPositiveVolume, r.volume > 0.0, "volume " + std::to_string(r.volume) + " not positive");
  if (r.min_valence < min_valence) {
    failed << (failed.tellp() > 0 ? "; " : "") << "minimum valence " << r.min_valence << " below " << min_valence;
  }
  if (failed.tellp() == 0) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << failed.str() << " (Euler characteristic " << r.euler_characteristic << ", "
                                       << r.components << " components)";
}

::testing::AssertionResult mesh_file_has(const fs::path& file, unsigned properties, MeshReport* report) {
  Mesh mesh;
  try {
    mesh = read_mesh(file);
  } catch (const std::exception& e) {
    return ::testing::AssertionFailure() << file << ": " << e.what();
  }
  if (mesh.triangles.empty()) return ::testing::AssertionFailure() << file << ": no triangles";
  const MeshReport r = check_mesh(mesh);
  if (report) *report = r;
  ::testing::AssertionResult result = mesh_has(r, properties);
  if (!result) return ::testing::AssertionFailure() << file << ": " << result.message();
  return result;
}

::testing::AssertionResult normals_point_away_from(const Mesh& mesh, const Vec3& center, double length_tolerance,
                                                   double min_cosine) {
  if (mesh.normals.size() != mesh.vertices.size()) {
    return ::testing::AssertionFailure() << mesh.normals.size() << " normals for " << mesh.vertices.size()
                                         << " vertices";
  }
  for (std::size_t v = 0; v < mesh.vertices.size(); ++v) {
    const double length = mesh.normals[v].norm();
    const double cosine = mesh.normals[v].dot((mesh.vertices[v] - center).normalized());
    if (!(std::abs(length - 1.0) <= length_tolerance) || !(cosine > min_cosine)) {
      return ::testing::AssertionFailure()
             << "vertex " << v << " at " << mesh.vertices[v].transpose() << ": normal " << mesh.normals[v].transpose()
             << " of length " << length << ", cosine " << cosine << " with the outward direction";
    }
  }
  return ::testing::AssertionSuccess();
}

::testing::AssertionResult draco_decoder_decodes(const fs::path& drc, const fs::path& ply) {
  const fs::path log = ply.string() + ".log";
  const ProcessResult r = run_process({"/usr/bin/draco_decoder", "-i", drc.string(), "-o", ply.string()}, log,
                                      ply.string() + ".err", std::chrono::seconds(60));
  if (r.code == 0) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << "draco_decoder -i " << drc << " -o " << ply << ": " << r;
}

}  // namespace surfacer::testing
