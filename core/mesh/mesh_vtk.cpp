// Legacy VTK and VTK XML (.vtu) mesh writers (core/mesh/mesh_vtk.h).
#include "core/mesh/mesh_vtk.h"

#include <zlib.h>

#include <algorithm>
#include <bit>
#include <cstdint>
#include <cstring>
#include <limits>
#include <string_view>

#include "core/mesh/mesh_io.h"
#include "core/util/base64.h"
#include "core/util/errors.h"
#include "core/util/text.h"

namespace surfacer {
namespace {

constexpr std::uint8_t kVtkTriangle = 5;
constexpr std::size_t kBlockBytes = std::size_t{1} << 20;  // uncompressed bytes per zlib block of a .vtu array

template <class T>
void append_raw(std::string& out, T value, bool big_endian) {
  unsigned char raw[sizeof(T)];
  std::memcpy(raw, &value, sizeof(T));
  if (big_endian != (std::endian::native == std::endian::big)) std::reverse(raw, raw + sizeof(T));
  out.append(reinterpret_cast<const char*>(raw), sizeof(T));
}

// Positions or normals as 3 x Float32 (or Float64) per vertex.
std::string vectors(const std::vector<Vec3>& values, bool float64, bool big_endian) {
  std::string out;
  out.reserve(values.size() * (float64 ? 24 : 12));
  for (const Vec3& p : values) {
    for (int c = 0; c < 3; ++c) {
      if (float64) {
        append_raw<double>(out, p[c], big_endian);
      } else {
        append_raw<float>(out, static_cast<float>(p[c]), big_endian);
      }
    }
  }
  return out;
}

// An attribute's values as Float32.
std::string floats(const std::vector<float>& values, bool big_endian) {
  std::string out;
  out.reserve(values.size() * 4);
  for (float v : values) append_raw<float>(out, v, big_endian);
  return out;
}

// --- Legacy ----------------------------------------------------------------------------------------------------------

std::string legacy(const Mesh& mesh, bool double_precision) {
  check_mesh_writable(mesh, "VTK");
  const std::size_t triangles = mesh.triangles.size();
  if (triangles > static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max()) / 4) {
    throw InvalidInput("triangles",
                       "a legacy .vtk file holds at most 536870911 triangles (its cell list size is a "
                       "32-bit count); this mesh has " +
                           std::to_string(triangles) + ": write .vtu instead");
  }
  const char* type = double_precision ? "double" : "float";
  std::string out = "# vtk DataFile Version 4.2\nsurfacer\nBINARY\nDATASET UNSTRUCTURED_GRID\nPOINTS " +
                    std::to_string(mesh.vertices.size()) + " " + type + "\n";
  out += vectors(mesh.vertices, double_precision, true);
  out += "\nCELLS " + std::to_string(triangles) + " " + std::to_string(4 * triangles) + "\n";
  out.reserve(out.size() + triangles * 20 + mesh.normals.size() * 12 + 128);
  for (const Triangle& t : mesh.triangles) {
    append_raw<std::int32_t>(out, 3, true);
    for (std::uint32_t v : t) append_raw<std::int32_t>(out, static_cast<std::int32_t>(v), true);
  }
  out += "\nCELL_TYPES " + std::to_string(triangles) + "\n";
  for (std::size_t t = 0; t < triangles; ++t) append_raw<std::int32_t>(out, kVtkTriangle, true);
  out += "\n";
  if (!mesh.normals.empty() || !mesh.attributes.empty())
    out += "POINT_DATA " + std::to_string(mesh.vertices.size()) + "\n";
  if (!mesh.normals.empty()) {
    // VECTORS rather than NORMALS: VTK reads both, meshio (and the readers built on it) only VECTORS.
    out += "VECTORS Normals float\n";
    out += vectors(mesh.normals, false, true);
    out += "\n";
  }
  // Attributes under their names: 3 components as VECTORS, 1, 2 or 4 as SCALARS with that many components.
  for (const Attribute& a : mesh.attributes) {
    if (a.components == 3) {
      out += "VECTORS " + token_name(a.name) + " float\n";
    } else {
      out += "SCALARS " + token_name(a.name) + " float " + std::to_string(a.components) + "\nLOOKUP_TABLE default\n";
    }
    out += floats(a.values, true);
    out += "\n";
  }
  return out;
}

// --- XML -------------------------------------------------------------------------------------------------------------

// One DataArray's content in VTK's compressed binary layout: the header (UInt64 little-endian: number of blocks,
// uncompressed block size, uncompressed size of a partial last block or 0, then each block's compressed size) and
// the zlib blocks, each base64-encoded on its own, as vtkXMLWriter does.
std::string compressed_base64(std::string_view data) {
  const std::size_t blocks = (data.size() + kBlockBytes - 1) / kBlockBytes;
  std::string header;
  append_raw<std::uint64_t>(header, blocks, false);
  append_raw<std::uint64_t>(header, kBlockBytes, false);
  append_raw<std::uint64_t>(header, data.size() % kBlockBytes, false);
  std::string compressed;
  std::string block;
  for (std::size_t b = 0; b < blocks; ++b) {
    const std::string_view in = data.substr(b * kBlockBytes, kBlockBytes);
    uLongf size = compressBound(static_cast<uLong>(in.size()));
    block.resize(size);
    if (compress2(reinterpret_cast<Bytef*>(block.data()), &size, reinterpret_cast<const Bytef*>(in.data()),
                  static_cast<uLong>(in.size()), Z_BEST_SPEED) != Z_OK) {
      throw Internal("zlib compress2 failed");
    }
    compressed.append(block.data(), size);
    append_raw<std::uint64_t>(header, size, false);
  }
  std::string out;
  append_base64(out, header);
  append_base64(out, compressed);
  return out;
}

void data_array(std::string& out, const char* type, const std::string& name, int components, std::string_view data) {
  out += "        <DataArray type=\"";
  out += type;
  out += "\" Name=\"";
  out += xml_escape(name);
  out += "\" NumberOfComponents=\"" + std::to_string(components) + "\" format=\"binary\">\n          ";
  out += compressed_base64(data);
  out += "\n        </DataArray>\n";
}

std::string xml(const Mesh& mesh, bool double_precision) {
  check_mesh_writable(mesh, "VTU");
  const std::size_t triangles = mesh.triangles.size();
  const bool wide =
      3 * static_cast<std::uint64_t>(triangles) > static_cast<std::uint64_t>(std::numeric_limits<std::int32_t>::max());
  std::string connectivity, offsets, types(triangles, static_cast<char>(kVtkTriangle));
  connectivity.reserve(triangles * (wide ? 24 : 12));
  offsets.reserve(triangles * (wide ? 8 : 4));
  for (std::size_t t = 0; t < triangles; ++t) {
    for (std::uint32_t v : mesh.triangles[t]) {
      if (wide) {
        append_raw<std::int64_t>(connectivity, v, false);
      } else {
        append_raw<std::int32_t>(connectivity, static_cast<std::int32_t>(v), false);
      }
    }
    if (wide) {
      append_raw<std::int64_t>(offsets, static_cast<std::int64_t>(3 * (t + 1)), false);
    } else {
      append_raw<std::int32_t>(offsets, static_cast<std::int32_t>(3 * (t + 1)), false);
    }
  }
  const char* index_type = wide ? "Int64" : "Int32";
  std::string out =
      "<?xml version=\"1.0\"?>\n"
      "<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\" "
      "compressor=\"vtkZLibDataCompressor\">\n"
      "  <UnstructuredGrid>\n"
      "    <Piece NumberOfPoints=\"" +
      std::to_string(mesh.vertices.size()) + "\" NumberOfCells=\"" + std::to_string(triangles) + "\">\n";
  if (!mesh.normals.empty() || !mesh.attributes.empty()) {
    out += mesh.normals.empty() ? "      <PointData>\n" : "      <PointData Normals=\"Normals\">\n";
    if (!mesh.normals.empty()) data_array(out, "Float32", "Normals", 3, vectors(mesh.normals, false, false));
    for (const Attribute& a : mesh.attributes)
      data_array(out, "Float32", a.name, a.components, floats(a.values, false));
    out += "      </PointData>\n";
  }
  out += "      <Points>\n";
  data_array(out, double_precision ? "Float64" : "Float32", "Points", 3,
             vectors(mesh.vertices, double_precision, false));
  out += "      </Points>\n      <Cells>\n";
  data_array(out, index_type, "connectivity", 1, connectivity);
  data_array(out, index_type, "offsets", 1, offsets);
  data_array(out, "UInt8", "types", 1, types);
  out += "      </Cells>\n    </Piece>\n  </UnstructuredGrid>\n</VTKFile>\n";
  return out;
}

}  // namespace

std::string write_vtk(const Mesh& mesh, bool double_precision) { return legacy(mesh, double_precision); }

std::string write_vtu(const Mesh& mesh, bool double_precision) { return xml(mesh, double_precision); }

std::string xml_escape(std::string_view text) {
  std::string out;
  for (const char c : text) {
    switch (c) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      case '\'':
        out += "&apos;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

}  // namespace surfacer
