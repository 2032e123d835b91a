// VTK legacy (.vtk) and VTK XML (.vtu, .vtp) point positions, point arrays and surface cells for
// core/particles/particle_io.h.
#include <lz4.h>
#include <lzma.h>
#include <zlib.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <limits>
#include <map>
#include <string>
#include <vector>

#include "core/particles/particle_io_detail.h"
#include "core/util/errors.h"
#include "core/util/text.h"

namespace surfacer::particle_io_detail {
namespace {

std::string upper(std::string_view s) {
  std::string out(s);
  for (char& c : out) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  return out;
}

// --- Cells ----------------------------------------------------------------------------------------------------------

// VTK's cell types that hold surface triangles (vtkCellType.h).
constexpr int kVtkTriangle = 5;
constexpr int kVtkTriangleStrip = 6;
constexpr int kVtkPolygon = 7;
constexpr int kVtkQuad = 9;

// One list of cells as a file stores it: cell c's point ids are connectivity[offsets[c] .. offsets[c + 1]) (offsets
// start at 0), its VTK type types[c] when the list is `typed` (legacy CELLS, XML Cells), else `type` for every cell
// (legacy POLYGONS and TRIANGLE_STRIPS, XML Polys and Strips).
struct CellList {
  std::vector<double> offsets, connectivity, types;
  bool typed = false;
  int type = kVtkPolygon;
  std::int64_t first_point = 0;  // of the piece: ids are the piece's own
};

// A legacy cell list ("k i0 .. ik-1" per cell, n cells) as offsets and connectivity.
void split_cell_list(const std::vector<double>& list, std::int64_t n, CellList& cells, const std::string& name,
                     const std::string& where) {
  cells.offsets.assign(1, 0.0);
  std::size_t at = 0;
  for (std::int64_t c = 0; c < n; ++c) {
    const double k = at < list.size() ? list[at] : -1.0;
    if (!(k >= 0 && k == std::floor(k) && k <= static_cast<double>(list.size() - at - 1))) {
      fail(name, where, "cell " + std::to_string(c) + " of " + std::to_string(n) + " does not fit in the cell list");
    }
    cells.connectivity.insert(cells.connectivity.end(), list.begin() + static_cast<std::ptrdiff_t>(at + 1),
                              list.begin() + static_cast<std::ptrdiff_t>(at + 1 + static_cast<std::size_t>(k)));
    cells.offsets.push_back(static_cast<double>(cells.connectivity.size()));
    at += 1 + static_cast<std::size_t>(k);
  }
}

// Appends the triangles of `cells` (of a piece of `points` points) to `out`: polygons, quads and triangles fanned from
// their first point, strips split with every other triangle turned so that all keep the strip's side; other cell types
// are skipped, and so is a typed list without its types (their kinds are unknown; the points are still read).
void append_triangles(const CellList& cells, std::int64_t points, std::vector<Triangle>& out, const std::string& name,
                      const std::string& where) {
  if (cells.typed && cells.types.empty()) return;
  const std::size_t n = cells.offsets.empty() ? 0 : cells.offsets.size() - 1;
  if (!cells.types.empty() && cells.types.size() != n) {
    fail(name, where,
         "the cell types hold " + std::to_string(cells.types.size()) + " values for " + std::to_string(n) + " cells");
  }
  const auto id = [&](double v) {
    if (!(v >= 0 && v < static_cast<double>(points) && v == std::floor(v))) {
      fail(name, where, "a cell names point " + format_number(v) + ", not one of the " + std::to_string(points));
    }
    return static_cast<std::uint32_t>(cells.first_point + static_cast<std::int64_t>(v));
  };
  for (std::size_t c = 0; c < n; ++c) {
    const double b = cells.offsets[c], e = cells.offsets[c + 1];
    if (!(b >= 0 && b <= e && e <= static_cast<double>(cells.connectivity.size()))) {
      fail(name, where,
           "cell " + std::to_string(c) + "'s offsets (" + format_number(b) + ", " + format_number(e) +
               ") do not lie within the " + std::to_string(cells.connectivity.size()) + " point ids");
    }
    const auto lo = static_cast<std::size_t>(b), hi = static_cast<std::size_t>(e);
    const double stored = cells.types.empty() ? cells.type : cells.types[c];
    const int type = stored >= 0 && stored < 256 ? static_cast<int>(stored) : -1;
    if (hi - lo < 3) continue;
    const std::vector<double>& ids = cells.connectivity;
    if (type == kVtkTriangle || type == kVtkPolygon || type == kVtkQuad) {
      for (std::size_t i = lo + 1; i + 1 < hi; ++i) out.push_back({id(ids[lo]), id(ids[i]), id(ids[i + 1])});
    } else if (type == kVtkTriangleStrip) {
      for (std::size_t i = lo; i + 2 < hi; ++i) {
        const bool odd = (i - lo) % 2 == 1;
        out.push_back({id(ids[odd ? i + 1 : i]), id(ids[odd ? i : i + 1]), id(ids[i + 2])});
      }
    }
  }
}

// --- Legacy ----------------------------------------------------------------------------------------------------------

class LegacyReader {
 public:
  LegacyReader(std::string_view bytes, const std::string& name, bool surface_cells)
      : cursor_{bytes, name}, name_(name), surface_cells_(surface_cells) {}

