// Argument checks shared by the scene builders (core/scene*.cpp). Internal: not part of the public interface.
// Each check throws surfacer::InvalidInput(field, "<field> <what is wrong>; <how to fix>").
#pragma once

#include <cmath>
#include <cstdio>
#include <string>

#include "core/util/errors.h"
#include "core/mesh/mesh.h"

namespace surfacer::scene_detail {

inline std::string format_number(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.10g", v);
  return buf;
}

inline void require_finite(const std::string& field, double v) {
  if (std::isnan(v)) throw InvalidInput(field, field + " is NaN; give a finite number");
  if (std::isinf(v)) throw InvalidInput(field, field + " is infinite; give a finite number");
}

inline void require_finite(const std::string& field, const Vec3& v) {
  static const char* const kAxes[3] = {".x", ".y", ".z"};
  for (int i = 0; i < 3; ++i) require_finite(field + kAxes[i], v[i]);
}

inline void require_positive(const std::string& field, double v, const std::string& hint = "") {
  require_finite(field, v);
  if (!(v > 0.0)) {
    throw InvalidInput(field, field + " (" + format_number(v) + ") must be > 0" + (hint.empty() ? "" : "; " + hint));
  }
}

inline void require_positive(const std::string& field, const Vec3& v, const std::string& hint = "") {
  static const char* const kAxes[3] = {".x", ".y", ".z"};
  for (int i = 0; i < 3; ++i) require_positive(field + kAxes[i], v[i], hint);
}

// Smallest box containing both.
inline Aabb merge(const Aabb& a, const Aabb& b) { return Aabb{a.min.cwiseMin(b.min), a.max.cwiseMax(b.max)}; }

}  // namespace surfacer::scene_detail
