#include "core/particles/attribute_interpolation.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "core/particles/spatial_hash.h"
#include "core/util/errors.h"
#include "core/util/format.h"
#include "core/util/parallel.h"

namespace surfacer {

AttributeInterpolationOptions AttributeInterpolationOptions::particle_support(double r_inner, double r_outer,
                                                                              std::span<const double> radii) {
  AttributeInterpolationOptions options;
  options.radius = r_outer;
  if (!radii.empty()) {
    const double ratio = r_outer / r_inner;
    options.radii.resize(radii.size());
    for (std::size_t i = 0; i < radii.size(); ++i) options.radii[i] = ratio * radii[i];
    options.radius = *std::max_element(options.radii.begin(), options.radii.end());
  }
  return options;
}

std::vector<Attribute> interpolate_attributes(std::span<const Vec3> particles, std::span<const Attribute> attributes,
                                              std::span<const Vec3> vertices,
                                              const AttributeInterpolationOptions& options, const RunControl& control) {
  const double radius = options.radius;
  if (!(radius > 0.0 && std::isfinite(radius))) {
    throw InvalidInput("radius", "radius (" + format_number(radius) + ") must be finite and > 0");
  }
  const bool weighted = !options.radii.empty();
  if (weighted && options.radii.size() != particles.size()) {
    throw InvalidInput("radius", "radii has " + std::to_string(options.radii.size()) + " values for " +
                                     std::to_string(particles.size()) + " particles");
  }
  std::vector<Attribute> out;
  for (const Attribute& a : attributes) {
    if (a.components < 1 || a.components > Attribute::kMaxComponents ||
        a.values.size() != particles.size() * static_cast<std::size_t>(a.components)) {
      throw InvalidInput("attributes", "attribute " + a.name + " has " + std::to_string(a.values.size()) +
                                           " values for " + std::to_string(particles.size()) + " particles of " +
                                           std::to_string(a.components) + " components");
    }
    out.push_back({a.name, a.components, std::vector<float>(vertices.size() * static_cast<std::size_t>(a.components))});
  }
  if (out.empty() || vertices.empty()) return out;
  if (particles.empty()) throw InvalidInput("particles", "no particles to interpolate attributes from");

  const SpatialHash hash(particles, radius);
  std::size_t floats = 0;
  for (const Attribute& a : attributes) floats += static_cast<std::size_t>(a.components);
  for_chunks(vertices.size(), resolve_threads(options.threads), [&](std::size_t begin, std::size_t end) {
    std::vector<double> sum(floats);
    for (std::size_t v = begin; v < end; ++v) {
      if ((v - begin) % 4096 == 0) control.check();
      const Vec3& x = vertices[v];
      const std::uint32_t ref = hash.nearest(x, std::numeric_limits<double>::infinity(), radius)->index;
      std::fill(sum.begin(), sum.end(), 0.0);
      double total = 0.0;
      hash.for_each_within(x, radius, [&](std::uint32_t i, const Vec3&, double d2) {
        const double r = weighted ? options.radii[i] : radius;
        const double q = 1.0 - d2 / (r * r);
        if (!(q > 0.0)) return;
        const double w = q * q * q;
        total += w;
        std::size_t k = 0;
        for (const Attribute& a : attributes) {
          const std::size_t c = static_cast<std::size_t>(a.components);
          for (std::size_t j = 0; j < c; ++j) {
            sum[k++] += w * (static_cast<double>(a.values[i * c + j]) - a.values[ref * c + j]);
          }
        }
      });
      std::size_t k = 0;
      for (std::size_t n = 0; n < attributes.size(); ++n) {
        const std::size_t c = static_cast<std::size_t>(attributes[n].components);
        for (std::size_t j = 0; j < c; ++j, ++k) {
          const double base = attributes[n].values[ref * c + j];
          out[n].values[v * c + j] = static_cast<float>(total > 0.0 ? base + sum[k] / total : base);
        }
      }
    }
  });
  control.check();
  return out;
}

}  // namespace surfacer
