// PLY / OBJ / Draco files. Parsers never trust counts from a header: every read is bounds-checked and reservations are
// capped by what the remaining bytes can hold, so truncated or hostile files fail with InvalidInput, not a crash.
#include "core/mesh/mesh_io.h"

#include <algorithm>
#include <bit>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <optional>
#include <sstream>
#include <vector>

#include "core/util/errors.h"
#include "core/mesh/mesh_codec.h"

namespace surfacer {
namespace {

[[noreturn]] void fail(const std::string& name, const std::string& where, const std::string& what) {
  throw InvalidInput("file", name + ": " + where + ": " + what);
}

std::string line_at(std::size_t line) { return "line " + std::to_string(line); }
std::string byte_at(std::size_t offset) { return "byte " + std::to_string(offset); }

bool is_space(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v'; }

// Splits a line into whitespace-separated tokens (reusing `out`).
void tokenize(std::string_view line, std::vector<std::string_view>& out) {
  out.clear();
  std::size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && is_space(line[i])) ++i;
    const std::size_t start = i;
    while (i < line.size() && !is_space(line[i])) ++i;
    if (i > start) out.push_back(line.substr(start, i - start));
  }
}

bool parse_double(std::string_view token, double& value) {
  const char* begin = token.data();
  const char* end = token.data() + token.size();
  if (begin != end && *begin == '+') ++begin;
  const auto result = std::from_chars(begin, end, value);
  return result.ec == std::errc() && result.ptr == end;
}

bool parse_int(std::string_view token, std::int64_t& value) {
  const char* begin = token.data();
  const char* end = token.data() + token.size();
  if (begin != end && *begin == '+') ++begin;
  const auto result = std::from_chars(begin, end, value);
  return result.ec == std::errc() && result.ptr == end;
}

// Lines of a text buffer, numbered from 1, without their line terminator.
class LineReader {
 public:
  explicit LineReader(std::string_view data) : data_(data) {}
  bool next(std::string_view& line) {
    if (pos_ >= data_.size()) return false;
    const std::size_t end = data_.find('\n', pos_);
    const std::size_t stop = end == std::string_view::npos ? data_.size() : end;
    line = data_.substr(pos_, stop - pos_);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    pos_ = end == std::string_view::npos ? data_.size() : end + 1;
    ++line_;
    return true;
  }
  std::size_t line() const { return line_; }
  std::size_t pos() const { return pos_; }