  ParticleFrame read() {
    const std::string_view first = cursor_.rest_of_line();
    if (first.rfind("# vtk DataFile Version", 0) != 0) {
      fail(name_, line_at(1), "not a VTK legacy file (the first line must start with '# vtk DataFile Version')");
    }
    cursor_.rest_of_line();  // title
    const std::size_t mode_line = cursor_.line;
    const std::string mode = upper(cursor_.expect("ASCII or BINARY"));
    if (mode == "BINARY") {
      binary_ = true;
    } else if (mode != "ASCII") {
      fail(name_, line_at(mode_line), "expected ASCII or BINARY on line 3, got '" + mode.substr(0, 40) + "'");
    }
    cursor_.report_bytes = binary_;
    ParticleFrame frame;
    bool have_points = false;
    bool point_data = false;  // inside POINT_DATA (else CELL_DATA or before either)
    std::int64_t attribute_count = 0;
    std::int64_t points = 0;
    std::vector<double> values;
    while (true) {
      const std::optional<std::string_view> token = cursor_.next();
      if (!token) break;
      const std::size_t at = cursor_.pos - token->size();
      const std::string key = upper(*token);
      if (key == "DATASET") {
        const std::string type = upper(cursor_.expect("dataset type"));
        if (type != "POLYDATA" && type != "UNSTRUCTURED_GRID") {
          fail(name_, where(at),
               "DATASET " + type.substr(0, 40) + " is not supported; use POLYDATA or UNSTRUCTURED_GRID");
        }
      } else if (key == "POINTS") {
        if (have_points) fail(name_, where(at), "second POINTS section");
        points = cursor_.count("number of points");
        const Scalar type = scalar(cursor_.expect("point type"));
        read_values(points, 3, type, "POINTS", &values);
        frame.positions.resize(static_cast<std::size_t>(points));
        for (std::size_t i = 0; i < frame.positions.size(); ++i) {
          frame.positions[i] = Vec3(values[3 * i], values[3 * i + 1], values[3 * i + 2]);
          if (!frame.positions[i].allFinite()) fail(name_, where(at), "point " + std::to_string(i) + " is not finite");
        }
        have_points = true;
      } else if (key == "VERTICES" || key == "LINES" || key == "POLYGONS" || key == "TRIANGLE_STRIPS" ||
                 key == "CELLS") {
        const std::int64_t n = cursor_.count("cell count");
        const std::int64_t size = cursor_.count("cell list size");
        // Surface cells are kept (ParticleFrame::triangles); vertices and lines are read past.
        const bool keep = surface_cells_ && (key == "POLYGONS" || key == "TRIANGLE_STRIPS" || key == "CELLS");
        CellList cells;
        cells.typed = key == "CELLS";
        cells.type = key == "TRIANGLE_STRIPS" ? kVtkTriangleStrip : kVtkPolygon;
        const std::size_t save_pos = cursor_.pos, save_line = cursor_.line;
        const std::optional<std::string_view> next = cursor_.next();
        if (next && upper(*next) == "OFFSETS") {  // VTK 5.1: OFFSETS <type> n values, CONNECTIVITY <type> size values
          read_values(n, 1, scalar(cursor_.expect("offsets type")), "OFFSETS", keep ? &cells.offsets : nullptr);
          if (upper(cursor_.expect("CONNECTIVITY")) != "CONNECTIVITY")
            fail(name_, where(cursor_.pos), "expected CONNECTIVITY");
          read_values(size, 1, scalar(cursor_.expect("connectivity type")), "CONNECTIVITY",
                      keep ? &cells.connectivity : nullptr);
        } else {
          cursor_.pos = save_pos;
          cursor_.line = save_line;
          read_values(size, 1, Scalar::kI32, key, keep ? &values : nullptr);
          if (keep) split_cell_list(values, n, cells, name_, where(at));
        }
        if (keep) cell_lists_.push_back(std::move(cells));
      } else if (key == "CELL_TYPES") {
        const std::int64_t n = cursor_.count("cell count");
        // The types of the last CELLS read (none when reading points only).
        const auto cells =
            std::find_if(cell_lists_.rbegin(), cell_lists_.rend(), [](const CellList& c) { return c.typed; });
        std::vector<double>* types = cells == cell_lists_.rend() ? nullptr : &cells->types;
        read_values(n, 1, Scalar::kI32, "CELL_TYPES", types);
      } else if (key == "POINT_DATA" || key == "CELL_DATA") {
        point_data = key == "POINT_DATA";
        attribute_count = cursor_.count("attribute count");
      } else if (key == "SCALARS") {
        const std::string array = token_name_decoded(cursor_.expect("scalars name"));
        const Scalar type = scalar(cursor_.expect("scalars type"));
        std::int64_t components = 1;
        const std::string_view rest = cursor_.rest_of_line();
        if (rest.find_first_not_of(" \t") != std::string_view::npos) {
          double v = 0.0;
          const std::size_t b = rest.find_first_not_of(" \t");
          const std::size_t e = rest.find_first_of(" \t", b);
          if (!parse_double(rest.substr(b, e == std::string_view::npos ? e : e - b), v) || v < 1 || v > 4 ||
              v != std::floor(v)) {
            fail(name_, where(cursor_.pos), "bad number of components in SCALARS " + array);
          }
          components = static_cast<std::int64_t>(v);
        }
        if (upper(cursor_.expect("LOOKUP_TABLE")) != "LOOKUP_TABLE")
          fail(name_, where(cursor_.pos), "expected LOOKUP_TABLE");
        cursor_.expect("lookup table name");
        const bool radius = point_data && components == 1 && is_radius_name(array);
        read_values(attribute_count, components, type, "SCALARS " + array, point_data ? &values : nullptr);
        if (radius) {
          frame.radii = values;
        } else if (point_data) {
          keep_attribute(frame, array, components, values);
        }
      } else if (key == "LOOKUP_TABLE") {
        cursor_.expect("lookup table name");
        read_values(cursor_.count("lookup table size"), 4, binary_ ? Scalar::kU8 : Scalar::kF64, "LOOKUP_TABLE",
                    nullptr);
      } else if (key == "COLOR_SCALARS") {
        cursor_.expect("color scalars name");
        const std::int64_t n = cursor_.count("number of color components");
        read_values(attribute_count, n, binary_ ? Scalar::kU8 : Scalar::kF64, "COLOR_SCALARS", nullptr);
      } else if (key == "VECTORS" || key == "NORMALS" || key == "TENSORS" || key == "TENSORS6") {
        const std::string array = token_name_decoded(cursor_.expect("array name"));
        const std::int64_t n = key == "TENSORS" ? 9 : key == "TENSORS6" ? 6 : 3;
        const bool keep = point_data && n <= Attribute::kMaxComponents;
        read_values(attribute_count, n, scalar(cursor_.expect("array type")), key, keep ? &values : nullptr);
        if (keep) keep_attribute(frame, array, n, values);
      } else if (key == "TEXTURE_COORDINATES") {
        cursor_.expect("array name");
        const std::int64_t dim = cursor_.count("texture dimension");
        read_values(attribute_count, dim, scalar(cursor_.expect("array type")), key, nullptr);
      } else if (key == "FIELD") {
        cursor_.expect("field name");
        const std::int64_t arrays = cursor_.count("number of arrays");
        for (std::int64_t a = 0; a < arrays; ++a) {
          const std::string array = token_name_decoded(cursor_.expect("array name"));
          if (upper(array) == "METADATA") {
            skip_metadata();
            --a;
            continue;
          }
          const std::int64_t components = cursor_.count("number of components");
          const std::int64_t tuples = cursor_.count("number of tuples");
          const std::string_view type_name = cursor_.expect("array type");
          if (!scalar_from_name(type_name)) {
            if (have_points) return finish(frame, points);  // e.g. string arrays after the points: nothing we need
            fail(name_, where(cursor_.pos),
                 "unsupported FIELD array type '" + std::string(type_name.substr(0, 40)) + "'");
          }
          const bool per_point = point_data || !have_points || tuples == points;
          const bool radius = components == 1 && is_radius_name(array) && per_point;
          const bool keep = per_point && components <= Attribute::kMaxComponents;
          read_values(tuples, components, *scalar_from_name(type_name), "FIELD array " + array,
                      radius || keep ? &values : nullptr);
          if (radius) {
            frame.radii = values;
          } else if (keep) {
            keep_attribute(frame, array, components, values);
          }
        }
      } else if (key == "METADATA") {
        skip_metadata();
      } else if (have_points) {
        break;  // sections we do not know cannot hold anything we need
      } else {
        fail(name_, where(at), "unexpected keyword '" + std::string(token->substr(0, 40)) + "' before POINTS");
      }
    }
    if (!have_points) fail(name_, where(cursor_.pos), "no POINTS section");
    return finish(frame, points);
  }

