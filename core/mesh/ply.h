// The one PLY reader: the header, then every element's items in order, ASCII or binary (either byte order). Mesh files
// (core/mesh/mesh_io.h) and particle point clouds (core/particles/particle_io.h) both read through it and differ only
// in which properties they take. Counts from the header are never trusted: every read is bounds-checked and
// reservation hints are capped by what the remaining bytes can hold, so truncated or hostile files fail with
// InvalidInput("file", "<name>: line N: ..." or "<name>: byte N: ..."), never a crash or a huge allocation.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <initializer_list>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace surfacer::ply {

enum class Type { kInt8, kUint8, kInt16, kUint16, kInt32, kUint32, kInt64, kUint64, kFloat32, kFloat64 };

// PLY type names (char uchar short ushort int uint float double) and sized ones (int8 ... float64, int64, uint64).
std::optional<Type> type_from_name(std::string_view name);
std::size_t type_size(Type type);
bool integral(Type type);

struct Property {
  std::string name;
  Type type = Type::kFloat32;  // the item type of a list
  bool list = false;
  Type count_type = Type::kUint8;
};

struct Element {
  std::string name;
  std::uint64_t count = 0;
  std::vector<Property> properties;
  std::size_t header_line = 0;  // where the element is declared

  // Index of the first property named one of `names` (in the order given), or -1.
  int find(std::initializer_list<std::string_view> names) const;
};

enum class Format { kAscii, kBinaryLittle, kBinaryBig };

struct Header {
  Format format = Format::kAscii;
  std::vector<Element> elements;
  std::size_t data_offset = 0;  // first byte after "end_header\n"
  std::size_t data_line = 0;    // line number of the first data line
};

// Per-vertex (per-point) attributes as PLY properties: a scalar is one property NAME; a vector of 2 to 4 components
// is NAME_x NAME_y [NAME_z [NAME_w]] in a row (what Houdini, CloudCompare and splashsurf write). The property of
// component c of an attribute `name` with `components` components:
std::string attribute_property(const std::string& name, int components, int c);
// The element's attributes: every non-list property for which `taken` is false, runs NAME_x NAME_y ... (or NAME_0
// NAME_1 ...) of up to 4 grouped into one vector NAME; each with its property indices, in file order. Names are one
// token each: attribute_property() writes white space and '%' as %XX (core/util/text.h token_name) and
// attribute_properties() decodes them.
struct AttributeProperties {
  std::string name;
  std::vector<int> properties;
};
std::vector<AttributeProperties> attribute_properties(const Element& element, const std::function<bool(int)>& taken);

// Throws InvalidInput("file") naming the line: not a PLY file, an unknown keyword, format or type, a malformed line,
// no format line, no end_header.
Header parse_header(std::string_view bytes, const std::string& name);

// Where an item was read, for messages: "line N" (ASCII) or "byte N" (binary, the item's first byte).
struct Location {
  bool binary = false;
  std::size_t at = 0;
  std::string text() const;
};

// One item of an element as read: the values of its scalar properties by property index (lists leave 0 there) and the
// values of the one list property the reader asked for.
struct Item {
  std::uint64_t index = 0;
  std::span<const double> scalars;
  std::span<const double> list;
  Location where;
};

// What a caller does with the data; read_data() calls, for each element in order: begin(), then item() per item.
class ElementReader {
 public:
  virtual ~ElementReader() = default;
  // Before the element's items. `capacity` bounds how many items the remaining bytes can hold (a safe reservation).
  virtual void begin(const Element& /*element*/, std::size_t /*capacity*/) {}
  // The list property (index) whose values Item::list carries, or -1 (lists are then only skipped). Its values must
  // be whole numbers (indices): anything else is an error naming the item.
  virtual int list_property(const Element& /*element*/) const { return -1; }
  virtual void item(const Element& element, const Item& item) = 0;
  // True: stop reading after this element (what follows is not needed).
  virtual bool last(const Element& /*element*/) const { return false; }
};

// Reads the data after the header. ASCII items are one per line (blank lines skipped), with exactly the values the
// header declares. Throws InvalidInput("file") naming the line or byte: unexpected end of file, a bad number, a
// negative list length, too many or too few values; and whatever the reader throws.
void read_data(std::string_view bytes, const Header& header, ElementReader& reader, const std::string& name);

// "vertex 3" / "face 3" / "element 'edge' item 3" (as messages name items).
std::string item_text(const Element& element, std::uint64_t index);

}  // namespace surfacer::ply
