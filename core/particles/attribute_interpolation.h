// Per-particle attributes (velocity, density, ...) carried onto surface vertices (docs/ALGORITHMS.md §1, CHOICE
// "Attribute interpolation"): at a vertex x, a normalized kernel over the particles within their support radius R_i,
//     a(x) = a_ref + sum_i w_i (a_i - a_ref) / sum_i w_i,   w_i = (1 - |x - p_i|^2 / R_i^2)^3   (|x - p_i| < R_i),
// where a_ref is the nearest particle's value (algebraically the plain normalized kernel sum w_i a_i / sum w_i; the
// differences make a constant field come back bit for bit). A convex combination of the neighbours' values: no
// overshoot, so a density stays positive and a mask in [0, 1]. A linear field a(p) = a0 + g.p comes back within
// |g| max_i R_i. A vertex with no particle strictly within reach takes its nearest particle's value.
#pragma once

#include <span>
#include <vector>

#include "core/mesh/mesh.h"
#include "core/util/run_control.h"

namespace surfacer {

struct AttributeInterpolationOptions {
  // The kernel's support R (scene units, > 0): the surfacer's r_outer, so every faithful vertex has a particle in it.
  double radius = 1.0;
  // Empty, or one support radius per particle (per-particle radii: r_outer_i); `radius` must then be their maximum.
  std::vector<double> radii;
  int threads = 0;  // 0: hardware threads

  // The support of a frame the particle surfacer made with resolved radii r_inner and r_outer (its stats): r_outer,
  // or with per-particle radii (`radii` non-empty) r_outer / r_inner x radii[i] each.
  static AttributeInterpolationOptions particle_support(double r_inner, double r_outer, std::span<const double> radii);
};

// The attributes of `particles` (each one element per particle, 1 to Attribute::kMaxComponents components) at
// `vertices`, under the same names and in the same order. Throws InvalidInput("attributes") for an attribute whose
// count is not the particle count, InvalidInput("radius") for a radius that is not finite and > 0, Cancelled.
// An empty particle set gives empty attributes only with no vertices (InvalidInput("particles") otherwise).
std::vector<Attribute> interpolate_attributes(std::span<const Vec3> particles, std::span<const Attribute> attributes,
                                              std::span<const Vec3> vertices,
                                              const AttributeInterpolationOptions& options,
                                              const RunControl& control = {});

}  // namespace surfacer
