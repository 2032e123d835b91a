// Argument checks for options and builder arguments across core. Each throws
// surfacer::InvalidInput(field, "<field> (<value>) <what is wrong>; <hint>"), the value printed by format_number.
#pragma once

#include <cmath>
#include <cstdint>
#include <string>

#include "core/util/errors.h"
#include "core/util/format.h"
#include "core/util/geometry.h"

namespace surfacer {

namespace checks_detail {
inline std::string with_hint(std::string message, const std::string& hint) {
  if (!hint.empty()) message += "; " + hint;
  return message;
}
inline constexpr const char* kAxes[3] = {".x", ".y", ".z"};
}  // namespace checks_detail

inline void require_finite(const std::string& field, double v) {
  if (std::isnan(v)) throw InvalidInput(field, field + " is NaN; give a finite number");
  if (std::isinf(v)) throw InvalidInput(field, field + " is infinite; give a finite number");
}

inline void require_finite(const std::string& field, const Vec3& v) {
  for (int i = 0; i < 3; ++i) require_finite(field + checks_detail::kAxes[i], v[i]);
}

// Coordinates and lengths of scenes, boxes and particles: at most this in magnitude, so that sums, squares, paddings
// and cell counts made of them stay far from overflow (a sphere of radius 1e308 has bounds of infinite size).
inline constexpr double kMaxCoordinate = 1e12;
// The smallest length: below it, reciprocals (a gyroid's 2 pi / period, a grid's cells per unit) overflow or lose
// every digit against coordinates of ordinary size.
inline constexpr double kMinLength = 1e-12;

namespace checks_detail {
inline void require_magnitude(const std::string& field, double v) {
  if (std::abs(v) > kMaxCoordinate) {
    throw InvalidInput(field, field + " (" + format_number(v) + ") is beyond +-" + format_number(kMaxCoordinate) +
                                  ", the range of coordinates and lengths; scale the input down");
  }
}
}  // namespace checks_detail

// Finite and within +-kMaxCoordinate.
inline void require_coordinate(const std::string& field, double v) {
  require_finite(field, v);
  checks_detail::require_magnitude(field, v);
}

inline void require_coordinate(const std::string& field, const Vec3& v) {
  for (int i = 0; i < 3; ++i) require_coordinate(field + checks_detail::kAxes[i], v[i]);
}

inline void require_positive(const std::string& field, double v, const std::string& hint = "") {
  require_finite(field, v);
  if (!(v > 0.0)) {
    throw InvalidInput(field, checks_detail::with_hint(field + " (" + format_number(v) + ") must be > 0", hint));
  }
}

inline void require_positive(const std::string& field, const Vec3& v, const std::string& hint = "") {
  for (int i = 0; i < 3; ++i) require_positive(field + checks_detail::kAxes[i], v[i], hint);
}

// kMinLength <= v <= kMaxCoordinate: a length.
inline void require_length(const std::string& field, double v, const std::string& hint = "") {
  require_positive(field, v, hint);
  checks_detail::require_magnitude(field, v);
  if (v < kMinLength) {
    throw InvalidInput(
        field, checks_detail::with_hint(field + " (" + format_number(v) + ") is below " + format_number(kMinLength) +
                                            ", the smallest length; scale the input up",
                                        hint));
  }
}

inline void require_length(const std::string& field, const Vec3& v, const std::string& hint = "") {
  for (int i = 0; i < 3; ++i) require_length(field + checks_detail::kAxes[i], v[i], hint);
}

// lo <= v <= hi (finite).
inline void require_range(const std::string& field, double v, double lo, double hi, const std::string& hint = "") {
  require_finite(field, v);
  if (!(v >= lo && v <= hi)) {
    throw InvalidInput(field, checks_detail::with_hint(field + " (" + format_number(v) + ") must be in [" +
                                                           format_number(lo) + ", " + format_number(hi) + "]",
                                                       hint));
  }
}

// lo < v <= hi (finite).
inline void require_range_open_low(const std::string& field, double v, double lo, double hi,
                                   const std::string& hint = "") {
  require_finite(field, v);
  if (!(v > lo && v <= hi)) {
    throw InvalidInput(field, checks_detail::with_hint(field + " (" + format_number(v) + ") must be in (" +
                                                           format_number(lo) + ", " + format_number(hi) + "]",
                                                       hint));
  }
}

// lo <= v <= hi for counts and indices.
inline void require_count(const std::string& field, std::int64_t v, std::int64_t lo, std::int64_t hi,
                          const std::string& hint = "") {
  if (v < lo || v > hi) {
    throw InvalidInput(field, checks_detail::with_hint(field + " (" + std::to_string(v) + ") must be in " +
                                                           std::to_string(lo) + ".." + std::to_string(hi),
                                                       hint));
  }
}

// Corners within +-kMaxCoordinate with min < max on every axis.
inline void require_box(const std::string& field, const Aabb& box) {
  require_coordinate(field + ".min", box.min);
  require_coordinate(field + ".max", box.max);
  for (int i = 0; i < 3; ++i) {
    if (!(box.min[i] < box.max[i])) {
      const std::string axis = checks_detail::kAxes[i];
      throw InvalidInput(field, field + ".min" + axis + " (" + format_number(box.min[i]) + ") must be < " + field +
                                    ".max" + axis + " (" + format_number(box.max[i]) + ")");
    }
  }
}

}  // namespace surfacer
