#include "tests/support/test_meshes.h"

#include <Eigen/Geometry>
#include <cmath>
#include <limits>
#include <map>
#include <numbers>
#include <random>
#include <unordered_map>
#include <utility>

#include "core/mesh/mesh_codec.h"
#include "core/mesh/mesh_gltf.h"
#include "core/util/format.h"

namespace surfacer::testing {

Mesh unit_cube() {
  Mesh m;
  for (int c = 0; c < 8; ++c) m.vertices.emplace_back(c & 1, (c >> 1) & 1, (c >> 2) & 1);
  // Corner c = (x, y, z) bits. Faces x=0, y=0, z=0 split through corner 0; x=1, y=1, z=1 through corner 7.
  m.triangles = {
      {0, 4, 6}, {0, 6, 2},  // x = 0 (normal -x)
      {0, 1, 5}, {0, 5, 4},  // y = 0 (normal -y)
      {0, 2, 3}, {0, 3, 1},  // z = 0 (normal -z)
      {7, 5, 1}, {7, 1, 3},  // x = 1 (normal +x)
      {7, 3, 2}, {7, 2, 6},  // y = 1 (normal +y)
      {7, 6, 4}, {7, 4, 5},  // z = 1 (normal +z)
  };
  return m;
}

Mesh icosphere(int subdivisions, double radius, const Vec3& center) {
  const double t = (1.0 + std::sqrt(5.0)) / 2.0;
  std::vector<Vec3> v = {{-1, t, 0},  {1, t, 0},  {-1, -t, 0}, {1, -t, 0}, {0, -1, t},  {0, 1, t},
                         {0, -1, -t}, {0, 1, -t}, {t, 0, -1},  {t, 0, 1},  {-t, 0, -1}, {-t, 0, 1}};
  for (Vec3& p : v) p.normalize();
  std::vector<Triangle> f = {{0, 11, 5},  {0, 5, 1},  {0, 1, 7},  {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
                             {11, 10, 2}, {10, 7, 6}, {7, 1, 8},  {3, 9, 4},  {3, 4, 2},   {3, 2, 6}, {3, 6, 8},
                             {3, 8, 9},   {4, 9, 5},  {2, 4, 11}, {6, 2, 10}, {8, 6, 7},   {9, 8, 1}};
  for (int s = 0; s < subdivisions; ++s) {
    std::map<std::pair<std::uint32_t, std::uint32_t>, std::uint32_t> mid;
    auto midpoint = [&](std::uint32_t a, std::uint32_t b) {
      const auto key = std::minmax(a, b);
      auto it = mid.find(key);
      if (it != mid.end()) return it->second;
      v.push_back((v[a] + v[b]).normalized());
      const auto id = static_cast<std::uint32_t>(v.size() - 1);
      mid.emplace(key, id);
      return id;
    };
    std::vector<Triangle> next;
    next.reserve(f.size() * 4);
    for (const Triangle& tri : f) {
      const std::uint32_t a = midpoint(tri[0], tri[1]), b = midpoint(tri[1], tri[2]), c = midpoint(tri[2], tri[0]);
      next.push_back({tri[0], a, c});
      next.push_back({tri[1], b, a});
      next.push_back({tri[2], c, b});
      next.push_back({a, b, c});
    }
    f = std::move(next);
  }
  Mesh m;
  m.vertices.reserve(v.size());
  for (const Vec3& p : v) m.vertices.push_back(center + radius * p);
  m.triangles = std::move(f);
  return m;
}

Mesh torus_mesh(double major_radius, double minor_radius, int major_segments, int minor_segments, const Vec3& center) {
  Mesh m;
  const double two_pi = 2.0 * std::acos(-1.0);
  for (int i = 0; i < major_segments; ++i) {
    const double u = two_pi * i / major_segments;
    for (int j = 0; j < minor_segments; ++j) {
      const double w = two_pi * j / minor_segments;
      const double rho = major_radius + minor_radius * std::cos(w);
      m.vertices.push_back(center + Vec3(rho * std::cos(u), rho * std::sin(u), minor_radius * std::sin(w)));
    }
  }
  auto id = [&](int i, int j) {
    return static_cast<std::uint32_t>((i % major_segments) * minor_segments + (j % minor_segments));
  };
  for (int i = 0; i < major_segments; ++i) {
    for (int j = 0; j < minor_segments; ++j) {
      // Outward: d/du x d/dw points away from the tube axis.
      m.triangles.push_back({id(i, j), id(i + 1, j), id(i + 1, j + 1)});
      m.triangles.push_back({id(i, j), id(i + 1, j + 1), id(i, j + 1)});
    }
  }
  return m;
}

Mesh open_square() {
  Mesh m;
  m.vertices = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
  m.triangles = {{0, 1, 2}, {0, 2, 3}};
  return m;
}

Mesh non_manifold_edge() {
  Mesh m;
  m.vertices = {{0, 0, 0}, {1, 0, 0}, {0.5, 1, 0}, {0.5, -1, 0}, {0.5, 0, 1}};
  m.triangles = {{0, 1, 2}, {1, 0, 3}, {0, 1, 4}};
  return m;
}

Mesh bowtie() {
  Mesh m;
  m.vertices = {{0, 0, 0}, {1, 1, 0}, {1, 0, 0}, {1, -1, 0}, {-1, 1, 0}, {-1, 0, 0}, {-1, -1, 0}};
  m.triangles = {{0, 3, 2}, {0, 2, 1}, {0, 4, 5}, {0, 5, 6}};
  return m;
}

Mesh double_tetrahedron() {
  Mesh m;
  // Tetrahedron with apex 0 at the origin pointing up, and its mirror image pointing down.
  m.vertices = {{0, 0, 0}, {1, 0, 1}, {-0.5, 0.8, 1}, {-0.5, -0.8, 1}, {1, 0, -1}, {-0.5, 0.8, -1}, {-0.5, -0.8, -1}};
  m.triangles = {{0, 2, 1}, {0, 3, 2}, {0, 1, 3}, {1, 2, 3},   // upper, cap normal +z
                 {0, 4, 5}, {0, 5, 6}, {0, 6, 4}, {4, 6, 5}};  // lower, cap normal -z
  return m;
}

Mesh flipped_triangle() {
  Mesh m = icosphere(1);
  std::swap(m.triangles[0][1], m.triangles[0][2]);
  return m;
}

std::string draco_bomb(std::uint32_t faces) {
  DracoOptions options;
  options.speed = 5;  // edgebreaker, standard traversal
  const std::string valid = encode_draco(icosphere(1), options);
  // Header (11 bytes), traversal type (1), then varints: vertices, faces, a byte of attribute data, symbols,
  // split symbols (Draco bitstream 2.2).
  std::size_t at = 12;
  auto varint_end = [&](std::size_t i) {
    while (static_cast<unsigned char>(valid.at(i)) & 0x80) ++i;
    return i + 1;
  };
  auto varint = [](std::uint32_t v) {
    std::string out;
    for (; v >= 0x80; v >>= 7) out.push_back(static_cast<char>((v & 0x7f) | 0x80));
    out.push_back(static_cast<char>(v));
    return out;
  };
  const std::size_t vertices_end = varint_end(at);
  const std::size_t faces_end = varint_end(vertices_end);
  const std::size_t symbols_end = varint_end(faces_end + 1);
  std::string bomb = valid.substr(0, vertices_end) + varint(faces) + valid.at(faces_end) + varint(faces);
  return bomb + valid.substr(symbols_end);
}

double max_distance_to_sphere(const Mesh& mesh, const Vec3& center, double radius) {
  double d = 0.0;
  for (const Vec3& p : mesh.vertices) d = std::max(d, std::abs((p - center).norm() - radius));
  return d;
}

double max_distance_to_torus(const Mesh& mesh, const Vec3& center, double major_radius, double minor_radius) {
  double d = 0.0;
  for (const Vec3& p : mesh.vertices) {
    const Vec3 q = p - center;
    const double rho = std::hypot(q.x(), q.y()) - major_radius;
    d = std::max(d, std::abs(std::hypot(rho, q.z()) - minor_radius));
  }
  return d;
}

namespace {

struct CellKey {
  std::int64_t x, y, z;
  bool operator==(const CellKey& o) const { return x == o.x && y == o.y && z == o.z; }
};
struct CellHash {
  std::size_t operator()(const CellKey& k) const {
    return static_cast<std::size_t>(k.x * 73856093) ^ static_cast<std::size_t>(k.y * 19349663) ^
           static_cast<std::size_t>(k.z * 83492791);
  }
};

}  // namespace

double max_nearest_vertex_distance(const Mesh& from, const Mesh& to) {
  if (from.vertices.empty()) return 0.0;
  if (to.vertices.empty()) return std::numeric_limits<double>::infinity();
  Vec3 lo = to.vertices[0], hi = lo;
  for (const Vec3& p : to.vertices) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  // About 2 points per cell on average for a surface mesh.
  const double extent = std::max((hi - lo).maxCoeff(), 1e-12);
  const double cell = extent / std::max(1.0, std::sqrt(static_cast<double>(to.vertices.size()) / 2.0));
  std::unordered_map<CellKey, std::vector<std::uint32_t>, CellHash> grid;
  auto key_of = [&](const Vec3& p) {
    return CellKey{static_cast<std::int64_t>(std::floor((p.x() - lo.x()) / cell)),
                   static_cast<std::int64_t>(std::floor((p.y() - lo.y()) / cell)),
                   static_cast<std::int64_t>(std::floor((p.z() - lo.z()) / cell))};
  };
  for (std::size_t i = 0; i < to.vertices.size(); ++i)
    grid[key_of(to.vertices[i])].push_back(static_cast<std::uint32_t>(i));
  double worst = 0.0;
  for (const Vec3& p : from.vertices) {
    const CellKey k = key_of(p);
    double best = std::numeric_limits<double>::infinity();
    // Grow the searched shell until the best distance found is certainly the nearest.
    for (std::int64_t r = 0;; ++r) {
      for (std::int64_t dx = -r; dx <= r; ++dx) {
        for (std::int64_t dy = -r; dy <= r; ++dy) {
          for (std::int64_t dz = -r; dz <= r; ++dz) {
            if (std::max({std::abs(dx), std::abs(dy), std::abs(dz)}) != r) continue;
            auto it = grid.find(CellKey{k.x + dx, k.y + dy, k.z + dz});
            if (it == grid.end()) continue;
            for (std::uint32_t i : it->second) best = std::min(best, (to.vertices[i] - p).norm());
          }
        }
      }
      if (best <= r * cell) break;
      if (r > 4 && r * cell > 4.0 * extent + (p - lo).norm()) break;  // far outside: everything was visited
    }
    worst = std::max(worst, best);
  }
  return worst;
}

std::optional<std::size_t> nearest_vertex(const Mesh& mesh, const Vec3& p) {
  std::optional<std::size_t> best;
  double best_d = std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
    const double d = (mesh.vertices[i] - p).squaredNorm();
    if (d < best_d) {
      best_d = d;
      best = i;
    }
  }
  return best;
}

double nearest_point_distance(const std::vector<Vec3>& points, const Vec3& x) {
  double best = std::numeric_limits<double>::infinity();
  for (const Vec3& p : points) best = std::min(best, (p - x).norm());
  return best;
}

Vec3 centroid(const Mesh& mesh) {
  Vec3 c = Vec3::Zero();
  for (const Vec3& v : mesh.vertices) c += v;
  return c / static_cast<double>(std::max<std::size_t>(1, mesh.vertices.size()));
}

double sphere_volume(double radius) { return 4.0 / 3.0 * std::numbers::pi * radius * radius * radius; }

double torus_volume(double major_radius, double minor_radius) {
  return 2.0 * std::numbers::pi * std::numbers::pi * major_radius * minor_radius * minor_radius;
}

// --- Fields --------------------------------------------------------------------------------------------------

double SphereField::value(const Vec3& p) const { return (p - center_).norm() - radius_; }
double SphereField::value_and_gradient(const Vec3& p, Vec3& gradient) const {
  const Vec3 d = p - center_;
  const double len = d.norm();
  gradient = len > 0.0 ? Vec3(d / len) : Vec3(0, 0, 1);
  return len - radius_;
}
std::optional<Aabb> SphereField::bounds() const {
  return Aabb{center_ - Vec3::Constant(radius_), center_ + Vec3::Constant(radius_)};
}

double TorusField::value(const Vec3& p) const {
  const Vec3 q = p - center_;
  return std::hypot(std::hypot(q.x(), q.y()) - major_, q.z()) - minor_;
}
double TorusField::value_and_gradient(const Vec3& p, Vec3& gradient) const {
  const Vec3 q = p - center_;
  const double rho = std::hypot(q.x(), q.y());
  const double a = rho - major_;
  const double len = std::hypot(a, q.z());
  const Vec3 radial = rho > 0.0 ? Vec3(q.x() / rho, q.y() / rho, 0.0) : Vec3(1, 0, 0);
  gradient = len > 0.0 ? Vec3((a / len) * radial + Vec3(0, 0, q.z() / len)) : Vec3(0, 0, 1);
  return len - minor_;
}
std::optional<Aabb> TorusField::bounds() const {
  const double r = major_ + minor_;
  return Aabb{center_ - Vec3(r, r, minor_), center_ + Vec3(r, r, minor_)};
}

double BoxField::value(const Vec3& p) const {
  Vec3 g;
  return value_and_gradient(p, g);
}
double BoxField::value_and_gradient(const Vec3& p, Vec3& gradient) const {
  const Vec3 q = (p - center_).cwiseAbs() - half_;
  const Vec3 sign = (p - center_).cwiseSign();
  const Vec3 outside = q.cwiseMax(0.0);
  const double out_len = outside.norm();
  if (out_len > 0.0) {
    gradient = (outside / out_len).cwiseProduct(sign);
    return out_len;
  }
  int axis = 0;
  q.maxCoeff(&axis);
  gradient = Vec3::Zero();
  gradient[axis] = sign[axis] != 0.0 ? sign[axis] : 1.0;
  return q[axis];
}
std::optional<Aabb> BoxField::bounds() const { return Aabb{center_ - half_, center_ + half_}; }

double TwoSpheresField::value_and_gradient(const Vec3& p, Vec3& gradient) const {
  Vec3 ga, gb;
  const double a = a_.value_and_gradient(p, ga);
  const double b = b_.value_and_gradient(p, gb);
  gradient = a <= b ? ga : gb;
  return std::min(a, b);
}
std::optional<Aabb> TwoSpheresField::bounds() const {
  const Aabb a = *a_.bounds(), b = *b_.bounds();
  return Aabb{a.min.cwiseMin(b.min), a.max.cwiseMax(b.max)};
}

Mesh polygonized(const FieldPtr& field, Polygonizer method, int cells, bool normals) {
  PolygonizeOptions options;
  options.method = method;
  options.cells = cells;
  options.normals = normals;
  options.threads = 2;
  const FieldPtr fields[] = {field};
  return polygonize(*field, resolve_grid(fields, options));
}

std::string plain_glb(const Mesh& mesh, const std::string& nodes, const std::string& roots, int index_type, int mode) {
  std::string bin;
  auto put = [&bin](const void* p, std::size_t n) { bin.append(static_cast<const char*>(p), n); };
  for (const Vec3& v : mesh.vertices) {
    const float xyz[4] = {static_cast<float>(v.x()), static_cast<float>(v.y()), static_cast<float>(v.z()), 0.0f};
    put(xyz, 16);
  }
  const std::size_t normal_offset = bin.size();
  for (const Vec3& n : mesh.normals) {
    const float xyz[3] = {static_cast<float>(n.x()), static_cast<float>(n.y()), static_cast<float>(n.z())};
    put(xyz, 12);
  }
  const std::size_t index_offset = bin.size();
  const int index_bytes = index_type == 5121 ? 1 : index_type == 5123 ? 2 : 4;
  for (const Triangle& t : mesh.triangles) {
    for (std::uint32_t v : t) put(&v, index_bytes);  // little-endian: the low bytes first
  }
  const std::string n = std::to_string(mesh.vertices.size());
  auto view = [](std::size_t offset, std::size_t length, const char* extra) {
    return R"({"buffer":0,"byteOffset":)" + std::to_string(offset) + R"(,"byteLength":)" + std::to_string(length) +
           extra + "}";
  };
  std::string json = R"({"asset":{"version":"2.0"},"buffers":[{"byteLength":)" + std::to_string(bin.size()) +
                     R"(}],"bufferViews":[)" + view(0, normal_offset, R"(,"byteStride":16)") + "," +
                     view(index_offset, bin.size() - index_offset, "");
  const bool normals = !mesh.normals.empty();
  if (normals) {  // glTF has no empty views
    json += ',';
    json += view(normal_offset, index_offset - normal_offset, "");
  }
  // POSITION states its bounds, as glTF asks (of the float32 values written).
  Eigen::Vector3f lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::max()), hi = -lo;
  for (const Vec3& v : mesh.vertices) {
    lo = lo.cwiseMin(v.cast<float>());
    hi = hi.cwiseMax(v.cast<float>());
  }
  auto triple = [](const Eigen::Vector3f& x) {
    std::string out(1, '[');
    for (int a = 0; a < 3; ++a) {
      if (a > 0) out += ',';
      out += format_number(x[a]);
    }
    return out + ']';
  };
  json += R"(],"accessors":[{"bufferView":0,"componentType":5126,"type":"VEC3","count":)" + n + R"(,"min":)" +
          triple(lo) + R"(,"max":)" + triple(hi) + "}";
  if (normals) json += R"(,{"bufferView":2,"componentType":5126,"type":"VEC3","count":)" + n + "}";
  const std::string attributes = normals ? R"({"POSITION":0,"NORMAL":1})" : R"({"POSITION":0})";
  const std::size_t first_index = normals ? 2 : 1;
  std::string primitives;
  if (mode == 4) {
    json += R"(,{"bufferView":1,"componentType":)" + std::to_string(index_type) + R"(,"type":"SCALAR","count":)" +
            std::to_string(3 * mesh.triangles.size()) + "}";
    primitives = R"({"attributes":)" + attributes + R"(,"indices":)" + std::to_string(first_index) + "}";
  } else {
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
      json += R"(,{"bufferView":1,"byteOffset":)" + std::to_string(3 * index_bytes * t) + R"(,"componentType":)" +
              std::to_string(index_type) + R"(,"type":"SCALAR","count":3})";
      primitives += std::string(t > 0 ? "," : "") + R"({"attributes":)" + attributes + R"(,"indices":)" +
                    std::to_string(first_index + t) + R"(,"mode":)" + std::to_string(mode) + "}";
    }
  }
  json += R"(],"meshes":[{"primitives":[)" + primitives + R"(]}],"nodes":)" + nodes + R"(,"scenes":[{"nodes":)" +
          roots + R"(}],"scene":0})";
  return pack_glb(json, bin);
}

std::vector<Vec3> particle_ball(const Vec3& c, double radius, double d, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> jitter(-0.15 * d, 0.15 * d);
  std::vector<Vec3> points;
  const int n = static_cast<int>(std::ceil(radius / d));
  for (int i = -n; i <= n; ++i)
    for (int j = -n; j <= n; ++j)
      for (int k = -n; k <= n; ++k) {
        const Vec3 p = Vec3(i, j, k) * d;
        if (p.norm() <= radius) points.push_back(c + p + Vec3(jitter(rng), jitter(rng), jitter(rng)));
      }
  return points;
}

}  // namespace surfacer::testing