 private:
  std::string where(std::size_t offset) const {
    return binary_ ? byte_at(offset) : line_at(line_of(cursor_.text, offset));
  }

  ParticleFrame finish(ParticleFrame& frame, std::int64_t points) const {
    if (!frame.radii.empty() && frame.radii.size() != static_cast<std::size_t>(points)) {
      fail(name_, where(cursor_.pos),
           "radius array has " + std::to_string(frame.radii.size()) + " values for " + std::to_string(points) +
               " points");
    }
    // Arrays of another length (a FIELD before the POINTS that turned out not to be per point) are no attributes.
    std::erase_if(frame.attributes, [&](const Attribute& a) { return a.count() != static_cast<std::size_t>(points); });
    for (const CellList& cells : cell_lists_)
      append_triangles(cells, points, frame.triangles, name_, where(cursor_.pos));
    return std::move(frame);
  }

  Scalar scalar(std::string_view type) const {
    const std::optional<Scalar> s = scalar_from_name(type);
    if (!s) fail(name_, where(cursor_.pos), "unsupported data type '" + std::string(type.substr(0, 40)) + "'");
    return *s;
  }

  void skip_metadata() {
    cursor_.rest_of_line();
    while (cursor_.pos < cursor_.text.size()) {
      const std::string_view l = cursor_.rest_of_line();
      if (l.find_first_not_of(" \t") == std::string_view::npos) break;
    }
  }

  // Reads tuples * components values of `type` (ASCII tokens, or big-endian binary starting after the current line);
  // stores them in *out when out != nullptr.
  void read_values(std::int64_t tuples, std::int64_t components, Scalar type, const std::string& what,
                   std::vector<double>* out) {
    if (tuples < 0 || components < 0 ||
        (components > 0 && tuples > std::numeric_limits<std::int64_t>::max() / components)) {
      fail(name_, where(cursor_.pos), "bad size of " + what);
    }
    const std::int64_t count = tuples * components;
    if (out != nullptr) out->clear();
    if (!binary_) {
      if (out != nullptr) out->reserve(capped_reserve(count, cursor_.text.size() - cursor_.pos, 2));
      for (std::int64_t i = 0; i < count; ++i) {
        const double v = cursor_.number(what + " value " + std::to_string(i) + " of " + std::to_string(count));
        if (out != nullptr) out->push_back(v);
      }
      return;
    }
    cursor_.skip_line();
    const std::size_t size = scalar_size(type);
    const std::size_t left = cursor_.text.size() - cursor_.pos;
    if (static_cast<std::uint64_t>(count) > left / size) {
      fail(name_, byte_at(cursor_.pos),
           "truncated " + what + " (needs " + std::to_string(count) + " x " + std::to_string(size) + " bytes, " +
               std::to_string(left) + " left)");
    }
    if (out != nullptr) {
      out->resize(static_cast<std::size_t>(count));
      for (std::size_t i = 0; i < out->size(); ++i)
        (*out)[i] = read_scalar(cursor_.text.data() + cursor_.pos + i * size, type, true);
    }
    cursor_.pos += static_cast<std::size_t>(count) * size;
  }

  TextCursor cursor_;
  const std::string& name_;
  bool binary_ = false;
  const bool surface_cells_;
  std::vector<CellList> cell_lists_;  // POLYGONS, TRIANGLE_STRIPS and CELLS (with their CELL_TYPES)
};

// --- XML (.vtu) --------------------------------------------------------------------------------------------------

struct Tag {
  std::string_view name;
  bool closing = false;
  bool self_closing = false;
  std::vector<std::pair<std::string_view, std::string_view>> attributes;
  std::size_t begin = 0, end = 0;  // '<' and one past '>'

  std::optional<std::string_view> attribute(std::string_view key) const {
    for (const auto& [k, v] : attributes) {
      if (k == key) return v;
    }
    return std::nullopt;
  }
};

// A Points or radius DataArray found while scanning the tags, decoded once the scan has found the appended data (if
// any): arrays are decoded in file order, so the pieces' points stay in order whatever their storage.
struct ArrayRef {
  Tag tag;
  bool points = false;
  std::string attribute;                // a PointData array other than the radius: its name (else empty)
  std::int64_t components = 1;          // ... and its components
  std::int64_t count = 0;               // values: points x components
  std::string_view content;             // inline arrays: the text between the tags
  std::size_t content_at = 0;           // ... and where it starts
  std::optional<std::uint64_t> offset;  // appended arrays: offset into the appended data
  std::vector<double> values;           // inline arrays: decoded as soon as they are met
  // A cell array (connectivity, offsets or types of a piece's Cells, Polys or Strips): which, and the index of its
  // piece's cell list. Decoded after the scan (connectivity's count is the last offset).
  std::string_view cell_array;
  int cell_list = -1;
};

class XmlReader {
 public:
  XmlReader(std::string_view text, const std::string& name, std::uint64_t max_inflated_bytes, bool surface_cells)
      : text_(text), name_(name), max_inflated_bytes_(max_inflated_bytes), surface_cells_(surface_cells) {}

