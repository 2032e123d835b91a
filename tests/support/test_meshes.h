// Analytic test inputs shared by the test binaries: small meshes with known topology, exact signed-distance fields
// (implemented here against core/scene/scene.h's Field interface so tests do not depend on core/scene/scene.cpp), and
// distance helpers for asserting geometric bounds.
#pragma once

#include <algorithm>
#include <cstdint>
#include <optional>
#include <string>

#include "core/mesh/mesh.h"
#include "core/polygonize/polygonize.h"
#include "core/scene/scene.h"

namespace surfacer::testing {

// --- Meshes (triangles counter-clockwise seen from outside) -------------------------------------------------------

// [0,1]^3, 8 vertices, 12 triangles. Face diagonals all pass through (0,0,0) or (1,1,1), so those two corners have
// valence 6 and the other six valence 4. Closed, manifold, oriented, Euler 2, volume 1, angles 45..90 degrees.
Mesh unit_cube();
// Icosahedron subdivided `subdivisions` times (each triangle into 4), vertices projected on the sphere.
// V = 10 * 4^s + 2, F = 20 * 4^s; 12 vertices of valence 5, the rest valence 6. Subdivision keeps the coarser
// vertices (icosphere(s) vertices are a prefix of icosphere(s + 1)'s).
Mesh icosphere(int subdivisions, double radius = 1.0, const Vec3& center = Vec3::Zero());
// Torus around the z axis through `center`: genus 1 (Euler 0), major_segments * minor_segments * 2 triangles.
Mesh torus_mesh(double major_radius, double minor_radius, int major_segments = 32, int minor_segments = 16,
                const Vec3& center = Vec3::Zero());
// Unit square in z = 0 as two triangles: open, 4 boundary edges, Euler 1.
Mesh open_square();
// Three triangles sharing the edge (0, 1): one non-manifold edge.
Mesh non_manifold_edge();
// Two triangle fans of two triangles each, sharing only vertex 0: edge-manifold, not vertex-manifold, open.
Mesh bowtie();
// Two tetrahedra touching at one vertex: closed and edge-manifold but not vertex-manifold.
Mesh double_tetrahedron();
// icosphere(1) with triangle 0 reversed: closed and manifold but not oriented.
Mesh flipped_triangle();

// {field = 0} polygonized on 2 threads with `cells` cells along the longest axis of the field's padded bounds.
Mesh polygonized(const FieldPtr& field, Polygonizer method, int cells, bool normals = false);

// `mesh` in a .glb with plain accessors, as another exporter writes it: float positions at a byte stride of 16, float
// normals when the mesh has them, indices of glTF componentType `index_type` (5121, 5123 or 5125), primitive `mode` (4:
// as they are; 6: each triangle as a fan of its own, in a primitive per triangle), mesh 0 instanced by `nodes` (a JSON
// array of glTF nodes) from the scene's roots `roots` (a JSON array of node indices).
std::string plain_glb(const Mesh& mesh, const std::string& nodes, const std::string& roots, int index_type = 5125,
                      int mode = 4);

// A Draco edgebreaker stream of icosphere(1) whose connectivity header declares `faces` triangles (and as many
// traversal symbols) instead of 80: a decompression bomb of about 200 bytes, since Draco allocates its corner table
// for the declared count (about 12 bytes per triangle) before it reads a symbol.
std::string draco_bomb(std::uint32_t faces = 200'000'000);

// --- Distances ---------------------------------------------------------------------------------------------------

// Largest | |p - c| - r | over the mesh vertices.
double max_distance_to_sphere(const Mesh& mesh, const Vec3& center, double radius);
// Largest distance from a vertex to the torus surface (axis z through center).
double max_distance_to_torus(const Mesh& mesh, const Vec3& center, double major_radius, double minor_radius);
// Largest distance from a vertex of `from` to its nearest vertex of `to` (grid hash; exact nearest neighbour).
// Infinity when `to` has no vertices and `from` has some.
double max_nearest_vertex_distance(const Mesh& from, const Mesh& to);
// Index of the vertex of `mesh` nearest to p (linear scan), or nullopt for no vertices.
std::optional<std::size_t> nearest_vertex(const Mesh& mesh, const Vec3& p);
// Distance from x to the nearest of `points` (linear scan; infinity for none).
double nearest_point_distance(const std::vector<Vec3>& points, const Vec3& x);
// Mean of the vertices (zero for none).
Vec3 centroid(const Mesh& mesh);
// Particles of a cubic lattice of spacing d within `radius` of c, each jittered uniformly by +-0.15 d per axis
// (std::mt19937 seeded with `seed`): a droplet.
std::vector<Vec3> particle_ball(const Vec3& c, double radius, double d, unsigned seed);

// --- Exact volumes ---------------------------------------------------------------------------------------------

double sphere_volume(double radius);
// Solid torus: 2 pi^2 R r^2.
double torus_volume(double major_radius, double minor_radius);

// --- Exact signed-distance fields (negative inside) -----------------------------------------------------------------

class SphereField final : public Field {
 public:
  SphereField(const Vec3& center, double radius) : center_(center), radius_(radius) {}
  double value(const Vec3& p) const override;
  double value_and_gradient(const Vec3& p, Vec3& gradient) const override;
  std::optional<Aabb> bounds() const override;

 private:
  Vec3 center_;
  double radius_;
};

// Axis z through `center`.
class TorusField final : public Field {
 public:
  TorusField(const Vec3& center, double major_radius, double minor_radius)
      : center_(center), major_(major_radius), minor_(minor_radius) {}
  double value(const Vec3& p) const override;
  double value_and_gradient(const Vec3& p, Vec3& gradient) const override;
  std::optional<Aabb> bounds() const override;

 private:
  Vec3 center_;
  double major_, minor_;
};

class BoxField final : public Field {
 public:
  BoxField(const Vec3& center, const Vec3& half_size) : center_(center), half_(half_size) {}
  double value(const Vec3& p) const override;
  double value_and_gradient(const Vec3& p, Vec3& gradient) const override;
  std::optional<Aabb> bounds() const override;

 private:
  Vec3 center_, half_;
};

// Solid dot(normal, p) <= offset; normal need not be unit (the value is divided by |normal|).
class PlaneField final : public Field {
 public:
  PlaneField(const Vec3& normal, double offset) : normal_(normal.normalized()), offset_(offset / normal.norm()) {}
  double value(const Vec3& p) const override { return normal_.dot(p) - offset_; }
  double value_and_gradient(const Vec3& p, Vec3& gradient) const override {
    gradient = normal_;
    return value(p);
  }
  std::optional<Aabb> bounds() const override { return std::nullopt; }

 private:
  Vec3 normal_;
  double offset_;
};

// Union (min) of two spheres.
class TwoSpheresField final : public Field {
 public:
  TwoSpheresField(const Vec3& c0, double r0, const Vec3& c1, double r1) : a_(c0, r0), b_(c1, r1) {}
  double value(const Vec3& p) const override { return std::min(a_.value(p), b_.value(p)); }
  double value_and_gradient(const Vec3& p, Vec3& gradient) const override;
  std::optional<Aabb> bounds() const override;

 private:
  SphereField a_, b_;
};

}  // namespace surfacer::testing
