// Shared pieces of the particle readers (core/particle_io*.cpp). Not part of the public API.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "core/particles/particle_io.h"
#include "core/util/format.h"
#include "core/util/text.h"

namespace surfacer::particle_io_detail {

// Throws InvalidInput("file", "<name>: <where>: <what>").
[[noreturn]] void fail(const std::string& name, const std::string& where, const std::string& what);
std::string line_at(std::size_t line);    // "line N"
std::string byte_at(std::size_t offset);  // "byte N"
// 1-based line number of a byte offset.
std::size_t line_of(std::string_view text, std::size_t offset);

std::string lower(std::string_view s);
bool is_radius_name(std::string_view name);  // "radius" or "pscale", any case

// Appends an attribute `name` of `components` values per point from `values` (points x components, as read) to
// `frame`, unless components is outside 1..Attribute::kMaxComponents, the name is empty or already taken (the first
// array of a name wins), or the name is a position/radius column. Values are not checked (a non-finite one in an
// array nobody uses is no error; pack_particle_records checks the arrays it sends).
void keep_attribute(ParticleFrame& frame, const std::string& name, std::int64_t components,
                    const std::vector<double>& values);

enum class Scalar { kI8, kU8, kI16, kU16, kI32, kU32, kI64, kU64, kF32, kF64 };
// PLY and VTK type names (char uchar short ... float double, int8 ... float64, unsigned_char ..., vtktypeint64).
std::optional<Scalar> scalar_from_name(std::string_view name);
std::size_t scalar_size(Scalar s);
// Reads one scalar of type s at p (scalar_size(s) bytes) as a double.
double read_scalar(const char* p, Scalar s, bool big_endian);

// Whitespace-token cursor over text with line tracking (1-based).
struct TextCursor {
  std::string_view text;
  const std::string& name;
  std::size_t pos = 0;
  std::size_t line = 1;
  std::size_t token_line = 1;  // line of the last token returned (errors at the end of the input name it)
  bool report_bytes = false;   // errors name "byte <pos>" instead of "line <line>" (text mixed with binary data)

  std::string where() const { return report_bytes ? byte_at(pos) : line_at(line); }
  void skip_space();
  std::optional<std::string_view> next();
  std::string_view expect(const std::string& what);  // fails at end of input
  double number(const std::string& what);            // fails unless the token is a number
  std::int64_t count(const std::string& what);       // non-negative integer
  void skip_line();                                  // past the next '\n'
  std::string_view rest_of_line();                   // up to '\n' (consumed), without '\r'
};

void check_finite(const Vec3& p, const std::string& name, const std::string& where);
// min(declared, bytes_left / min_bytes_each + 1): a reservation no header can inflate.
std::size_t capped_reserve(std::int64_t declared, std::size_t bytes_left, std::size_t min_bytes_each);

ParticleFrame parse_ply_points(std::string_view bytes, const std::string& name);
ParticleFrame parse_vtk_points(std::string_view bytes, const std::string& name);
ParticleFrame parse_json_points(std::string_view bytes, const std::string& name);
// Compressed arrays may inflate to at most `max_inflated_bytes` in all (ResourceLimit past it).
ParticleFrame parse_vtu_points(std::string_view bytes, const std::string& name, std::uint64_t max_inflated_bytes);

}  // namespace surfacer::particle_io_detail