  ParticleFrame read() {
    std::vector<ArrayRef> arrays;
    std::vector<std::string_view> stack;
    std::int64_t piece_points = -1;  // -1 outside a <Piece>
    std::int64_t piece_points_read = 0;
    std::int64_t points_before = 0;  // of the pieces before this one
    // Per piece, its Polys, Strips and Cells that have arrays: the index of each in cell_lists_.
    std::map<std::string_view, int> piece_lists;
    std::map<std::string_view, std::int64_t> piece_cells;
    bool piece_radius = false;
    bool saw_file = false, any_radius = false, any_piece_without_radius = false;
    std::size_t pos = 0;
    while (true) {
      const std::optional<Tag> tag = next_tag(pos);
      if (!tag) break;
      pos = tag->end;
      if (tag->closing) {
        if (stack.empty() || stack.back() != tag->name) {
          fail(name_, where(tag->begin), "unexpected </" + std::string(tag->name.substr(0, 40)) + ">");
        }
        stack.pop_back();
        if (tag->name == "Piece") {
          if (piece_points_read != piece_points) {
            fail(name_, where(tag->begin),
                 "piece declares " + std::to_string(piece_points) + " points but has " +
                     std::to_string(piece_points_read));
          }
          (piece_radius ? any_radius : any_piece_without_radius) = true;
          points_before += piece_points;
          piece_points = -1;
        }
        continue;
      }
      if (tag->name == "VTKFile") {
        saw_file = true;
        const std::string type(tag->attribute("type").value_or(""));
        if (type != "UnstructuredGrid" && type != "PolyData") {
          fail(name_, where(tag->begin),
               "VTKFile type '" + type.substr(0, 40) +
                   "' is not supported; use UnstructuredGrid or PolyData (.vtu/.vtp)");
        }
        const std::string order(tag->attribute("byte_order").value_or("LittleEndian"));
        if (order != "LittleEndian" && order != "BigEndian") fail(name_, where(tag->begin), "bad byte_order");
        big_endian_ = order == "BigEndian";
        const std::string header(tag->attribute("header_type").value_or("UInt32"));
        if (header != "UInt32" && header != "UInt64")
          fail(name_, where(tag->begin), "bad header_type '" + header + "'");
        header_size_ = header == "UInt64" ? 8 : 4;
        if (const auto compressor = tag->attribute("compressor"); compressor && !compressor->empty()) {
          if (*compressor == "vtkZLibDataCompressor") {
            compressor_ = Compressor::kZlib;
          } else if (*compressor == "vtkLZ4DataCompressor") {
            compressor_ = Compressor::kLz4;
          } else if (*compressor == "vtkLZMADataCompressor") {
            compressor_ = Compressor::kLzma;
          } else {
            fail(name_, where(tag->begin),
                 "compressor \"" + std::string(compressor->substr(0, 60)) +
                     "\" is not supported; write the file uncompressed or with zlib (vtkZLibDataCompressor, VTK's "
                     "and meshio's default), LZ4 (vtkLZ4DataCompressor) or LZMA (vtkLZMADataCompressor)");
          }
        }
      } else if (tag->name == "Piece") {
        if (!saw_file) fail(name_, where(tag->begin), "<Piece> outside <VTKFile>");
        // A piece's counts and radius flag are its own: a piece opened inside another would restart them while the
        // outer one's arrays are already read.
        if (piece_points >= 0) fail(name_, where(tag->begin), "<Piece> inside another <Piece>");
        double n = -1.0;
        const std::string_view np = tag->attribute("NumberOfPoints").value_or("");
        if (!parse_double(np, n) || n < 0 || n != std::floor(n) || n > 4.0e9) {
          fail(name_, where(tag->begin), "Piece has no valid NumberOfPoints");
        }
        piece_points = static_cast<std::int64_t>(n);
        piece_points_read = 0;
        piece_radius = false;
        piece_lists.clear();
        piece_cells.clear();
        for (const auto& [section, count] : {std::pair<std::string_view, std::string_view>{"Cells", "NumberOfCells"},
                                             {"Polys", "NumberOfPolys"},
                                             {"Strips", "NumberOfStrips"}}) {
          double cells = 0.0;
          if (const auto a = tag->attribute(count);
              a && (!parse_double(*a, cells) || cells < 0 || cells != std::floor(cells) || cells > 4.0e9)) {
            fail(name_, where(tag->begin), "Piece has no valid " + std::string(count));
          }
          piece_cells[section] = static_cast<std::int64_t>(cells);
        }
      } else if (tag->name == "AppendedData") {
        appended(*tag);
        break;  // raw bytes follow, up to the end of the file
      } else if (surface_cells_ && tag->name == "DataArray" && !stack.empty() && piece_cells.count(stack.back()) != 0 &&
                 piece_points >= 0) {
        const std::string_view section = stack.back();
        const std::string_view which = tag->attribute("Name").value_or("");
        if (which == "connectivity" || which == "offsets" || (which == "types" && section == "Cells")) {
          auto [list, fresh] = piece_lists.try_emplace(section, static_cast<int>(cell_lists_.size()));
          if (fresh) {
            PieceCells piece;
            piece.cells.typed = section == "Cells";
            piece.cells.type = section == "Strips" ? kVtkTriangleStrip : kVtkPolygon;
            piece.cells.first_point = points_before;
            piece.points = piece_points;
            piece.declared = piece_cells[section];
            cell_lists_.push_back(std::move(piece));
          }
          ArrayRef array;
          array.tag = *tag;
          array.cell_array = which;
          array.cell_list = list->second;
          array.count = which == "connectivity" ? 0 : piece_cells[section];  // connectivity's: its last offset
          locate(array, pos);
          arrays.push_back(std::move(array));
        }
      } else if (tag->name == "DataArray" && !stack.empty() &&
                 (stack.back() == "Points" ||
                  // The piece's first radius (or pscale) array; a second one is other data, not more radii.
                  (stack.back() == "PointData" && !piece_radius &&
                   is_radius_name(tag->attribute("Name").value_or(""))) ||
                  is_attribute_array(*tag, stack.back()))) {
        if (piece_points < 0) fail(name_, where(tag->begin), "DataArray outside a <Piece>");
        const bool points = stack.back() == "Points";
        double nc = 1.0;
        if (const auto a = tag->attribute("NumberOfComponents")) {
          if (!parse_double(*a, nc)) nc = -1.0;
        }
        const bool attribute = !points && !is_radius_name(tag->attribute("Name").value_or(""));
        const std::int64_t components = points ? 3 : attribute ? static_cast<std::int64_t>(nc) : 1;
        if (nc != static_cast<double>(components) && points) {
          fail(name_, where(tag->begin), "Points DataArray must have NumberOfComponents=\"3\"");
        }
        const bool is_appended = tag->attribute("format").value_or("ascii") == "appended";
        if (tag->self_closing && !is_appended) fail(name_, where(tag->begin), "empty DataArray");
        if (nc == static_cast<double>(components)) {  // (a multi-component "radius" is not a radius: skipped)
          ArrayRef array;
          array.tag = *tag;
          array.points = points;
          if (attribute) array.attribute = std::string(tag->attribute("Name").value_or(""));
          array.components = components;
          array.count = piece_points * components;
          locate(array, pos);
          if (!is_appended) array.values = decode(array);
          arrays.push_back(std::move(array));
          if (points) {
            piece_points_read += piece_points;
          } else if (!attribute) {
            piece_radius = true;
          }
        }
      }
      if (!tag->self_closing) stack.push_back(tag->name);
    }
    if (!saw_file) fail(name_, line_at(1), "not a VTK XML file (no <VTKFile> element)");
    if (piece_points >= 0) fail(name_, where(text_.size()), "file ends inside a <Piece>");
    if (any_radius && any_piece_without_radius) {
      fail(name_, where(text_.size()), "some pieces have a radius array and some do not");
    }
    ParticleFrame frame;
    struct Collected {
      std::string name;
      std::int64_t components = 1;
      std::vector<double> values;
    };
    std::vector<Collected> attributes;
    // Cell arrays: offsets first (VTK's end offsets, one per cell), then the connectivity they span and the types.
    for (const std::string_view which : {"offsets", "connectivity", "types"}) {
      for (ArrayRef& array : arrays) {
        if (array.cell_array != which) continue;
        CellList& cells = cell_lists_[static_cast<std::size_t>(array.cell_list)].cells;
        if (which == "connectivity") {
          const double last = cells.offsets.size() > 1 ? cells.offsets.back() : 0.0;
          // (the decoder checks the count against the bytes present; this keeps it an integer it can multiply)
          if (!(last >= 0 && last <= 1e12)) {
            fail(name_, where(array.tag.begin), "cell offsets end at " + format_number(last));
          }
          array.count = static_cast<std::int64_t>(last);
        }
        std::vector<double> values = decode(array);
        if (which == "offsets") {
          cells.offsets.assign(1, 0.0);
          cells.offsets.insert(cells.offsets.end(), values.begin(), values.end());
        } else {
          (which == "connectivity" ? cells.connectivity : cells.types) = std::move(values);
        }
      }
    }
    for (const PieceCells& piece : cell_lists_) {
      if (piece.declared > 0 && piece.cells.offsets.size() != static_cast<std::size_t>(piece.declared) + 1) {
        fail(name_, where(text_.size()),
             "a piece declares " + std::to_string(piece.declared) + " cells without their offsets array");
      }
      append_triangles(piece.cells, piece.points, frame.triangles, name_, where(text_.size()));
    }
    for (ArrayRef& array : arrays) {
      if (array.cell_list >= 0) continue;
      const std::vector<double> values = array.offset ? decode(array) : std::move(array.values);
      if (array.points) {
        for (std::size_t i = 0; i + 2 < values.size(); i += 3) {
          const Vec3 p(values[i], values[i + 1], values[i + 2]);
          if (!p.allFinite()) {  // (the line is found only on failure: counting lines per point is quadratic)
            check_finite(p, name_, where(array.tag.begin) + " (point " + std::to_string(i / 3) + ")");
          }
          frame.positions.push_back(p);
        }
      } else if (array.attribute.empty()) {
        frame.radii.insert(frame.radii.end(), values.begin(), values.end());
      } else {
        auto it = std::find_if(attributes.begin(), attributes.end(),
                               [&](const auto& a) { return a.name == array.attribute; });
        if (it == attributes.end()) {
          attributes.push_back({array.attribute, array.components, {}});
          it = attributes.end() - 1;
        }
        if (it->components == array.components) it->values.insert(it->values.end(), values.begin(), values.end());
      }
    }
    // An array that some piece lacks (or has with other components) is no attribute.
    for (const auto& a : attributes) {
      if (a.values.size() == frame.positions.size() * static_cast<std::size_t>(a.components)) {
        keep_attribute(frame, a.name, a.components, a.values);
      }
    }
    // Each piece checks its own counts; this holds the sum to them too, as the legacy reader's finish() does.
    if (!frame.radii.empty() && frame.radii.size() != frame.positions.size()) {
      fail(name_, where(text_.size()),
           "radius arrays hold " + std::to_string(frame.radii.size()) + " values for " +
               std::to_string(frame.positions.size()) + " points");
    }
    return frame;
  }