 private:
  std::string_view data_;
  std::size_t pos_ = 0;
  std::size_t line_ = 0;
};

// --- PLY ----------------------------------------------------------------------------------------------------------

enum class PlyType { kInt8, kUint8, kInt16, kUint16, kInt32, kUint32, kFloat32, kFloat64 };

std::optional<PlyType> ply_type(std::string_view name) {
  if (name == "char" || name == "int8") return PlyType::kInt8;
  if (name == "uchar" || name == "uint8") return PlyType::kUint8;
  if (name == "short" || name == "int16") return PlyType::kInt16;
  if (name == "ushort" || name == "uint16") return PlyType::kUint16;
  if (name == "int" || name == "int32") return PlyType::kInt32;
  if (name == "uint" || name == "uint32") return PlyType::kUint32;
  if (name == "float" || name == "float32") return PlyType::kFloat32;
  if (name == "double" || name == "float64") return PlyType::kFloat64;
  return std::nullopt;
}

std::size_t ply_size(PlyType type) {
  switch (type) {
    case PlyType::kInt8:
    case PlyType::kUint8:
      return 1;
    case PlyType::kInt16:
    case PlyType::kUint16:
      return 2;
    case PlyType::kInt32:
    case PlyType::kUint32:
    case PlyType::kFloat32:
      return 4;
    case PlyType::kFloat64:
      return 8;
  }
  return 1;
}

bool ply_integral(PlyType type) { return type != PlyType::kFloat32 && type != PlyType::kFloat64; }

struct PlyProperty {
  std::string name;
  PlyType type = PlyType::kFloat32;  // item type for lists
  bool list = false;
  PlyType count_type = PlyType::kUint8;
};

struct PlyElement {
  std::string name;
  std::uint64_t count = 0;
  std::vector<PlyProperty> properties;
  std::size_t header_line = 0;
};

enum class PlyFormat { kAscii, kBinaryLittle, kBinaryBig };

struct PlyHeader {
  PlyFormat format = PlyFormat::kAscii;
  std::vector<PlyElement> elements;
  std::size_t data_offset = 0;
  std::size_t data_line = 0;  // line number of the first data line (ASCII)
};

PlyHeader parse_ply_header(std::string_view bytes, const std::string& name) {
  PlyHeader header;
  LineReader lines(bytes);
  std::string_view line;
  std::vector<std::string_view> tok;
  if (!lines.next(line) || line != "ply") fail(name, line_at(1), "not a PLY file (the first line must be 'ply')");
  bool have_format = false;
  while (true) {
    if (!lines.next(line)) fail(name, line_at(lines.line() + 1), "unexpected end of file in the PLY header");
    tokenize(line, tok);
    const std::string where = line_at(lines.line());
    if (tok.empty() || tok[0] == "comment" || tok[0] == "obj_info") continue;
    if (tok[0] == "end_header") break;
    if (tok[0] == "format") {
      if (tok.size() < 2) fail(name, where, "format line needs a format name");
      if (tok[1] == "ascii") {
        header.format = PlyFormat::kAscii;
      } else if (tok[1] == "binary_little_endian") {
        header.format = PlyFormat::kBinaryLittle;
      } else if (tok[1] == "binary_big_endian") {
        header.format = PlyFormat::kBinaryBig;
      } else {
        fail(name, where, "unknown PLY format '" + std::string(tok[1]) + "'");
      }
      have_format = true;
    } else if (tok[0] == "element") {
      std::int64_t count = 0;
      if (tok.size() != 3 || !parse_int(tok[2], count) || count < 0) {
        fail(name, where, "expected 'element <name> <count>'");
      }
      header.elements.push_back({std::string(tok[1]), static_cast<std::uint64_t>(count), {}, lines.line()});
    } else if (tok[0] == "property") {
      if (header.elements.empty()) fail(name, where, "property before any element");
      PlyProperty property;
      if (tok.size() == 5 && tok[1] == "list") {
        const auto count_type = ply_type(tok[2]);
        const auto item_type = ply_type(tok[3]);
        if (!count_type || !item_type || !ply_integral(*count_type)) {
          fail(name, where, "bad list property types '" + std::string(tok[2]) + " " + std::string(tok[3]) + "'");
        }
        property.list = true;
        property.count_type = *count_type;
        property.type = *item_type;
        property.name = std::string(tok[4]);
      } else if (tok.size() == 3) {
        const auto type = ply_type(tok[1]);
        if (!type) fail(name, where, "unknown property type '" + std::string(tok[1]) + "'");
        property.type = *type;
        property.name = std::string(tok[2]);
      } else {
        fail(name, where, "expected 'property <type> <name>' or 'property list <count type> <type> <name>'");
      }
      header.elements.back().properties.push_back(std::move(property));
    } else {
      fail(name, where, "unexpected header keyword '" + std::string(tok[0]) + "'");
    }
  }
  if (!have_format) fail(name, line_at(lines.line()), "the PLY header has no format line");
  header.data_offset = lines.pos();
  header.data_line = lines.line() + 1;
  return header;
}

// What the mesh needs from the vertex and face elements.
struct PlyLayout {
  int x = -1, y = -1, z = -1, nx = -1, ny = -1, nz = -1;  // property indices in the vertex element
  int indices = -1;                                       // list property index in the face element
};

int find_property(const PlyElement& element, std::initializer_list<std::string_view> names) {
  for (std::string_view wanted : names) {
    for (std::size_t p = 0; p < element.properties.size(); ++p) {
      if (element.properties[p].name == wanted) return static_cast<int>(p);
    }
  }
  return -1;
}

// A face's vertex index as read (any double: it may be far outside the int64 range, or NaN).
std::string index_text(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

// Builds the mesh while the element readers feed values.
class PlyBuilder {
 public:
  PlyBuilder(const PlyHeader& header, const std::string& name) : name_(name) {
    int vertex_elements = 0, face_elements = 0;
    for (const PlyElement& e : header.elements) {
      // The layout is taken from one vertex and one face element: values of a second one would be read with it.
      if ((e.name == "vertex" && ++vertex_elements > 1) || (e.name == "face" && ++face_elements > 1)) {
        fail(name, line_at(e.header_line),
             "a second '" + e.name + "' element; a PLY mesh has one vertex element and at most one face element");
      }
      if (e.name == "vertex") {
        // Mesh indices are 32-bit (faces may come first and name any index below the declared count).
        if (e.count > std::numeric_limits<std::uint32_t>::max()) {
          fail(name, line_at(e.header_line),
               "the vertex element declares " + std::to_string(e.count) + " vertices; at most 4294967295 are supported");
        }
        vertex_count_ = e.count;
        layout_.x = find_property(e, {"x"});
        layout_.y = find_property(e, {"y"});
        layout_.z = find_property(e, {"z"});
        layout_.nx = find_property(e, {"nx"});
        layout_.ny = find_property(e, {"ny"});
        layout_.nz = find_property(e, {"nz"});
        for (int p : {layout_.x, layout_.y, layout_.z}) {
          if (p < 0) fail(name, line_at(e.header_line), "the vertex element needs properties x, y and z");
          if (e.properties[p].list) fail(name, line_at(e.header_line), "vertex coordinates cannot be lists");
        }
        has_normals_ = layout_.nx >= 0 && layout_.ny >= 0 && layout_.nz >= 0 && !e.properties[layout_.nx].list &&
                       !e.properties[layout_.ny].list && !e.properties[layout_.nz].list;
      } else if (e.name == "face") {
        layout_.indices = find_property(e, {"vertex_indices", "vertex_index"});
        if (layout_.indices < 0) {
          for (std::size_t p = 0; p < e.properties.size() && layout_.indices < 0; ++p) {
            if (e.properties[p].list) layout_.indices = static_cast<int>(p);
          }
        }
        if (layout_.indices < 0 || !e.properties[layout_.indices].list) {
          fail(name, line_at(e.header_line), "the face element needs a list property vertex_indices");
        }
        if (!ply_integral(e.properties[layout_.indices].type)) {
          fail(name, line_at(e.header_line), "face vertex_indices must have an integer type");
        }
      }
    }
  }

  void reserve(const PlyElement& e, std::size_t cap) {
    if (e.name == "vertex") {
      mesh_.vertices.reserve(std::min<std::uint64_t>(e.count, cap));
      if (has_normals_) mesh_.normals.reserve(std::min<std::uint64_t>(e.count, cap));
    } else if (e.name == "face") {
      mesh_.triangles.reserve(std::min<std::uint64_t>(e.count, cap));
    }
  }

  // values[p] for scalar properties; for the vertex element.
  void vertex(const double* values) {
    mesh_.vertices.emplace_back(values[layout_.x], values[layout_.y], values[layout_.z]);
    if (has_normals_) mesh_.normals.emplace_back(values[layout_.nx], values[layout_.ny], values[layout_.nz]);
  }

  // One face's vertex indices (already checked integral); `where` locates it for messages.
  void face(const std::vector<double>& indices, std::uint64_t face_number, const std::string& where) {
    if (indices.size() < 3) {
      fail(name_, where,
           "face " + std::to_string(face_number) + " has " + std::to_string(indices.size()) +
               " vertices; a face needs at least 3");
    }
    for (double v : indices) {
      if (!(v >= 0.0) || v >= static_cast<double>(vertex_count_)) {
        fail(name_, where,
             "face " + std::to_string(face_number) + " uses vertex index " + index_text(v) + " but there are " +
                 std::to_string(vertex_count_) + " vertices");
      }
    }
    const auto a = static_cast<std::uint32_t>(indices[0]);
    for (std::size_t k = 1; k + 1 < indices.size(); ++k) {
      mesh_.triangles.push_back(
          {a, static_cast<std::uint32_t>(indices[k]), static_cast<std::uint32_t>(indices[k + 1])});
    }
  }

  const PlyLayout& layout() const { return layout_; }
  Mesh take() { return std::move(mesh_); }

 private:
  const std::string& name_;
  PlyLayout layout_;
  bool has_normals_ = false;
  std::uint64_t vertex_count_ = 0;
  Mesh mesh_;
};

std::string element_item(const PlyElement& e, std::uint64_t i) {
  return (e.name == "vertex" || e.name == "face" ? e.name : "element '" + e.name + "' item") + " " + std::to_string(i);
}

void read_ply_ascii(std::string_view bytes, const PlyHeader& header, PlyBuilder& builder, const std::string& name) {
  LineReader lines(bytes.substr(header.data_offset));
  const std::size_t line_base = header.data_line - 1;
  std::string_view line;
  std::vector<std::string_view> tok;
  std::vector<double> scalars;
  std::vector<double> indices;
  for (const PlyElement& e : header.elements) {
    const bool is_vertex = e.name == "vertex";
    const bool is_face = e.name == "face";
    builder.reserve(e, (bytes.size() - header.data_offset) / 2 + 1);
    scalars.assign(e.properties.size(), 0.0);
    for (std::uint64_t i = 0; i < e.count; ++i) {
      do {
        if (!lines.next(line)) {
          fail(name, line_at(line_base + lines.line() + 1),
               "unexpected end of file: expected " + element_item(e, i) + " of " + std::to_string(e.count));
        }
        tokenize(line, tok);
      } while (tok.empty());
      const std::string where = line_at(line_base + lines.line());
      std::size_t t = 0;
      for (std::size_t p = 0; p < e.properties.size(); ++p) {
        const PlyProperty& property = e.properties[p];
        if (!property.list) {
          if (t >= tok.size()) {
            fail(name, where,
                 "expected " + std::to_string(e.properties.size()) + " numbers for " + element_item(e, i) + ", found " +
                     std::to_string(tok.size()));
          }
          if (!parse_double(tok[t], scalars[p])) {
            fail(name, where, "bad number '" + std::string(tok[t]) + "' for " + element_item(e, i));
          }
          ++t;
          continue;
        }
        std::int64_t count = 0;
        if (t >= tok.size() || !parse_int(tok[t], count) || count < 0) {
          fail(name, where, "expected a list length for property " + property.name + " of " + element_item(e, i));
        }
        ++t;
        if (static_cast<std::uint64_t>(count) > tok.size() - t) {
          fail(name, where,
               "list " + property.name + " of " + element_item(e, i) + " announces " + std::to_string(count) +
                   " values but the line has " + std::to_string(tok.size() - t));
        }
        const bool wanted = is_face && static_cast<int>(p) == builder.layout().indices;
        if (wanted) indices.clear();
        for (std::int64_t k = 0; k < count; ++k, ++t) {
          double value = 0.0;
          if (!parse_double(tok[t], value) || (wanted && value != std::floor(value))) {
            fail(name, where,
                 "bad value '" + std::string(tok[t]) + "' in list " + property.name + " of " + element_item(e, i));
          }
          if (wanted) indices.push_back(value);
        }
      }
      if (t != tok.size()) {
        fail(name, where,
             "found " + std::to_string(tok.size()) + " values for " + element_item(e, i) + ", expected " +
                 std::to_string(t));
      }
      if (is_vertex) builder.vertex(scalars.data());
      if (is_face) builder.face(indices, i, where);
    }
  }
}

class BinaryReader {
 public:
  BinaryReader(std::string_view bytes, std::size_t pos, bool big_endian, const std::string& name)
      : bytes_(bytes), pos_(pos), swap_(big_endian != (std::endian::native == std::endian::big)), name_(name) {}

  std::size_t pos() const { return pos_; }
  std::size_t remaining() const { return bytes_.size() - pos_; }

  double read(PlyType type, const PlyElement& e, std::uint64_t i) {
    const std::size_t size = ply_size(type);
    if (size > remaining()) {
      fail(name_, byte_at(pos_), "unexpected end of file in " + element_item(e, i) + " of " + std::to_string(e.count));
    }
    unsigned char raw[8];
    std::memcpy(raw, bytes_.data() + pos_, size);
    pos_ += size;
    if (swap_) std::reverse(raw, raw + size);
    switch (type) {
      case PlyType::kInt8:
        return static_cast<double>(static_cast<std::int8_t>(raw[0]));
      case PlyType::kUint8:
        return static_cast<double>(raw[0]);
      case PlyType::kInt16:
        return static_cast<double>(load<std::int16_t>(raw));
      case PlyType::kUint16:
        return static_cast<double>(load<std::uint16_t>(raw));
      case PlyType::kInt32:
        return static_cast<double>(load<std::int32_t>(raw));
      case PlyType::kUint32:
        return static_cast<double>(load<std::uint32_t>(raw));
      case PlyType::kFloat32:
        return static_cast<double>(load<float>(raw));
      case PlyType::kFloat64:
        return load<double>(raw);
    }
    return 0.0;
  }

 private:
  template <class T>
  static T load(const unsigned char* raw) {
    T value;
    std::memcpy(&value, raw, sizeof(T));
    return value;
  }

  std::string_view bytes_;
  std::size_t pos_;
  bool swap_;
  const std::string& name_;
};

void read_ply_binary(std::string_view bytes, const PlyHeader& header, PlyBuilder& builder, const std::string& name) {
  BinaryReader in(bytes, header.data_offset, header.format == PlyFormat::kBinaryBig, name);
  std::vector<double> scalars;
  std::vector<double> indices;
  for (const PlyElement& e : header.elements) {
    const bool is_vertex = e.name == "vertex";
    const bool is_face = e.name == "face";
    std::size_t min_bytes = 0;
    for (const PlyProperty& p : e.properties) min_bytes += p.list ? ply_size(p.count_type) : ply_size(p.type);
    builder.reserve(e, in.remaining() / std::max<std::size_t>(min_bytes, 1) + 1);
    scalars.assign(e.properties.size(), 0.0);
    for (std::uint64_t i = 0; i < e.count; ++i) {
      const std::size_t item_start = in.pos();
      if (min_bytes == 0 && i > 0) break;  // an element without properties: nothing to read
      for (std::size_t p = 0; p < e.properties.size(); ++p) {
        const PlyProperty& property = e.properties[p];
        if (!property.list) {
          scalars[p] = in.read(property.type, e, i);
          continue;
        }
        const std::size_t count_at = in.pos();
        const double count = in.read(property.count_type, e, i);
        if (count < 0) fail(name, byte_at(count_at), "negative list length in " + element_item(e, i));
        const auto n = static_cast<std::uint64_t>(count);
        if (n > in.remaining() / ply_size(property.type)) {
          fail(name, byte_at(count_at),
               "unexpected end of file in " + element_item(e, i) + " of " + std::to_string(e.count) + " (list of " +
                   std::to_string(n) + ")");
        }
        const bool wanted = is_face && static_cast<int>(p) == builder.layout().indices;
        if (wanted) indices.resize(n);
        for (std::uint64_t k = 0; k < n; ++k) {
          const double value = in.read(property.type, e, i);
          if (wanted) indices[k] = value;
        }
      }
      if (is_vertex) builder.vertex(scalars.data());
      if (is_face) builder.face(indices, i, byte_at(item_start));
    }
  }
}

Mesh parse_ply(std::string_view bytes, const std::string& name) {
  const PlyHeader header = parse_ply_header(bytes, name);
  PlyBuilder builder(header, name);
  if (header.format == PlyFormat::kAscii) {
    read_ply_ascii(bytes, header, builder, name);
  } else {
    read_ply_binary(bytes, header, builder, name);
  }
  return builder.take();
}

// --- OBJ ----------------------------------------------------------------------------------------------------------

Mesh parse_obj(std::string_view bytes, const std::string& name) {
  Mesh mesh;
  std::vector<Vec3> normals;
  bool normals_match = true;  // every face corner so far names a normal with the same index as its vertex
  bool any_face_normal = false;
  LineReader lines(bytes);
  std::string_view line;
  std::vector<std::string_view> tok;
  std::vector<std::uint32_t> face;
  while (lines.next(line)) {
    tokenize(line, tok);
    if (tok.empty() || tok[0][0] == '#') continue;
    const std::string where = line_at(lines.line());
    if (tok[0] == "v" || tok[0] == "vn") {
      const bool is_normal = tok[0] == "vn";
      double c[3];
      if (tok.size() < 4 || !parse_double(tok[1], c[0]) || !parse_double(tok[2], c[1]) || !parse_double(tok[3], c[2])) {
        const std::size_t number = (is_normal ? normals.size() : mesh.vertices.size()) + 1;
        fail(name, where,
             std::string("expected 3 numbers for ") + (is_normal ? "normal " : "vertex ") + std::to_string(number));
      }
      (is_normal ? normals : mesh.vertices).emplace_back(c[0], c[1], c[2]);
    } else if (tok[0] == "f") {
      if (tok.size() < 4)
        fail(name, where, "a face needs at least 3 vertices, found " + std::to_string(tok.size() - 1));
      face.clear();
      for (std::size_t k = 1; k < tok.size(); ++k) {
        const std::string_view corner = tok[k];
        const std::size_t slash = corner.find('/');
        std::int64_t index = 0;
        if (!parse_int(corner.substr(0, slash), index) || index == 0) {
          fail(name, where, "bad face vertex '" + std::string(corner) + "'");
        }
        const auto count = static_cast<std::int64_t>(mesh.vertices.size());
        const std::int64_t resolved = index > 0 ? index - 1 : count + index;
        if (resolved < 0 || resolved >= count) {
          fail(name, where,
               "face vertex " + std::to_string(index) + " is out of range (" + std::to_string(count) +
                   " vertices defined so far)");
        }
        face.push_back(static_cast<std::uint32_t>(resolved));
        // Normal index: the field after the second slash, if any.
        const std::size_t second = slash == std::string_view::npos ? slash : corner.find('/', slash + 1);
        std::int64_t normal = 0;
        if (second != std::string_view::npos && second + 1 < corner.size() &&
            parse_int(corner.substr(second + 1), normal) && normal != 0) {
          any_face_normal = true;
          const auto ncount = static_cast<std::int64_t>(normals.size());
          const std::int64_t nres = normal > 0 ? normal - 1 : ncount + normal;
          if (nres != resolved) normals_match = false;
        } else {
          normals_match = false;
        }
      }
      for (std::size_t k = 1; k + 1 < face.size(); ++k) mesh.triangles.push_back({face[0], face[k], face[k + 1]});
    }
    // vt, o, g, s, usemtl, mtllib, l, p and unknown keywords are ignored.
  }
  // Per-vertex normals only when the file pairs vertex i with normal i everywhere (as write_obj does).
  if (any_face_normal && normals_match && normals.size() == mesh.vertices.size()) mesh.normals = std::move(normals);
  return mesh;
}

// --- Writers ------------------------------------------------------------------------------------------------------

void check_writable(const Mesh& mesh) {
  if (mesh.vertices.size() > static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max())) {
    throw InvalidInput("vertices", "mesh has too many vertices for a PLY/OBJ file (max 2^31 - 1)");
  }
  if (!mesh.normals.empty() && mesh.normals.size() != mesh.vertices.size()) {
    throw InvalidInput("normals", "mesh has " + std::to_string(mesh.normals.size()) + " normals for " +
                                      std::to_string(mesh.vertices.size()) + " vertices");
  }
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    for (std::uint32_t v : mesh.triangles[t]) {
      if (v >= mesh.vertices.size()) {
        throw InvalidInput("triangles", "triangle " + std::to_string(t) + " uses vertex " + std::to_string(v) +
                                            " but the mesh has " + std::to_string(mesh.vertices.size()) + " vertices");
      }
    }
  }
}

