#include "core/mesh/ply.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>

#include "core/util/errors.h"
#include "core/util/format.h"
#include "core/util/text.h"

namespace surfacer::ply {
namespace {

[[noreturn]] void fail(const std::string& name, const std::string& where, const std::string& what) {
  throw InvalidInput("file", name + ": " + where + ": " + what);
}

std::string line_at(std::size_t line) { return "line " + std::to_string(line); }

}  // namespace

std::optional<Type> type_from_name(std::string_view name) {
  if (name == "char" || name == "int8") return Type::kInt8;
  if (name == "uchar" || name == "uint8") return Type::kUint8;
  if (name == "short" || name == "int16") return Type::kInt16;
  if (name == "ushort" || name == "uint16") return Type::kUint16;
  if (name == "int" || name == "int32") return Type::kInt32;
  if (name == "uint" || name == "uint32") return Type::kUint32;
  if (name == "int64") return Type::kInt64;
  if (name == "uint64") return Type::kUint64;
  if (name == "float" || name == "float32") return Type::kFloat32;
  if (name == "double" || name == "float64") return Type::kFloat64;
  return std::nullopt;
}

std::size_t type_size(Type type) {
  switch (type) {
    case Type::kInt8:
    case Type::kUint8:
      return 1;
    case Type::kInt16:
    case Type::kUint16:
      return 2;
    case Type::kInt32:
    case Type::kUint32:
    case Type::kFloat32:
      return 4;
    case Type::kInt64:
    case Type::kUint64:
    case Type::kFloat64:
      return 8;
  }
  return 1;
}

bool integral(Type type) { return type != Type::kFloat32 && type != Type::kFloat64; }

int Element::find(std::initializer_list<std::string_view> names) const {
  for (std::string_view wanted : names) {
    for (std::size_t p = 0; p < properties.size(); ++p) {
      if (properties[p].name == wanted) return static_cast<int>(p);
    }
  }
  return -1;
}

std::string Location::text() const { return (binary ? "byte " : "line ") + std::to_string(at); }

std::string item_text(const Element& element, std::uint64_t index) {
  const bool named = element.name == "vertex" || element.name == "face";
  return (named ? element.name : "element " + quote(element.name) + " item") + " " + std::to_string(index);
}

Header parse_header(std::string_view bytes, const std::string& name) {
  Header header;
  LineReader lines(bytes);
  std::string_view line;
  std::vector<std::string_view> tok;
  if (!lines.next(line) || line != "ply") fail(name, line_at(1), "not a PLY file (the first line must be 'ply')");
  bool have_format = false;
  while (true) {
    if (!lines.next(line)) {
      fail(name, line_at(lines.line() + 1), "unexpected end of file in the PLY header (no 'end_header')");
    }
    tokenize(line, tok);
    const std::string where = line_at(lines.line());
    if (tok.empty() || tok[0] == "comment" || tok[0] == "obj_info") continue;
    if (tok[0] == "end_header") break;
    if (tok[0] == "format") {
      if (tok.size() < 2) fail(name, where, "expected 'format <ascii|binary_little_endian|binary_big_endian> 1.0'");
      if (tok[1] == "ascii") {
        header.format = Format::kAscii;
      } else if (tok[1] == "binary_little_endian") {
        header.format = Format::kBinaryLittle;
      } else if (tok[1] == "binary_big_endian") {
        header.format = Format::kBinaryBig;
      } else {
        fail(name, where, "unknown PLY format " + quote(tok[1]));
      }
      have_format = true;
    } else if (tok[0] == "element") {
      std::int64_t count = 0;
      if (tok.size() != 3 || !parse_int(tok[2], count) || count < 0) {
        fail(name, where, "expected 'element <name> <count>' with a count >= 0");
      }
      header.elements.push_back({std::string(tok[1]), static_cast<std::uint64_t>(count), {}, lines.line()});
    } else if (tok[0] == "property") {
      if (header.elements.empty()) fail(name, where, "property before any element");
      Property property;
      if (tok.size() == 5 && tok[1] == "list") {
        const auto count_type = type_from_name(tok[2]);
        const auto item_type = type_from_name(tok[3]);
        if (!count_type || !item_type || !integral(*count_type)) {
          fail(name, where, "bad list property types " + quote(std::string(tok[2]) + " " + std::string(tok[3])));
        }
        property = {std::string(tok[4]), *item_type, true, *count_type};
      } else if (tok.size() == 3) {
        const auto type = type_from_name(tok[1]);
        if (!type) fail(name, where, "unknown property type " + quote(tok[1]));
        property = {std::string(tok[2]), *type, false, Type::kUint8};
      } else {
        fail(name, where, "expected 'property <type> <name>' or 'property list <count type> <type> <name>'");
      }
      header.elements.back().properties.push_back(std::move(property));
    } else {
      fail(name, where, "unknown header keyword " + quote(tok[0]));
    }
  }
  if (!have_format) fail(name, line_at(lines.line()), "the PLY header has no format line");
  header.data_offset = lines.pos();
  header.data_line = lines.line() + 1;
  return header;
}

namespace {

// Values of the list the reader asked for must be whole numbers (they are indices).
bool whole(double v) { return v == std::floor(v); }

void read_ascii(std::string_view bytes, const Header& header, ElementReader& reader, const std::string& name) {
  LineReader lines(bytes.substr(header.data_offset));
  const std::size_t line_base = header.data_line - 1;
  std::string_view line;
  std::vector<std::string_view> tok;
  std::vector<double> scalars;
  std::vector<double> list;
  for (const Element& e : header.elements) {
    reader.begin(e, (bytes.size() - header.data_offset) / 2 + 1);
    const int wanted = reader.list_property(e);
    scalars.assign(e.properties.size(), 0.0);
    for (std::uint64_t i = 0; i < e.count; ++i) {
      do {
        if (!lines.next(line)) {
          fail(name, line_at(line_base + lines.line() + 1),
               "unexpected end of file: expected " + item_text(e, i) + " of " + std::to_string(e.count));
        }
        tokenize(line, tok);
      } while (tok.empty());
      const Location where{false, line_base + lines.line()};
      std::size_t t = 0;
      for (std::size_t p = 0; p < e.properties.size(); ++p) {
        const Property& property = e.properties[p];
        if (!property.list) {
          if (t >= tok.size()) {
            fail(name, where.text(),
                 "expected " + std::to_string(e.properties.size()) + " numbers for " + item_text(e, i) + ", found " +
                     std::to_string(tok.size()));
          }
          if (!parse_double(tok[t], scalars[p])) {
            fail(name, where.text(), "bad number " + quote(tok[t]) + " for " + item_text(e, i));
          }
          ++t;
          continue;
        }
        std::int64_t count = 0;
        if (t >= tok.size() || !parse_int(tok[t], count) || count < 0) {
          fail(name, where.text(), "expected a list length for property " + property.name + " of " + item_text(e, i));
        }
        ++t;
        if (static_cast<std::uint64_t>(count) > tok.size() - t) {
          fail(name, where.text(),
               "list " + property.name + " of " + item_text(e, i) + " announces " + std::to_string(count) +
                   " values but the line has " + std::to_string(tok.size() - t));
        }
        const bool keep = static_cast<int>(p) == wanted;
        if (keep) list.clear();
        for (std::int64_t k = 0; k < count; ++k, ++t) {
          double value = 0.0;
          if (!parse_double(tok[t], value) || (keep && !whole(value))) {
            fail(name, where.text(),
                 "bad value " + quote(tok[t]) + " in list " + property.name + " of " + item_text(e, i));
          }
          if (keep) list.push_back(value);
        }
      }
      if (t != tok.size()) {
        fail(name, where.text(),
             "found " + std::to_string(tok.size()) + " values for " + item_text(e, i) + ", expected " +
                 std::to_string(t));
      }
      reader.item(e, Item{i, scalars, list, where});
    }
    if (reader.last(e)) return;
  }
}

class BinaryReader {
 public:
  BinaryReader(std::string_view bytes, std::size_t pos, bool big_endian, const std::string& name)
      : bytes_(bytes), pos_(pos), swap_(big_endian != (std::endian::native == std::endian::big)), name_(name) {}