 private:
  std::string where(std::size_t offset) const { return line_at(line_of(text_, offset)); }

  // A PointData array of 1 to Attribute::kMaxComponents numbers other than the radius: an attribute.
  static bool is_attribute_array(const Tag& tag, std::string_view parent) {
    if (parent != "PointData") return false;
    const std::string_view name = tag.attribute("Name").value_or("");
    if (name.empty() || is_radius_name(name)) return false;
    if (!scalar_from_name(tag.attribute("type").value_or(""))) return false;
    double nc = 1.0;
    if (const auto a = tag.attribute("NumberOfComponents")) {
      if (!parse_double(*a, nc)) return false;
    }
    return nc >= 1 && nc <= Attribute::kMaxComponents && nc == std::floor(nc);
  }

  // Where an array's values lie: the appended data's offset, or the inline text up to the first child element; moves
  // `pos` past an inline array.
  void locate(ArrayRef& array, std::size_t& pos) const {
    const Tag& tag = array.tag;
    if (tag.attribute("format").value_or("ascii") == "appended") {
      double offset = -1.0;
      if (!parse_double(tag.attribute("offset").value_or(""), offset) || offset < 0 || offset != std::floor(offset) ||
          offset > 1e18) {
        fail(name_, where(tag.begin), "appended DataArray has no valid offset");
      }
      array.offset = static_cast<std::uint64_t>(offset);
    }
    if (!tag.self_closing) {
      const std::size_t close = text_.find("</DataArray>", tag.end);
      if (close == std::string_view::npos) fail(name_, where(tag.begin), "DataArray is not closed");
      // The values end at the first child element (VTK writes <InformationKey> elements after them).
      const std::size_t values_end = std::min(close, text_.find('<', tag.end));
      array.content = text_.substr(tag.end, values_end - tag.end);
      array.content_at = tag.end;
      pos = close;
    }
  }