template <class T>
void append_le(std::string& out, T value) {
  unsigned char raw[sizeof(T)];
  std::memcpy(raw, &value, sizeof(T));
  if constexpr (std::endian::native == std::endian::big) std::reverse(raw, raw + sizeof(T));
  out.append(reinterpret_cast<const char*>(raw), sizeof(T));
}

void append_number(std::string& out, double value) {
  char buf[32];
  const auto result = std::to_chars(buf, buf + sizeof(buf), value, std::chars_format::general, 9);
  out.append(buf, result.ptr);
}

void append_uint(std::string& out, std::uint64_t value) {
  char buf[24];
  const auto result = std::to_chars(buf, buf + sizeof(buf), value);
  out.append(buf, result.ptr);
}

std::string read_file(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InvalidInput("file", path.string() + ": cannot open for reading: " + std::strerror(errno));
  std::ostringstream buffer;
  buffer << in.rdbuf();
  if (in.bad()) throw InvalidInput("file", path.string() + ": read error");
  return std::move(buffer).str();
}

}  // namespace

MeshFormat mesh_format_from_path(const std::filesystem::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (ext == ".ply") return MeshFormat::kPly;
  if (ext == ".obj") return MeshFormat::kObj;
  if (ext == ".drc") return MeshFormat::kDraco;
  throw InvalidInput("file", path.string() + ": unknown mesh file extension '" + ext + "'; use .ply, .obj or .drc");
}

