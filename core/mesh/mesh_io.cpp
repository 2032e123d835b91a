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
#include <stdexcept>
#include <vector>

#include "core/mesh/frame_codec.h"
#include "core/mesh/mesh_codec.h"
#include "core/mesh/mesh_gltf.h"
#include "core/mesh/mesh_vtk.h"
#include "core/mesh/ply.h"
#include "core/util/errors.h"
#include "core/util/parallel.h"
#include "core/util/text.h"

namespace surfacer {
namespace {

[[noreturn]] void fail(const std::string& name, const std::string& where, const std::string& what) {
  throw InvalidInput("file", name + ": " + where + ": " + what);
}

std::string line_at(std::size_t line) { return "line " + std::to_string(line); }

// --- PLY ----------------------------------------------------------------------------------------------------------

// What the mesh needs from the vertex and face elements.
struct PlyLayout {
  int x = -1, y = -1, z = -1, nx = -1, ny = -1, nz = -1;  // property indices in the vertex element
  int indices = -1;                                       // list property index in the face element
};

// A face's vertex index as read (any double: it may be far outside the int64 range, or NaN).
std::string index_text(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

// Builds the mesh from the vertex and face elements (other elements are read past).
class PlyBuilder final : public ply::ElementReader {
 public:
  PlyBuilder(const ply::Header& header, const std::string& name) : name_(name) {
    int vertex_elements = 0, face_elements = 0;
    for (const ply::Element& e : header.elements) {
      // The layout is taken from one vertex and one face element: values of a second one would be read with it.
      if ((e.name == "vertex" && ++vertex_elements > 1) || (e.name == "face" && ++face_elements > 1)) {
        fail(name, line_at(e.header_line),
             "a second '" + e.name + "' element; a PLY mesh has one vertex element and at most one face element");
      }
      if (e.name == "vertex") {
        // Mesh indices are 32-bit (faces may come first and name any index below the declared count).
        if (e.count > std::numeric_limits<std::uint32_t>::max()) {
          fail(
              name, line_at(e.header_line),
              "the vertex element declares " + std::to_string(e.count) + " vertices; at most 4294967295 are supported");
        }
        vertex_count_ = e.count;
        layout_.x = e.find({"x"});
        layout_.y = e.find({"y"});
        layout_.z = e.find({"z"});
        layout_.nx = e.find({"nx"});
        layout_.ny = e.find({"ny"});
        layout_.nz = e.find({"nz"});
        for (int p : {layout_.x, layout_.y, layout_.z}) {
          if (p < 0) fail(name, line_at(e.header_line), "the vertex element needs properties x, y and z");
          if (e.properties[p].list) fail(name, line_at(e.header_line), "vertex coordinates cannot be lists");
        }
        has_normals_ = layout_.nx >= 0 && layout_.ny >= 0 && layout_.nz >= 0 && !e.properties[layout_.nx].list &&
                       !e.properties[layout_.ny].list && !e.properties[layout_.nz].list;
        // Every other vertex property is a per-vertex attribute (write_ply's vertex properties).
        attribute_properties_ = ply::attribute_properties(e, [&](int p) {
          return p == layout_.x || p == layout_.y || p == layout_.z ||
                 (has_normals_ && (p == layout_.nx || p == layout_.ny || p == layout_.nz));
        });
        for (const ply::AttributeProperties& a : attribute_properties_) {
          mesh_.attributes.push_back({a.name, static_cast<int>(a.properties.size()), {}});
        }
      } else if (e.name == "face") {
        layout_.indices = e.find({"vertex_indices", "vertex_index"});
        if (layout_.indices < 0) {
          for (std::size_t p = 0; p < e.properties.size() && layout_.indices < 0; ++p) {
            if (e.properties[p].list) layout_.indices = static_cast<int>(p);
          }
        }
        if (layout_.indices < 0 || !e.properties[layout_.indices].list) {
          fail(name, line_at(e.header_line), "the face element needs a list property vertex_indices");
        }
        if (!ply::integral(e.properties[layout_.indices].type)) {
          fail(name, line_at(e.header_line), "face vertex_indices must have an integer type");
        }
      }
    }
  }

  void begin(const ply::Element& e, std::size_t cap) override {
    if (e.name == "vertex") {
      mesh_.vertices.reserve(std::min<std::uint64_t>(e.count, cap));
      if (has_normals_) mesh_.normals.reserve(std::min<std::uint64_t>(e.count, cap));
    } else if (e.name == "face") {
      mesh_.triangles.reserve(std::min<std::uint64_t>(e.count, cap));
    }
  }

  int list_property(const ply::Element& e) const override { return e.name == "face" ? layout_.indices : -1; }

  void item(const ply::Element& e, const ply::Item& item) override {
    if (e.name == "vertex") vertex(item.scalars);
    if (e.name == "face") face(item.list, item.index, item.where.text());
  }

  Mesh take() { return std::move(mesh_); }

 private:
  void vertex(std::span<const double> values) {
    mesh_.vertices.emplace_back(values[layout_.x], values[layout_.y], values[layout_.z]);
    if (has_normals_) mesh_.normals.emplace_back(values[layout_.nx], values[layout_.ny], values[layout_.nz]);
    for (std::size_t a = 0; a < attribute_properties_.size(); ++a) {
      for (int p : attribute_properties_[a].properties) {
        mesh_.attributes[a].values.push_back(static_cast<float>(values[static_cast<std::size_t>(p)]));
      }
    }
  }

  // One face's vertex indices (whole numbers); `where` locates it for messages.
  void face(std::span<const double> indices, std::uint64_t face_number, const std::string& where) {
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

  const std::string& name_;
  PlyLayout layout_;
  bool has_normals_ = false;
  std::vector<ply::AttributeProperties> attribute_properties_;  // of mesh_.attributes, in order
  std::uint64_t vertex_count_ = 0;
  Mesh mesh_;
};

Mesh parse_ply(std::string_view bytes, const std::string& name) {
  const ply::Header header = ply::parse_header(bytes, name);
  PlyBuilder builder(header, name);
  ply::read_data(bytes, header, builder, name);
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

void check_attributes(const Mesh& mesh) {
  for (const Attribute& a : mesh.attributes) {
    if (a.components < 1 || a.components > Attribute::kMaxComponents ||
        a.values.size() != mesh.vertices.size() * static_cast<std::size_t>(a.components)) {
      throw InvalidInput("attributes", "mesh attribute " + a.name + " has " + std::to_string(a.values.size()) +
                                           " values of " + std::to_string(a.components) + " components for " +
                                           std::to_string(mesh.vertices.size()) + " vertices");
    }
  }
}

void check_mesh_writable(const Mesh& mesh, std::string_view format) {
  if (mesh.vertices.size() > static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max())) {
    throw InvalidInput("vertices", "mesh has too many vertices for a " + std::string(format) + " file (max 2^31 - 1)");
  }
  if (!mesh.normals.empty() && mesh.normals.size() != mesh.vertices.size()) {
    throw InvalidInput("normals", "mesh has " + std::to_string(mesh.normals.size()) + " normals for " +
                                      std::to_string(mesh.vertices.size()) + " vertices");
  }
  check_attributes(mesh);
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    for (std::uint32_t v : mesh.triangles[t]) {
      if (v >= mesh.vertices.size()) {
        throw InvalidInput("triangles", "triangle " + std::to_string(t) + " uses vertex " + std::to_string(v) +
                                            " but the mesh has " + std::to_string(mesh.vertices.size()) + " vertices");
      }
    }
  }
}

std::string lower_extension(const std::filesystem::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return ext;
}

MeshFormat mesh_format_from_path(const std::filesystem::path& path) {
  const std::string ext = lower_extension(path);
  if (ext == ".ply") return MeshFormat::kPly;
  if (ext == ".obj") return MeshFormat::kObj;
  if (ext == ".drc") return MeshFormat::kDraco;
  if (ext == ".glb") return MeshFormat::kGlb;
  if (ext == ".gltf") return MeshFormat::kGltf;
  throw InvalidInput(
      "file", path.string() + ": unknown mesh file extension '" + ext + "'; use .ply, .obj, .drc, .glb or .gltf");
}

Mesh parse_mesh(std::string_view bytes, MeshFormat format, const std::string& name_for_errors,
                const MeshReadLimits& limits) {
  switch (format) {
    case MeshFormat::kPly:
      return parse_ply(bytes, name_for_errors);
    case MeshFormat::kObj:
      return parse_obj(bytes, name_for_errors);
    case MeshFormat::kDraco:
      try {
        return decode_draco(bytes, limits);
      } catch (const Error& e) {
        if (e.kind() != ErrorKind::kInvalidInput) throw Error(e.kind(), e.field(), name_for_errors + ": " + e.what());
        throw InvalidInput("file", name_for_errors + ": " + e.what());
      }
    case MeshFormat::kGlb:
    case MeshFormat::kGltf:
      return parse_glb(bytes, name_for_errors, limits);
  }
  throw Internal("parse_mesh: unknown format");
}

Mesh read_mesh(const std::filesystem::path& path, const MeshReadLimits& limits) {
  const MeshFormat format = mesh_format_from_path(path);
  const std::string bytes = read_file(path);
  return parse_mesh(bytes, format, path.string(), limits);
}

std::string write_ply(const Mesh& mesh, bool double_precision) {
  check_mesh_writable(mesh, "PLY/OBJ");
  const bool normals = !mesh.normals.empty();
  std::string out;
  const char* type = double_precision ? "double" : "float";
  out += "ply\nformat binary_little_endian 1.0\ncomment surfacer\nelement vertex ";
  append_uint(out, mesh.vertices.size());
  out += std::string("\nproperty ") + type + " x\nproperty " + type + " y\nproperty " + type + " z\n";
  if (normals) out += "property float nx\nproperty float ny\nproperty float nz\n";
  std::size_t attribute_floats = 0;
  for (const Attribute& a : mesh.attributes) {
    for (int c = 0; c < a.components; ++c)
      out += "property float " + ply::attribute_property(a.name, a.components, c) + "\n";
    attribute_floats += static_cast<std::size_t>(a.components);
  }
  out += "element face ";
  append_uint(out, mesh.triangles.size());
  out += "\nproperty list uchar int vertex_indices\nend_header\n";
  const std::size_t vertex_bytes = (double_precision ? 24 : 12) + (normals ? 12 : 0) + 4 * attribute_floats;
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
    for (const Attribute& a : mesh.attributes) {
      const std::size_t n = static_cast<std::size_t>(a.components);
      for (std::size_t c = 0; c < n; ++c) append_le<float>(out, a.values[v * n + c]);
    }
  }
  for (const Triangle& t : mesh.triangles) {
    out.push_back(3);
    for (std::uint32_t v : t) append_le<std::int32_t>(out, static_cast<std::int32_t>(v));
  }
  return out;
}

std::string write_obj(const Mesh& mesh) {
  check_mesh_writable(mesh, "PLY/OBJ");
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

namespace {

// The bytes of `mesh` in the file format of `path`'s extension (write_mesh).
std::string mesh_file_bytes(const std::filesystem::path& path, const Mesh& mesh) {
  const std::string ext = lower_extension(path);
  // .vtk and .vtu are written only: positions in double precision, as the Mesh holds them.
  if (ext == ".vtk") return write_vtk(mesh, /*double_precision=*/true);
  if (ext == ".vtu") return write_vtu(mesh, /*double_precision=*/true);
  switch (mesh_format_from_path(path)) {
    case MeshFormat::kPly:
      return write_ply(mesh);
    case MeshFormat::kObj:
      return write_obj(mesh);
    case MeshFormat::kDraco:
      return encode_draco(mesh, DracoOptions{});
    case MeshFormat::kGlb:
      return to_gltf(mesh, resolve_threads(0));  // encoded on every core
    case MeshFormat::kGltf:
      return write_gltf(mesh);
  }
  throw std::logic_error("mesh_file_bytes: unhandled format");
}

}  // namespace

void write_mesh(const std::filesystem::path& path, const Mesh& mesh) {
  const std::string bytes = mesh_file_bytes(path, mesh);
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) throw InvalidInput("file", path.string() + ": cannot open for writing: " + std::strerror(errno));
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  out.close();
  if (!out) throw InvalidInput("file", path.string() + ": write failed");
}

}  // namespace surfacer