  // <AppendedData encoding="raw|base64">, then optional white space and '_': the data starts after the '_'.
  void appended(const Tag& tag) {
    const std::string encoding(tag.attribute("encoding").value_or("raw"));
    if (encoding != "raw" && encoding != "base64") {
      fail(name_, where(tag.begin), "AppendedData encoding '" + encoding.substr(0, 40) + "' is not raw or base64");
    }
    appended_base64_ = encoding == "base64";
    std::size_t i = tag.end;
    while (i < text_.size() && std::isspace(static_cast<unsigned char>(text_[i]))) ++i;
    if (i >= text_.size() || text_[i] != '_') fail(name_, where(tag.end), "AppendedData must start with '_'");
    appended_at_ = i + 1;
  }

  // Bytes of one array's payload, in order: inline base64 decoded up front, appended data read where it lies.
  class Payload {
   public:
    Payload(std::string_view bytes, bool base64, const XmlReader& reader, std::string where)
        : bytes_(bytes), base64_(base64), reader_(reader), where_(std::move(where)) {}
    // The next n bytes (n is checked against what is left before anything is decoded or copied). In base64 the n
    // bytes are one encoded unit: ceil(n / 3) groups of four characters, the last one padded.
    std::string take(std::uint64_t n, const std::string& what) {
      const std::uint64_t need = base64_ ? (n + 2) / 3 * 4 : n;
      if (need > bytes_.size() - pos_) {
        fail(reader_.name_, where_,
             "truncated " + what + " (needs " + std::to_string(n) + " bytes, " +
                 std::to_string(base64_ ? (bytes_.size() - pos_) / 4 * 3 : bytes_.size() - pos_) + " left)");
      }
      std::string out = base64_ ? reader_.base64(bytes_.substr(pos_, need), 0) : std::string(bytes_.substr(pos_, n));
      out.resize(static_cast<std::size_t>(n));
      pos_ += static_cast<std::size_t>(need);
      return out;
    }
    // n1 + n2 bytes written as one base64 unit or as two (the first one padded): VTK encodes an uncompressed array's
    // header and data as one unit, a compressed array's block header and its blocks as two.
    std::string take_two(std::uint64_t n1, std::uint64_t n2, const std::string& what) {
      if (base64_ && n1 % 3 != 0) {
        const std::uint64_t need1 = (n1 + 2) / 3 * 4;
        if (need1 <= bytes_.size() - pos_ && bytes_[pos_ + static_cast<std::size_t>(need1) - 1] == '=') {
          std::string out = take(n1, what);
          return out + take(n2, what);
        }
      }
      if (n2 > std::numeric_limits<std::uint64_t>::max() - n1) fail(reader_.name_, where_, "oversized " + what);
      return take(n1 + n2, what);
    }
    // The next n bytes without consuming them (in base64 also the first n bytes of a longer unit).
    std::string peek(std::uint64_t n, const std::string& what) {
      const std::size_t pos = pos_;
      std::string out = take(n, what);
      pos_ = pos;
      return out;
    }
    std::uint64_t left() const { return base64_ ? (bytes_.size() - pos_) / 4 * 3 : bytes_.size() - pos_; }
    const std::string& where() const { return where_; }

   private:
    std::string_view bytes_;
    bool base64_;
    const XmlReader& reader_;
    std::string where_;
    std::size_t pos_ = 0;
  };

  std::uint64_t header_word(const std::string& bytes, std::size_t index) const {
    const double v =
        read_scalar(bytes.data() + index * header_size_, header_size_ == 8 ? Scalar::kU64 : Scalar::kU32, big_endian_);
    return v >= 1.8e19 ? std::numeric_limits<std::uint64_t>::max() : static_cast<std::uint64_t>(v);
  }

  // The uncompressed bytes of one binary array: a byte-count header and the data, or (compressed) VTK's block
  // header (blocks, block size, size of a partial last block or 0, each block's compressed size) and the compressed
  // blocks. Base64 units are as VTK writes them: header and data as one unit when uncompressed; the block header as one
  // unit and all the blocks as the next when compressed. `expected` bytes are what the array must hold; nothing is
  // allocated for a size the bytes present cannot back.
  std::string payload_bytes(Payload& in, std::uint64_t expected) {
    if (compressor_ == Compressor::kNone) {
      const std::string all = in.take_two(header_size_, expected, "binary DataArray");
      const std::uint64_t declared = header_word(all, 0);
      if (declared != expected) {
        fail(name_, in.where(),
             "binary DataArray header says " + std::to_string(declared) + " bytes, expected " +
                 std::to_string(expected));
      }
      return all.substr(header_size_);
    }
    const std::string head = in.peek(3 * header_size_, "compressed DataArray header");
    const std::uint64_t blocks = header_word(head, 0), block_size = header_word(head, 1),
                        last_size = header_word(head, 2);
    if (blocks > in.left() / header_size_) {
      fail(
          name_, in.where(),
          "compressed DataArray declares " + std::to_string(blocks) + " blocks; the file is too short for their sizes");
    }
    const std::uint64_t header_bytes = (3 + blocks) * header_size_;
    const std::string header = in.peek(header_bytes, "compressed DataArray block sizes");
    bool fits = last_size <= block_size;
    std::uint64_t total = 0;
    if (blocks > 0) {
      // (blocks - 1) full blocks within `expected` first, so the sum below cannot overflow.
      fits = fits && block_size > 0 && blocks - 1 <= expected / block_size;
      if (fits) total = (blocks - 1) * block_size + (last_size != 0 ? last_size : block_size);
    }
    if (!fits || total != expected) {
      fail(name_, in.where(),
           "compressed DataArray header gives " + std::to_string(blocks) + " blocks of " + std::to_string(block_size) +
               " bytes (last " + std::to_string(last_size) + "), expected " + std::to_string(expected) +
               " bytes in all");
    }
    inflated_ += total;
    // zlib inflates at most 1032 bytes per compressed byte (plus its header), LZ4 at most 255: a block that claims
    // more is a lie, refused before its output is allocated. LZMA has no such bound; the limit on all inflated bytes
    // below holds it.
    const std::uint64_t ratio = compressor_ == Compressor::kZlib ? 1032 : compressor_ == Compressor::kLz4 ? 255 : 0;
    std::uint64_t compressed_total = 0;
    for (std::uint64_t b = 0; b < blocks; ++b) {
      const std::uint64_t size = header_word(header, static_cast<std::size_t>(3 + b));
      const std::uint64_t out = b + 1 == blocks && last_size != 0 ? last_size : block_size;
      if (size > in.left() || (ratio != 0 && out > size * ratio + 64)) {
        fail(name_, in.where(),
             "compressed block " + std::to_string(b) + " of " + std::to_string(blocks) + " claims " +
                 std::to_string(size) + " bytes inflating to " + std::to_string(out) +
                 (size > in.left() ? ", more than the file holds"
                                   : std::string(", more than ") + (compressor_ == Compressor::kZlib ? "zlib" : "LZ4") +
                                         " can produce"));
      }
      compressed_total += size;
      if (compressed_total > in.left()) {
        fail(name_, in.where(), "compressed blocks hold more bytes than the file has left");
      }
    }
    if (inflated_ > max_inflated_bytes_) {
      throw ResourceLimit("file", name_ + ": " + in.where() + ": its compressed DataArrays inflate to " +
                                      std::to_string(inflated_) + " bytes, more than " +
                                      std::to_string(max_inflated_bytes_) + " (the limit)");
    }
    const std::string data = in.take_two(header_bytes, compressed_total, "compressed DataArray")
                                 .substr(static_cast<std::size_t>(header_bytes));
    std::string out(static_cast<std::size_t>(total), '\0');
    std::uint64_t done = 0, at = 0;
    for (std::uint64_t b = 0; b < blocks; ++b) {
      const std::uint64_t size = header_word(header, static_cast<std::size_t>(3 + b));
      const std::uint64_t want = b + 1 == blocks && last_size != 0 ? last_size : block_size;
      const std::string error = inflate_block(std::string_view(data).substr(at, size), out.data() + done, want);
      if (!error.empty()) {
        fail(name_, in.where(),
             "compressed block " + std::to_string(b) + " of " + std::to_string(blocks) + " does not inflate to its " +
                 std::to_string(want) + " bytes (" + error + ")");
      }
      at += size;
      done += want;
    }
    return out;
  }