Mesh parse_mesh(std::string_view bytes, MeshFormat format, const std::string& name_for_errors) {
  switch (format) {
    case MeshFormat::kPly:
      return parse_ply(bytes, name_for_errors);
    case MeshFormat::kObj:
      return parse_obj(bytes, name_for_errors);
    case MeshFormat::kDraco:
      try {
        return decode_draco(bytes);
      } catch (const Error& e) {
        throw InvalidInput("file", name_for_errors + ": " + e.what());
      }
  }
  throw Internal("parse_mesh: unknown format");
}

Mesh read_mesh(const std::filesystem::path& path) {
  const MeshFormat format = mesh_format_from_path(path);
  const std::string bytes = read_file(path);
  return parse_mesh(bytes, format, path.string());
}

std::string write_ply(const Mesh& mesh, bool double_precision) {
  check_writable(mesh);
  const bool normals = !mesh.normals.empty();
  std::string out;
  const char* type = double_precision ? "double" : "float";
  out += "ply\nformat binary_little_endian 1.0\ncomment surfacer\nelement vertex ";
  append_uint(out, mesh.vertices.size());
  out += std::string("\nproperty ") + type + " x\nproperty " + type + " y\nproperty " + type + " z\n";
  if (normals) out += "property float nx\nproperty float ny\nproperty float nz\n";
  out += "element face ";
  append_uint(out, mesh.triangles.size());
  out += "\nproperty list uchar int vertex_indices\nend_header\n";
  const std::size_t vertex_bytes = (double_precision ? 24 : 12) + (normals ? 12 : 0);
  out.reserve(out.size() + mesh.vertices.size() * vertex_bytes + mesh.triangles.size() * 13);
  for (std::size_t v = 0; v < mesh.vertices.size(); ++v) {
    const Vec3& p = mesh.vertices[v];
    for (int c = 0; c < 3; ++c) {
      if (double_precision) {
        append_le<double>(out, p[c]);
      } else {
        append_le<float>(out, static_cast<float>(p[c]));
      }
    }
    if (normals) {
      for (int c = 0; c < 3; ++c) append_le<float>(out, static_cast<float>(mesh.normals[v][c]));
    }
  }
  for (const Triangle& t : mesh.triangles) {
    out.push_back(3);
    for (std::uint32_t v : t) append_le<std::int32_t>(out, static_cast<std::int32_t>(v));
  }
  return out;
}

