// PLY point clouds for core/particles/particle_io.h: the "vertex" element's x, y, z and optional radius/pscale.
#include <limits>
#include <vector>

#include "core/particles/particle_io_detail.h"

namespace surfacer::particle_io_detail {
namespace {

struct Property {
  std::string name;
  Scalar type = Scalar::kF32;
  bool list = false;
  Scalar count_type = Scalar::kU8;
};

struct Element {
  std::string name;
  std::int64_t count = 0;
  std::vector<Property> properties;
};

enum class Encoding { kAscii, kLittle, kBig };

std::vector<std::string_view> split(std::string_view line) {
  std::vector<std::string_view> out;
  std::size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && (line[i] == ' ' || line[i] == '\t')) ++i;
    const std::size_t start = i;
    while (i < line.size() && line[i] != ' ' && line[i] != '\t') ++i;
    if (i > start) out.push_back(line.substr(start, i - start));
  }
  return out;
}

}  // namespace

ParticleFrame parse_ply_points(std::string_view bytes, const std::string& name) {
  TextCursor header{bytes, name};
  if (header.rest_of_line() != "ply") fail(name, line_at(1), "not a PLY file (the first line must be 'ply')");
  std::optional<Encoding> encoding;
  std::vector<Element> elements;
  while (true) {
    if (header.pos >= bytes.size()) fail(name, line_at(header.line), "header ends without 'end_header'");
    const std::size_t line_no = header.line;
    const std::vector<std::string_view> t = split(header.rest_of_line());
    if (t.empty()) continue;
    if (t[0] == "end_header") break;
    if (t[0] == "comment" || t[0] == "obj_info") continue;
    if (t[0] == "format") {
      if (t.size() != 3)
        fail(name, line_at(line_no), "expected 'format <ascii|binary_little_endian|binary_big_endian> 1.0'");
      if (t[1] == "ascii") {
        encoding = Encoding::kAscii;
      } else if (t[1] == "binary_little_endian") {
        encoding = Encoding::kLittle;
      } else if (t[1] == "binary_big_endian") {
        encoding = Encoding::kBig;
      } else {
        fail(name, line_at(line_no), "unknown PLY format '" + std::string(t[1]) + "'");
      }
    } else if (t[0] == "element") {
      std::int64_t count = -1;
      if (t.size() == 3) {
        double c = 0.0;
        if (parse_number(t[2], c) && c >= 0.0 && c == std::floor(c) && c < 9.0e18) count = static_cast<std::int64_t>(c);
      }
      if (count < 0) fail(name, line_at(line_no), "expected 'element <name> <count>' with a count >= 0");
      elements.push_back({std::string(t[1]), count, {}});
    } else if (t[0] == "property") {
      if (elements.empty()) fail(name, line_at(line_no), "property before any element");
      Property p;
      if (t.size() == 5 && t[1] == "list") {
        const auto ct = scalar_from_name(t[2]);
        const auto it = scalar_from_name(t[3]);
        if (!ct || !it || *ct == Scalar::kF32 || *ct == Scalar::kF64) {
          fail(name, line_at(line_no), "bad list property types '" + std::string(t[2]) + " " + std::string(t[3]) + "'");
        }
        p = {std::string(t[4]), *it, true, *ct};
      } else if (t.size() == 3) {
        const auto type = scalar_from_name(t[1]);
        if (!type) fail(name, line_at(line_no), "unknown property type '" + std::string(t[1]) + "'");
        p = {std::string(t[2]), *type, false, Scalar::kU8};
      } else {
        fail(name, line_at(line_no), "expected 'property <type> <name>' or 'property list <count type> <type> <name>'");
      }
      elements.back().properties.push_back(p);
    } else {
      fail(name, line_at(line_no), "unknown header keyword '" + std::string(t[0].substr(0, 40)) + "'");
    }
  }
  if (!encoding) fail(name, line_at(header.line - 1), "header has no 'format' line");

  std::size_t vertex = elements.size();
  for (std::size_t e = 0; e < elements.size(); ++e) {
    if (elements[e].name == "vertex") {
      vertex = e;
      break;
    }
  }
  if (vertex == elements.size()) fail(name, line_at(header.line - 1), "header declares no 'vertex' element");
  const Element& v = elements[vertex];
  int ix = -1, iy = -1, iz = -1, ir = -1;
  for (std::size_t p = 0; p < v.properties.size(); ++p) {
    const Property& prop = v.properties[p];
    if (prop.list) continue;
    const int pi = static_cast<int>(p);
    if (prop.name == "x" && ix < 0) ix = pi;
    if (prop.name == "y" && iy < 0) iy = pi;
    if (prop.name == "z" && iz < 0) iz = pi;
    if (is_radius_name(prop.name) && ir < 0) ir = pi;
  }
  if (ix < 0 || iy < 0 || iz < 0) fail(name, line_at(header.line - 1), "element 'vertex' lacks an x, y or z property");

  ParticleFrame frame;
  const std::size_t data_at = header.pos;
  std::vector<double> values(v.properties.size(), 0.0);

  if (*encoding == Encoding::kAscii) {
    TextCursor in{bytes, name, data_at, header.line};
    auto read_instance = [&](const Element& e, std::int64_t i, bool keep) {
      const std::string what = "element '" + e.name + "' " + std::to_string(i) + " of " + std::to_string(e.count);
      for (std::size_t p = 0; p < e.properties.size(); ++p) {
        const Property& prop = e.properties[p];
        if (prop.list) {
          const double n = in.number(what);
          if (!(n >= 0.0) || n != std::floor(n)) fail(name, line_at(in.line), "bad list length in " + what);
          for (double k = 0; k < n; ++k) in.number(what);
        } else {
          const double x = in.number(what);
          if (keep) values[p] = x;
        }
      }
    };
    for (std::size_t e = 0; e < vertex; ++e) {
      for (std::int64_t i = 0; i < elements[e].count; ++i) read_instance(elements[e], i, false);
    }
    frame.positions.reserve(capped_reserve(v.count, bytes.size() - data_at, 6));
    if (ir >= 0) frame.radii.reserve(frame.positions.capacity());
    for (std::int64_t i = 0; i < v.count; ++i) {
      read_instance(v, i, true);
      const Vec3 p(values[static_cast<std::size_t>(ix)], values[static_cast<std::size_t>(iy)],
                   values[static_cast<std::size_t>(iz)]);
      check_finite(p, name, line_at(in.line) + " (vertex " + std::to_string(i) + ")");
      frame.positions.push_back(p);
      if (ir >= 0) frame.radii.push_back(values[static_cast<std::size_t>(ir)]);
    }
    return frame;
  }

  const bool big = *encoding == Encoding::kBig;
  std::size_t pos = data_at;
  auto read_instance = [&](const Element& e, std::int64_t i, bool keep) {
    for (std::size_t p = 0; p < e.properties.size(); ++p) {
      const Property& prop = e.properties[p];
      auto truncated = [&] {
        fail(name, byte_at(pos),
             "truncated element '" + e.name + "' " + std::to_string(i) + " of " + std::to_string(e.count));
      };
      if (prop.list) {
        const std::size_t cs = scalar_size(prop.count_type);
        if (bytes.size() - pos < cs) truncated();
        const double n = read_scalar(bytes.data() + pos, prop.count_type, big);
        if (n < 0.0) fail(name, byte_at(pos), "negative list length in element '" + e.name + "'");
        pos += cs;
        const double need = n * static_cast<double>(scalar_size(prop.type));
        if (need > static_cast<double>(bytes.size() - pos)) truncated();
        pos += static_cast<std::size_t>(need);
      } else {
        const std::size_t s = scalar_size(prop.type);
        if (bytes.size() - pos < s) truncated();
        if (keep) values[p] = read_scalar(bytes.data() + pos, prop.type, big);
        pos += s;
      }
    }
  };
  for (std::size_t e = 0; e < vertex; ++e) {
    const Element& el = elements[e];
    bool fixed = true;
    std::size_t record = 0;
    for (const Property& prop : el.properties) {
      fixed = fixed && !prop.list;
      record += scalar_size(prop.type);
    }
    if (fixed) {
      if (record > 0 && static_cast<std::uint64_t>(el.count) > (bytes.size() - pos) / record) {
        const std::size_t whole = (bytes.size() - pos) / record;
        pos += whole * record;
        fail(name, byte_at(pos),
             "truncated element '" + el.name + "' " + std::to_string(whole) + " of " + std::to_string(el.count));
      }
      pos += record * static_cast<std::size_t>(el.count);
    } else {
      for (std::int64_t i = 0; i < el.count; ++i) read_instance(el, i, false);
    }
  }
  frame.positions.reserve(capped_reserve(v.count, bytes.size() - pos, 3));
  if (ir >= 0) frame.radii.reserve(frame.positions.capacity());
  for (std::int64_t i = 0; i < v.count; ++i) {
    const std::size_t at = pos;
    read_instance(v, i, true);
    const Vec3 p(values[static_cast<std::size_t>(ix)], values[static_cast<std::size_t>(iy)],
                 values[static_cast<std::size_t>(iz)]);
    check_finite(p, name, byte_at(at) + " (vertex " + std::to_string(i) + ")");
    frame.positions.push_back(p);
    if (ir >= 0) frame.radii.push_back(values[static_cast<std::size_t>(ir)]);
  }
  return frame;
}

}  // namespace surfacer::particle_io_detail