  std::size_t pos() const { return pos_; }
  std::size_t remaining() const { return bytes_.size() - pos_; }

  // Truncation errors name the first byte of the item being read.
  void start_item() { item_start_ = pos_; }
  [[noreturn]] void truncated(const Element& e, std::uint64_t i, const std::string& detail = "") const {
    fail(name_, "byte " + std::to_string(item_start_),
         "unexpected end of file in " + item_text(e, i) + " of " + std::to_string(e.count) + detail);
  }

  void skip(std::size_t n) { pos_ += n; }

  double read(Type type, const Element& e, std::uint64_t i) {
    const std::size_t size = type_size(type);
    if (size > remaining()) truncated(e, i);
    unsigned char raw[8];
    std::memcpy(raw, bytes_.data() + pos_, size);
    pos_ += size;
    if (swap_) std::reverse(raw, raw + size);
    switch (type) {
      case Type::kInt8:
        return static_cast<double>(static_cast<std::int8_t>(raw[0]));
      case Type::kUint8:
        return static_cast<double>(raw[0]);
      case Type::kInt16:
        return static_cast<double>(load<std::int16_t>(raw));
      case Type::kUint16:
        return static_cast<double>(load<std::uint16_t>(raw));
      case Type::kInt32:
        return static_cast<double>(load<std::int32_t>(raw));
      case Type::kUint32:
        return static_cast<double>(load<std::uint32_t>(raw));
      case Type::kInt64:
        return static_cast<double>(load<std::int64_t>(raw));
      case Type::kUint64:
        return static_cast<double>(load<std::uint64_t>(raw));
      case Type::kFloat32:
        return static_cast<double>(load<float>(raw));
      case Type::kFloat64:
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
  std::size_t item_start_ = 0;
  bool swap_;
  const std::string& name_;
};

void read_binary(std::string_view bytes, const Header& header, ElementReader& reader, const std::string& name) {
  BinaryReader in(bytes, header.data_offset, header.format == Format::kBinaryBig, name);
  std::vector<double> scalars;
  std::vector<double> list;
  for (const Element& e : header.elements) {
    std::size_t min_bytes = 0;
    bool fixed = true;
    for (const Property& p : e.properties) {
      min_bytes += p.list ? type_size(p.count_type) : type_size(p.type);
      fixed = fixed && !p.list;
    }
    reader.begin(e, in.remaining() / std::max<std::size_t>(min_bytes, 1) + 1);
    const int wanted = reader.list_property(e);
    scalars.assign(e.properties.size(), 0.0);
    if (fixed && min_bytes > 0 && e.count > in.remaining() / min_bytes) {
      // Too short for the declared items: name the first item that does not fit.
      const std::uint64_t whole_items = in.remaining() / min_bytes;
      in.skip(whole_items * min_bytes);
      in.start_item();
      in.truncated(e, whole_items);
    }
    for (std::uint64_t i = 0; i < e.count; ++i) {
      if (min_bytes == 0) break;  // an element without properties: nothing to read
      in.start_item();
      const Location where{true, in.pos()};
      for (std::size_t p = 0; p < e.properties.size(); ++p) {
        const Property& property = e.properties[p];
        if (!property.list) {
          scalars[p] = in.read(property.type, e, i);
          continue;
        }
        const std::size_t count_at = in.pos();
        const double count = in.read(property.count_type, e, i);
        if (count < 0) fail(name, "byte " + std::to_string(count_at), "negative list length in " + item_text(e, i));
        // Compared as a double before the cast: a 64-bit count can exceed what std::uint64_t holds once rounded.
        if (count > static_cast<double>(in.remaining() / type_size(property.type))) {
          in.truncated(e, i, " (list of " + format_number(count) + ")");
        }
        const auto n = static_cast<std::uint64_t>(count);
        const bool keep = static_cast<int>(p) == wanted;
        if (keep) list.resize(n);
        for (std::uint64_t k = 0; k < n; ++k) {
          const double value = in.read(property.type, e, i);
          if (keep) {
            if (!whole(value)) {
              fail(name, where.text(),
                   "bad value " + format_number(value) + " in list " + property.name + " of " + item_text(e, i));
            }
            list[k] = value;
          }
        }
      }
      reader.item(e, Item{i, scalars, list, where});
    }
    if (reader.last(e)) return;
  }
}

}  // namespace

void read_data(std::string_view bytes, const Header& header, ElementReader& reader, const std::string& name) {
  if (header.format == Format::kAscii) {
    read_ascii(bytes, header, reader, name);
  } else {
    read_binary(bytes, header, reader, name);
  }
}

std::string attribute_property(const std::string& name, int components, int c) {
  static const char kAxes[] = "xyzw";
  const std::string token = token_name(name);  // one token: white space as %20
  return components == 1 ? token : token + "_" + kAxes[c];
}

std::vector<AttributeProperties> attribute_properties(const Element& element, const std::function<bool(int)>& taken) {
  constexpr std::size_t kMaxRun = 4;
  const auto& props = element.properties;
  auto free = [&](std::size_t p) { return !props[p].list && !taken(static_cast<int>(p)); };
  std::vector<AttributeProperties> out;
  for (std::size_t p = 0; p < props.size();) {
    if (!free(p)) {
      ++p;
      continue;
    }
    const std::string& first = props[p].name;
    const std::size_t cut = first.rfind('_');
    const std::string suffix = cut == std::string::npos ? "" : first.substr(cut);
    std::size_t run = 1;
    if (cut > 0 && (suffix == "_x" || suffix == "_0")) {
      const std::string base = first.substr(0, cut);
      const char* const axes = suffix == "_x" ? "xyzw" : "0123";
      while (run < kMaxRun && p + run < props.size() && free(p + run) &&
             props[p + run].name == base + "_" + axes[run]) {
        ++run;
      }
      if (run > 1) {
        AttributeProperties group{token_name_decoded(base), {}};
        for (std::size_t c = 0; c < run; ++c) group.properties.push_back(static_cast<int>(p + c));
        out.push_back(std::move(group));
        p += run;
        continue;
      }
    }
    out.push_back({token_name_decoded(first), {static_cast<int>(p)}});
    ++p;
  }
  return out;
}

}  // namespace surfacer::ply