std::string write_obj(const Mesh& mesh) {
  check_writable(mesh);
  const bool normals = !mesh.normals.empty();
  std::string out = "# surfacer\n";
  out.reserve(mesh.vertices.size() * (normals ? 80 : 40) + mesh.triangles.size() * (normals ? 40 : 24));
  auto triple = [&out](const char* key, const Vec3& p) {
    out += key;
    for (int c = 0; c < 3; ++c) {
      out.push_back(' ');
      append_number(out, p[c]);
    }
    out.push_back('\n');
  };
  for (const Vec3& p : mesh.vertices) triple("v", p);
  for (const Vec3& n : mesh.normals) triple("vn", n);
  for (const Triangle& t : mesh.triangles) {
    out.push_back('f');
    for (std::uint32_t v : t) {
      out.push_back(' ');
      append_uint(out, v + 1ull);
      if (normals) {
        out += "//";
        append_uint(out, v + 1ull);
      }
    }
    out.push_back('\n');
  }
  return out;
}

void write_mesh(const std::filesystem::path& path, const Mesh& mesh) {
  const MeshFormat format = mesh_format_from_path(path);
  std::string bytes;
  switch (format) {
    case MeshFormat::kPly:
      bytes = write_ply(mesh);
      break;
    case MeshFormat::kObj:
      bytes = write_obj(mesh);
      break;
    case MeshFormat::kDraco:
      bytes = encode_draco(mesh, DracoOptions{});
      break;
  }
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) throw InvalidInput("file", path.string() + ": cannot open for writing: " + std::strerror(errno));
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  out.close();
  if (!out) throw InvalidInput("file", path.string() + ": write failed");
}

}  // namespace surfacer