  // Decompresses one block into exactly `want` bytes at `out`; returns "" or what went wrong.
  std::string inflate_block(std::string_view block, char* out, std::uint64_t want) const {
    switch (compressor_) {
      case Compressor::kZlib: {
        uLongf produced = static_cast<uLongf>(want);
        const int rc = uncompress(reinterpret_cast<Bytef*>(out), &produced,
                                  reinterpret_cast<const Bytef*>(block.data()), static_cast<uLong>(block.size()));
        if (rc != Z_OK) return std::string("zlib: ") + zError(rc);
        return produced == want ? "" : "zlib: too short";
      }
      case Compressor::kLz4: {
        if (block.size() > static_cast<std::size_t>(std::numeric_limits<int>::max()) ||
            want > static_cast<std::uint64_t>(std::numeric_limits<int>::max())) {
          return "lz4: block over 2 GB";
        }
        const int produced =
            LZ4_decompress_safe(block.data(), out, static_cast<int>(block.size()), static_cast<int>(want));
        if (produced < 0) return "lz4: malformed block";
        return static_cast<std::uint64_t>(produced) == want ? "" : "lz4: too short";
      }
      case Compressor::kLzma: {
        std::uint64_t memlimit = std::uint64_t{1} << 27;  // decoder memory: VTK's presets (up to 9) need < 70 MiB
        std::size_t in_pos = 0, out_pos = 0;
        const lzma_ret rc = lzma_stream_buffer_decode(
            &memlimit, 0, nullptr, reinterpret_cast<const std::uint8_t*>(block.data()), &in_pos, block.size(),
            reinterpret_cast<std::uint8_t*>(out), &out_pos, static_cast<std::size_t>(want));
        if (rc != LZMA_OK) return "lzma: " + std::string(rc == LZMA_BUF_ERROR ? "too long or truncated" : "malformed");
        return out_pos == want ? "" : "lzma: too short";
      }
      case Compressor::kNone:
        break;
    }
    return "not compressed";
  }

  std::vector<double> decode(const ArrayRef& array) {
    const Tag& tag = array.tag;
    const std::int64_t count = array.count;
    const std::string type_name(tag.attribute("type").value_or(""));
    const std::optional<Scalar> type = scalar_from_name(type_name);
    if (!type) fail(name_, where(tag.begin), "unsupported DataArray type '" + type_name.substr(0, 40) + "'");
    const std::string format(tag.attribute("format").value_or("ascii"));
    std::vector<double> values;
    if (format == "ascii") {
      const std::string_view content = array.content;
      TextCursor c{content, name_};
      values.reserve(capped_reserve(count, content.size(), 2));
      std::size_t last = 0;  // end of the last value read
      for (std::int64_t i = 0; i < count; ++i) {
        const std::optional<std::string_view> t = c.next();
        if (!t) {
          fail(name_, where(array.content_at + last),
               "DataArray has " + std::to_string(i) + " values, expected " + std::to_string(count));
        }
        last = c.pos;
        double v = 0.0;
        if (!parse_double(*t, v)) {
          fail(name_, where(array.content_at + c.pos), "'" + std::string(t->substr(0, 40)) + "' is not a number");
        }
        values.push_back(v);
      }
      if (c.next())
        fail(name_, where(array.content_at + c.pos), "DataArray has more than " + std::to_string(count) + " values");
      return values;
    }
    const std::uint64_t size = scalar_size(*type);
    const std::uint64_t expected = static_cast<std::uint64_t>(count) * size;
    std::string bytes;
    if (format == "appended") {
      if (!appended_at_) {
        fail(name_, where(tag.begin), "appended DataArray, but the file has no <AppendedData> after it");
      }
      const std::uint64_t offset = *array.offset;
      const std::size_t available = text_.size() - *appended_at_;
      if (offset > available) {
        fail(name_, where(tag.begin),
             "appended DataArray offset " + std::to_string(offset) + " is past the end of the appended data (" +
                 std::to_string(available) + " bytes)");
      }
      Payload in(text_.substr(*appended_at_ + static_cast<std::size_t>(offset)), appended_base64_, *this,
                 where(tag.begin) + " (appended data at offset " + std::to_string(offset) + ")");
      bytes = payload_bytes(in, expected);
    } else if (format == "binary") {
      const std::string decoded = base64(array.content, array.content_at);
      Payload in(decoded, false, *this, where(array.content_at));
      bytes = payload_bytes(in, expected);
    } else {
      fail(name_, where(tag.begin), "unknown DataArray format '" + format.substr(0, 40) + "'");
    }
    values.resize(static_cast<std::size_t>(count));
    for (std::size_t i = 0; i < values.size(); ++i) {
      values[i] = read_scalar(bytes.data() + i * size, *type, big_endian_);
    }
    return values;
  }

  std::optional<Tag> next_tag(std::size_t pos) const {
    while (true) {
      const std::size_t lt = text_.find('<', pos);
      if (lt == std::string_view::npos) return std::nullopt;
      if (text_.substr(lt, 4) == "<!--") {
        const std::size_t e = text_.find("-->", lt + 4);
        if (e == std::string_view::npos) fail(name_, where(lt), "unterminated comment");
        pos = e + 3;
        continue;
      }
      if (text_.substr(lt, 2) == "<?" || text_.substr(lt, 2) == "<!") {
        const std::size_t e = text_.find('>', lt);
        if (e == std::string_view::npos) fail(name_, where(lt), "unterminated declaration");
        pos = e + 1;
        continue;
      }
      Tag tag;
      tag.begin = lt;
      std::size_t i = lt + 1;
      if (i < text_.size() && text_[i] == '/') {
        tag.closing = true;
        ++i;
      }
      auto is_name = [](char c) {
        return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == ':' || c == '-' || c == '.';
      };
      auto skip_ws = [&] {
        while (i < text_.size() && std::isspace(static_cast<unsigned char>(text_[i]))) ++i;
      };
      const std::size_t name_begin = i;
      while (i < text_.size() && is_name(text_[i])) ++i;
      tag.name = text_.substr(name_begin, i - name_begin);
      if (tag.name.empty()) fail(name_, where(lt), "malformed tag");
      while (true) {
        skip_ws();
        if (i >= text_.size()) fail(name_, where(lt), "unterminated tag <" + std::string(tag.name.substr(0, 40)));
        if (text_[i] == '>') {
          ++i;
          break;
        }
        if (text_[i] == '/' && i + 1 < text_.size() && text_[i + 1] == '>') {
          tag.self_closing = true;
          i += 2;
          break;
        }
        const std::size_t key_begin = i;
        while (i < text_.size() && is_name(text_[i])) ++i;
        const std::string_view key = text_.substr(key_begin, i - key_begin);
        skip_ws();
        if (key.empty() || i >= text_.size() || text_[i] != '=') fail(name_, where(i), "malformed attribute");
        ++i;
        skip_ws();
        if (i >= text_.size() || (text_[i] != '"' && text_[i] != '\'')) fail(name_, where(i), "unquoted attribute");
        const char quote = text_[i++];
        const std::size_t value_end = text_.find(quote, i);
        if (value_end == std::string_view::npos) fail(name_, where(i), "unterminated attribute value");
        tag.attributes.emplace_back(key, text_.substr(i, value_end - i));
        i = value_end + 1;
      }
      tag.end = i;
      return tag;
    }
  }

  // Base64 decoded in groups of four characters; padding ends a group, so independently encoded blocks (header and
  // data written separately, as VTK does) decode as well as one stream.
  std::string base64(std::string_view content, std::size_t content_at) const {
    std::string out;
    out.reserve(content.size() / 4 * 3 + 3);
    int group[4];
    int n = 0, pad = 0;
    for (std::size_t i = 0; i < content.size(); ++i) {
      const char c = content[i];
      if (std::isspace(static_cast<unsigned char>(c))) continue;
      int v;
      if (c >= 'A' && c <= 'Z') {
        v = c - 'A';
      } else if (c >= 'a' && c <= 'z') {
        v = c - 'a' + 26;
      } else if (c >= '0' && c <= '9') {
        v = c - '0' + 52;
      } else if (c == '+') {
        v = 62;
      } else if (c == '/') {
        v = 63;
      } else if (c == '=' && n >= 2) {
        v = 0;
        ++pad;
      } else {
        fail(name_, where(content_at + i), "invalid base64 character in binary DataArray");
      }
      if (pad > 0 && c != '=') fail(name_, where(content_at + i), "base64 data after padding inside a group");
      group[n++] = v;
      if (n == 4) {
        const unsigned bits = (static_cast<unsigned>(group[0]) << 18) | (static_cast<unsigned>(group[1]) << 12) |
                              (static_cast<unsigned>(group[2]) << 6) | static_cast<unsigned>(group[3]);
        out.push_back(static_cast<char>((bits >> 16) & 0xff));
        if (pad < 2) out.push_back(static_cast<char>((bits >> 8) & 0xff));
        if (pad < 1) out.push_back(static_cast<char>(bits & 0xff));
        n = 0;
        pad = 0;
      }
    }
    if (n != 0) fail(name_, where(content_at + content.size()), "base64 data ends inside a group of four");
    return out;
  }

  std::string_view text_;
  const std::string& name_;
  std::uint64_t max_inflated_bytes_;
  std::uint64_t inflated_ = 0;  // bytes the compressed arrays decoded so far inflated to
  bool big_endian_ = false;
  enum class Compressor { kNone, kZlib, kLz4, kLzma };
  Compressor compressor_ = Compressor::kNone;
  std::size_t header_size_ = 4;
  std::optional<std::size_t> appended_at_;  // first byte after <AppendedData ...> _
  bool appended_base64_ = false;
  const bool surface_cells_;
  // One cell list (Cells, Polys or Strips) of a piece, with the piece's points and the cells it declares.
  struct PieceCells {
    CellList cells;
    std::int64_t points = 0, declared = 0;
  };
  std::vector<PieceCells> cell_lists_;
};

}  // namespace

ParticleFrame parse_vtk_points(std::string_view bytes, const std::string& name, bool surface_cells) {
  return LegacyReader(bytes, name, surface_cells).read();
}

ParticleFrame parse_vtu_points(std::string_view bytes, const std::string& name, std::uint64_t max_inflated_bytes,
                               bool surface_cells) {
  return XmlReader(bytes, name, max_inflated_bytes, surface_cells).read();
}

}  // namespace surfacer::particle_io_detail
