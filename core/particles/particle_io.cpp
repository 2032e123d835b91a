// Particle file readers (core/particles/particle_io.h). Every read is bounds-checked against the bytes present; counts
// from headers only cap reservations by what the remaining bytes could hold.
#include "core/particles/particle_io.h"

#include <zlib.h>

#include <algorithm>
#include <bit>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <optional>
#include <vector>

#include "core/particles/particle_io_detail.h"
#include "core/util/errors.h"

namespace surfacer {
namespace particle_io_detail {

[[noreturn]] void fail(const std::string& name, const std::string& where, const std::string& what) {
  throw InvalidInput("file", name + ": " + where + ": " + what);
}

std::string line_at(std::size_t line) { return "line " + std::to_string(line); }

std::string byte_at(std::size_t offset) { return "byte " + std::to_string(offset); }

std::size_t line_of(std::string_view text, std::size_t offset) {
  offset = std::min(offset, text.size());
  return 1 +
         static_cast<std::size_t>(std::count(text.begin(), text.begin() + static_cast<std::ptrdiff_t>(offset), '\n'));
}

std::string lower(std::string_view s) {
  std::string out(s);
  for (char& c : out) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return out;
}

bool is_radius_name(std::string_view name) {
  const std::string n = lower(name);
  return n == "radius" || n == "pscale";
}

void keep_attribute(ParticleFrame& frame, const std::string& name, std::int64_t components,
                    const std::vector<double>& values) {
  if (name.empty() || components < 1 || components > Attribute::kMaxComponents) return;
  const std::string n = lower(name);
  if (n == "x" || n == "y" || n == "z" || is_radius_name(n) || find_attribute(frame, name) != nullptr) return;
  Attribute attribute;
  attribute.name = name;
  attribute.components = static_cast<int>(components);
  attribute.values.assign(values.begin(), values.end());  // (float conversion; checked where they are used)
  frame.attributes.push_back(std::move(attribute));
}

std::optional<Scalar> scalar_from_name(std::string_view name) {
  const std::string n = lower(name);
  if (n == "char" || n == "int8") return Scalar::kI8;
  if (n == "uchar" || n == "uint8" || n == "unsigned_char") return Scalar::kU8;
  if (n == "short" || n == "int16") return Scalar::kI16;
  if (n == "ushort" || n == "uint16" || n == "unsigned_short") return Scalar::kU16;
  if (n == "int" || n == "int32") return Scalar::kI32;
  if (n == "uint" || n == "uint32" || n == "unsigned_int") return Scalar::kU32;
  if (n == "long" || n == "int64" || n == "vtktypeint64") return Scalar::kI64;
  if (n == "unsigned_long" || n == "uint64" || n == "vtktypeuint64") return Scalar::kU64;
  if (n == "float" || n == "float32") return Scalar::kF32;
  if (n == "double" || n == "float64") return Scalar::kF64;
  return std::nullopt;
}

std::size_t scalar_size(Scalar s) {
  switch (s) {
    case Scalar::kI8:
    case Scalar::kU8:
      return 1;
    case Scalar::kI16:
    case Scalar::kU16:
      return 2;
    case Scalar::kI32:
    case Scalar::kU32:
    case Scalar::kF32:
      return 4;
    case Scalar::kI64:
    case Scalar::kU64:
    case Scalar::kF64:
      return 8;
  }
  return 1;
}

double read_scalar(const char* p, Scalar s, bool big_endian) {
  unsigned char b[8];
  const std::size_t n = scalar_size(s);
  std::memcpy(b, p, n);
  if (big_endian != (std::endian::native == std::endian::big)) std::reverse(b, b + n);
  switch (s) {
    case Scalar::kI8:
      return static_cast<double>(static_cast<std::int8_t>(b[0]));
    case Scalar::kU8:
      return static_cast<double>(b[0]);
    case Scalar::kI16: {
      std::int16_t v;
      std::memcpy(&v, b, 2);
      return v;
    }
    case Scalar::kU16: {
      std::uint16_t v;
      std::memcpy(&v, b, 2);
      return v;
    }
    case Scalar::kI32: {
      std::int32_t v;
      std::memcpy(&v, b, 4);
      return v;
    }
    case Scalar::kU32: {
      std::uint32_t v;
      std::memcpy(&v, b, 4);
      return v;
    }
    case Scalar::kI64: {
      std::int64_t v;
      std::memcpy(&v, b, 8);
      return static_cast<double>(v);
    }
    case Scalar::kU64: {
      std::uint64_t v;
      std::memcpy(&v, b, 8);
      return static_cast<double>(v);
    }
    case Scalar::kF32: {
      float v;
      std::memcpy(&v, b, 4);
      return v;
    }
    case Scalar::kF64: {
      double v;
      std::memcpy(&v, b, 8);
      return v;
    }
  }
  return 0.0;
}

void TextCursor::skip_space() {
  while (pos < text.size()) {
    const char c = text[pos];
    if (c == '\n') {
      ++line;
    } else if (!(c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v')) {
      break;
    }
    ++pos;
  }
}

std::optional<std::string_view> TextCursor::next() {
  skip_space();
  if (pos >= text.size()) return std::nullopt;
  token_line = line;
  const std::size_t start = pos;
  while (pos < text.size()) {
    const char c = text[pos];
    if (c == ' ' || c == '\t' || c == '\r' || c == '\n' || c == '\f' || c == '\v') break;
    ++pos;
  }
  return text.substr(start, pos - start);
}

std::string_view TextCursor::expect(const std::string& what) {
  const std::optional<std::string_view> t = next();
  if (!t) fail(name, report_bytes ? byte_at(pos) : line_at(token_line), "unexpected end of file; expected " + what);
  return *t;
}

double TextCursor::number(const std::string& what) {
  const std::string_view t = expect(what);
  double v = 0.0;
  if (!parse_double(t, v)) fail(name, where(), quote(t) + " is not a number (" + what + ")");
  return v;
}

std::int64_t TextCursor::count(const std::string& what) {
  const std::string_view t = expect(what);
  std::int64_t v = 0;
  const auto r = std::from_chars(t.data(), t.data() + t.size(), v);
  if (r.ec != std::errc() || r.ptr != t.data() + t.size() || v < 0) {
    fail(name, where(), quote(t) + " is not a valid " + what);
  }
  return v;
}

void TextCursor::skip_line() {
  while (pos < text.size() && text[pos] != '\n') ++pos;
  if (pos < text.size()) {
    ++pos;
    ++line;
  }
}

std::string_view TextCursor::rest_of_line() {
  const std::size_t start = pos;
  while (pos < text.size() && text[pos] != '\n') ++pos;
  std::string_view l = text.substr(start, pos - start);
  if (pos < text.size()) {
    ++pos;
    ++line;
  }
  if (!l.empty() && l.back() == '\r') l.remove_suffix(1);
  return l;
}

void check_finite(const Vec3& p, const std::string& name, const std::string& where) {
  if (!p.allFinite()) fail(name, where, "non-finite coordinate");
}

std::size_t capped_reserve(std::int64_t declared, std::size_t bytes_left, std::size_t min_bytes_each) {
  const std::size_t cap = bytes_left / std::max<std::size_t>(1, min_bytes_each) + 1;
  return static_cast<std::size_t>(std::min<std::uint64_t>(static_cast<std::uint64_t>(declared), cap));
}

}  // namespace particle_io_detail

const Attribute* find_attribute(const ParticleFrame& frame, std::string_view name) {
  for (const Attribute& attribute : frame.attributes) {
    if (attribute.name == name) return &attribute;
  }
  return nullptr;
}

std::string attribute_list(const ParticleFrame& frame) {
  std::string list;
  for (const Attribute& attribute : frame.attributes) {
    list += (list.empty() ? "" : ", ") + attribute.name + " (" + std::to_string(attribute.components) + ")";
  }
  return list.empty() ? "none" : list;
}

namespace {

using namespace particle_io_detail;

bool is_gzip(std::string_view bytes) {
  return bytes.size() >= 2 && static_cast<unsigned char>(bytes[0]) == 0x1f &&
         static_cast<unsigned char>(bytes[1]) == 0x8b;
}

[[noreturn]] void too_many_bytes(const std::string& name, std::uint64_t max_bytes, const char* what) {
  throw ResourceLimit("file", name + ": " + what + " more than " + std::to_string(max_bytes) + " bytes (the limit)");
}

// Inflates gzip data (concatenated members are one stream) into `out` (capacity bytes), or, when `out` is null,
// only counts what it inflates to (through a small scratch buffer), stopping once that passes `max_bytes`. Returns
// the inflated size.
std::uint64_t inflate_all(std::string_view bytes, const std::string& name, std::uint64_t max_bytes, char* out,
                          std::uint64_t capacity) {
  z_stream zs{};
  if (inflateInit2(&zs, 16 + MAX_WBITS) != Z_OK) throw Internal("zlib inflateInit2 failed");
  struct End {
    z_stream& zs;
    ~End() { inflateEnd(&zs); }
  } end{zs};
  std::vector<char> scratch(out == nullptr ? std::size_t{1} << 18 : 0);
  std::uint64_t produced = 0;
  std::size_t consumed = 0;
  while (true) {
    if (produced > max_bytes) too_many_bytes(name, max_bytes, "its gzip data inflates to");
    char* const target = out != nullptr ? out + produced : scratch.data();
    const std::uint64_t room = out != nullptr ? capacity - produced : scratch.size();
    const std::size_t in_chunk = std::min<std::size_t>(bytes.size() - consumed, 1u << 30);
    const std::size_t out_chunk = static_cast<std::size_t>(std::min<std::uint64_t>(room, 1u << 30));
    zs.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(bytes.data() + consumed));
    zs.avail_in = static_cast<uInt>(in_chunk);
    zs.next_out = reinterpret_cast<Bytef*>(target);
    zs.avail_out = static_cast<uInt>(out_chunk);
    const int status = inflate(&zs, Z_NO_FLUSH);
    consumed += in_chunk - zs.avail_in;
    produced += out_chunk - zs.avail_out;
    if (status == Z_STREAM_END) {
      if (consumed < bytes.size() && is_gzip(bytes.substr(consumed))) {
        inflateReset(&zs);
        continue;
      }
      break;
    }
    if (status == Z_OK) continue;
    if (status == Z_BUF_ERROR && zs.avail_out == 0 && out_chunk > 0) continue;
    const std::string message = zs.msg != nullptr ? zs.msg : "";
    if (status == Z_BUF_ERROR) fail(name, byte_at(consumed) + " of the gzip data", "truncated gzip stream");
    fail(name, byte_at(consumed) + " of the gzip data",
         "corrupt gzip stream" + (message.empty() ? "" : ": " + message));
  }
  if (produced > max_bytes) too_many_bytes(name, max_bytes, "its gzip data inflates to");
  return produced;
}

// Inflates gzip data into at most `max_bytes`. The data is inflated twice: first only counted, so a bomb is refused
// having allocated nothing, then into a buffer of exactly its size (never a larger one, nor a copy while growing).
std::string gunzip(std::string_view bytes, const std::string& name, std::uint64_t max_bytes) {
  const std::uint64_t size = inflate_all(bytes, name, max_bytes, nullptr, 0);
  std::string out;
  try {
    out.resize(static_cast<std::size_t>(size) + 1);  // one spare byte: room for inflate() to see the end
  } catch (const std::bad_alloc&) {
    throw ResourceLimit(
        "file", name + ": its gzip data inflates to " + std::to_string(size) + " bytes, more memory than there is");
  }
  const std::uint64_t again = inflate_all(bytes, name, max_bytes, out.data(), out.size());
  if (again != size) throw Internal(name + ": gzip data inflated to two different sizes");
  out.resize(static_cast<std::size_t>(size));
  return out;
}

// --- .xyz / .txt / .csv ---------------------------------------------------------------------------------------------

// Text particle files hold no control bytes but white space; splashsurf's .xyz (raw float32 triples) is full of them.
void refuse_binary_text(std::string_view text, const std::string& name) {
  const std::string_view head = text.substr(0, 4096);
  for (std::size_t i = 0; i < head.size(); ++i) {
    const auto c = static_cast<unsigned char>(head[i]);
    if ((c < 0x20 && c != '\t' && c != '\n' && c != '\r' && c != '\f' && c != '\v') || c == 0x7f) {
      fail(name, byte_at(i),
           "binary data in a text particle file (.xyz/.txt/.csv are \"x y z [r]\" lines); if this is splashsurf's "
           "binary .xyz (raw little-endian float32 x y z triples), rename it to .bin, which Surfacer reads as "
           "exactly that");
    }
  }
}

ParticleFrame parse_xyz(std::string_view text, const std::string& name) {
  refuse_binary_text(text, name);
  ParticleFrame frame;
  frame.positions.reserve(text.size() / 8);
  std::size_t pos = 0, line_no = 0;
  std::size_t columns = 0;  // 0 until the first content line
  int cx = 0, cy = 1, cz = 2, cr = -1;
  std::vector<std::pair<std::string, int>> named;  // the header's other columns: scalar attributes
  std::vector<std::vector<double>> named_values;
  std::vector<std::string_view> tokens;
  while (pos < text.size()) {
    std::size_t eol = text.find('\n', pos);
    if (eol == std::string_view::npos) eol = text.size();
    std::string_view line = text.substr(pos, eol - pos);
    pos = eol + 1;
    ++line_no;
    if (const std::size_t hash = line.find('#'); hash != std::string_view::npos) line = line.substr(0, hash);
    tokens.clear();
    std::size_t i = 0;
    while (i < line.size()) {
      while (i < line.size() && (std::isspace(static_cast<unsigned char>(line[i])) || line[i] == ',')) ++i;
      const std::size_t start = i;
      while (i < line.size() && !std::isspace(static_cast<unsigned char>(line[i])) && line[i] != ',') ++i;
      if (i > start) tokens.push_back(line.substr(start, i - start));
    }
    if (tokens.empty()) continue;
    if (columns == 0) {
      double probe = 0.0;
      if (!parse_double(tokens[0], probe)) {
        // A header of column names.
        cx = cy = cz = cr = -1;
        for (std::size_t c = 0; c < tokens.size(); ++c) {
          const std::string n = lower(tokens[c]);
          const int ci = static_cast<int>(c);
          if (n == "x" && cx < 0) cx = ci;
          if (n == "y" && cy < 0) cy = ci;
          if (n == "z" && cz < 0) cz = ci;
          if ((n == "radius" || n == "pscale" || n == "r") && cr < 0) cr = ci;
        }
        for (std::size_t c = 0; c < tokens.size(); ++c) {
          const int ci = static_cast<int>(c);
          if (ci != cx && ci != cy && ci != cz && ci != cr) named.emplace_back(std::string(tokens[c]), ci);
        }
        if (cx < 0 || cy < 0 || cz < 0) {
          fail(name, line_at(line_no),
               quote(tokens[0]) + " is not a number, and as a header line the columns do not name x, y and z");
        }
        columns = tokens.size();
        continue;
      }
      if (tokens.size() != 3 && tokens.size() != 4) {
        fail(name, line_at(line_no), "expected 3 or 4 values (x y z [radius]), got " + std::to_string(tokens.size()));
      }
      columns = tokens.size();
      cr = columns == 4 ? 3 : -1;
    }
    if (tokens.size() != columns) {
      fail(name, line_at(line_no),
           "expected " + std::to_string(columns) + " values like the first line, got " + std::to_string(tokens.size()));
    }
    auto value = [&](int c) {
      double v = 0.0;
      if (!parse_double(tokens[static_cast<std::size_t>(c)], v)) {
        fail(name, line_at(line_no),
             quote(tokens[static_cast<std::size_t>(c)]) + " is not a number (column " + std::to_string(c + 1) + ")");
      }
      if (!std::isfinite(v)) fail(name, line_at(line_no), "non-finite value in column " + std::to_string(c + 1));
      return v;
    };
    frame.positions.emplace_back(value(cx), value(cy), value(cz));
    if (cr >= 0) frame.radii.push_back(value(cr));
    named_values.resize(named.size());
    for (std::size_t a = 0; a < named.size(); ++a) {
      double v = 0.0;
      // A column that is not numbers throughout (names, tags) is no attribute.
      if (named[a].second >= 0 && parse_double(tokens[static_cast<std::size_t>(named[a].second)], v)) {
        named_values[a].push_back(v);
      } else {
        named[a].second = -1;
      }
    }
  }
  named_values.resize(named.size());  // a header without data rows names columns that have no values
  for (std::size_t a = 0; a < named.size(); ++a) {
    if (named[a].second >= 0) keep_attribute(frame, named[a].first, 1, named_values[a]);
  }
  return frame;
}

// --- .bin ------------------------------------------------------------------------------------------------------------

ParticleFrame parse_bin(std::string_view bytes, const std::string& name) {
  if (bytes.size() % 12 != 0) {
    fail(
        name, byte_at(bytes.size() - bytes.size() % 12),
        std::to_string(bytes.size() % 12) + " trailing bytes: a .bin file holds float32 x y z triples (12 bytes each)");
  }
  ParticleFrame frame;
  frame.positions.resize(bytes.size() / 12);
  for (std::size_t i = 0; i < frame.positions.size(); ++i) {
    const char* p = bytes.data() + 12 * i;
    Vec3 v(read_scalar(p, Scalar::kF32, false), read_scalar(p + 4, Scalar::kF32, false),
           read_scalar(p + 8, Scalar::kF32, false));
    check_finite(v, name, byte_at(12 * i));
    frame.positions[i] = v;
  }
  return frame;
}

// --- .bgeo (Houdini classic) -------------------------------------------------------------------------------------

class BigEndianReader {
 public:
  BigEndianReader(std::string_view bytes, const std::string& name) : bytes_(bytes), name_(name) {}
  std::size_t pos() const { return pos_; }
  std::size_t left() const { return bytes_.size() - pos_; }
  void need(std::size_t n, const std::string& what) const {
    if (left() < n) {
      fail(name_, byte_at(pos_),
           "truncated " + what + " (needs " + std::to_string(n) + " bytes, " + std::to_string(left()) + " left)");
    }
  }
  std::int32_t i32(const std::string& what) {
    need(4, what);
    const double v = read_scalar(bytes_.data() + pos_, Scalar::kI32, true);
    pos_ += 4;
    return static_cast<std::int32_t>(v);
  }
  std::uint16_t u16(const std::string& what) {
    need(2, what);
    const double v = read_scalar(bytes_.data() + pos_, Scalar::kU16, true);
    pos_ += 2;
    return static_cast<std::uint16_t>(v);
  }
  std::string_view take(std::size_t n, const std::string& what) {
    need(n, what);
    const std::string_view s = bytes_.substr(pos_, n);
    pos_ += n;
    return s;
  }
  const char* at() const { return bytes_.data() + pos_; }
  void skip(std::size_t n, const std::string& what) { take(n, what); }

 private:
  std::string_view bytes_;
  const std::string& name_;
  std::size_t pos_ = 0;
};

ParticleFrame parse_bgeo(std::string_view bytes, const std::string& name) {
  BigEndianReader in(bytes, name);
  const std::string_view magic = in.take(4, "header (magic)");
  if (magic != "Bgeo") {
    if (magic == std::string_view("\x7fNSJ", 4)) {
      fail(name, byte_at(0),
           "this is the new (JSON-based) BGEO format; only classic BGEO is supported (save as .bhclassic from "
           "Houdini, or write with Partio)");
    }
    fail(name, byte_at(0), "not a classic BGEO file (magic is not 'Bgeo')");
  }
  if (in.take(1, "header (version)")[0] != 'V') fail(name, byte_at(4), "expected 'V' after the magic");
  const std::size_t version_at = in.pos();
  const std::int32_t version = in.i32("header (version)");
  if (version != 5)
    fail(name, byte_at(version_at), "BGEO version " + std::to_string(version) + " (only 5 is supported)");
  const std::size_t counts_at = in.pos();
  std::int32_t counts[9];
  static const char* const kCountNames[9] = {"points",
                                             "primitives",
                                             "point groups",
                                             "primitive groups",
                                             "point attributes",
                                             "vertex attributes",
                                             "primitive attributes",
                                             "detail attributes",
                                             ""};
  for (int c = 0; c < 8; ++c) {
    counts[c] = in.i32("header (counts)");
    if (counts[c] < 0) {
      fail(name, byte_at(counts_at + 4 * static_cast<std::size_t>(c)),
           std::string("negative number of ") + kCountNames[c] + " (" + std::to_string(counts[c]) + ")");
    }
  }
  const std::int64_t points = counts[0];
  const std::int32_t point_attributes = counts[4];

  // Point attribute dictionary: every attribute adds `size` 32-bit words to each point record after x y z w.
  std::size_t words = 4;
  std::optional<std::size_t> radius_word;
  struct Kept {
    std::string name;
    std::size_t word = 0, size = 0;
    bool integer = false;
  };
  std::vector<Kept> kept;  // float, int and vector attributes: ParticleFrame::attributes
  for (std::int32_t a = 0; a < point_attributes; ++a) {
    const std::string what = "point attribute " + std::to_string(a);
    const std::uint16_t name_length = in.u16(what + " name length");
    const std::string attribute(in.take(name_length, what + " name"));
    const std::size_t size_at = in.pos();
    const std::uint16_t size = in.u16(what + " size");
    const std::int32_t type = in.i32(what + " type");
    if (type == 0 || type == 1 || type == 5) {  // float, int, vector: `size` default words
      in.skip(4u * size, what + " defaults");
    } else if (type == 4) {  // indexed string: a table of strings, `size` int words per point
      const std::size_t table_at = in.pos();
      const std::int32_t strings = in.i32(what + " string count");
      if (strings < 0) fail(name, byte_at(table_at), "negative string count for attribute '" + attribute + "'");
      for (std::int32_t s = 0; s < strings; ++s) in.skip(in.u16(what + " string length"), what + " string");
    } else {
      fail(name, byte_at(size_at + 2),
           "point attribute '" + attribute + "' has type " + std::to_string(type) +
               (type == 2 ? " (string), which classic BGEO readers cannot skip" : ", which is unknown"));
    }
    if ((attribute == "pscale" || attribute == "radius") && type == 0 && size == 1 && !radius_word) {
      radius_word = words;
    } else if (type == 0 || type == 1 || type == 5) {
      kept.push_back({attribute, words, size, type == 1});
    }
    words += size;
  }

  const std::size_t record = 4 * words;
  ParticleFrame frame;
  const std::size_t data_at = in.pos();
  if (static_cast<std::uint64_t>(points) * record > in.left()) {
    const std::size_t whole = in.left() / record;
    fail(name, byte_at(data_at + whole * record),
         "truncated point " + std::to_string(whole) + " of " + std::to_string(points) + " (needs " +
             std::to_string(record) + " bytes, " + std::to_string(in.left() - whole * record) + " left)");
  }
  frame.positions.resize(static_cast<std::size_t>(points));
  if (radius_word) frame.radii.resize(static_cast<std::size_t>(points));
  for (std::size_t i = 0; i < frame.positions.size(); ++i) {
    const char* p = in.at();
    Vec3 v(read_scalar(p, Scalar::kF32, true), read_scalar(p + 4, Scalar::kF32, true),
           read_scalar(p + 8, Scalar::kF32, true));
    check_finite(v, name, byte_at(in.pos()) + " (point " + std::to_string(i) + ")");
    frame.positions[i] = v;
    if (radius_word) frame.radii[i] = read_scalar(p + 4 * *radius_word, Scalar::kF32, true);
    in.skip(record, "point");
  }
  std::vector<double> values;
  for (const Kept& k : kept) {
    if (k.size < 1 || k.size > static_cast<std::size_t>(Attribute::kMaxComponents)) continue;
    values.resize(frame.positions.size() * k.size);
    const char* base = in.at() - frame.positions.size() * record;
    for (std::size_t i = 0; i < frame.positions.size(); ++i) {
      for (std::size_t c = 0; c < k.size; ++c) {
        values[i * k.size + c] =
            read_scalar(base + i * record + 4 * (k.word + c), k.integer ? Scalar::kI32 : Scalar::kF32, true);
      }
    }
    keep_attribute(frame, k.name, static_cast<std::int64_t>(k.size), values);
  }
  // Primitives, groups and detail attributes follow; a particle frame needs none of them.
  return frame;
}

}  // namespace

ParticleFormat particle_format_from_path(const std::filesystem::path& path) {
  std::filesystem::path p = path;
  if (lower(p.extension().string()) == ".gz") p = p.stem();
  const std::string ext = lower(p.extension().string());
  if (ext == ".xyz" || ext == ".txt" || ext == ".csv") return ParticleFormat::kXyz;
  if (ext == ".ply") return ParticleFormat::kPly;
  if (ext == ".vtk") return ParticleFormat::kVtk;
  if (ext == ".vtu" || ext == ".vtp") return ParticleFormat::kVtu;  // VTK XML UnstructuredGrid or PolyData
  if (ext == ".bin") return ParticleFormat::kBin;
  if (ext == ".bgeo" || ext == ".bhclassic") return ParticleFormat::kBgeo;
  if (ext == ".json") return ParticleFormat::kJson;
  throw InvalidInput("file", path.string() + ": unknown particle file extension '" + ext +
                                 "'; use .xyz, .txt, .csv, .ply, .vtk, .vtu, .vtp, .bin, .bgeo, .bhclassic or .json "
                                 "(optionally .gz)");
}

namespace {

ParticleFrame parse_format(std::string_view bytes, ParticleFormat format, const std::string& name,
                           const ParticleReadLimits& limits) {
  switch (format) {
    case ParticleFormat::kXyz:
      return parse_xyz(bytes, name);
    case ParticleFormat::kPly:
      return parse_ply_points(bytes, name);
    case ParticleFormat::kVtk:
      return parse_vtk_points(bytes, name);
    case ParticleFormat::kVtu:
      return parse_vtu_points(bytes, name, limits.max_bytes);
    case ParticleFormat::kBin:
      return parse_bin(bytes, name);
    case ParticleFormat::kBgeo:
      return parse_bgeo(bytes, name);
    case ParticleFormat::kJson:
      return parse_json_points(bytes, name);
  }
  throw Internal("unknown particle format");
}

[[noreturn]] void too_many_particles(const std::string& name, std::uint64_t count, std::int64_t max_particles) {
  throw ResourceLimit("file", name + ": " + std::to_string(count) + " particles, more than " +
                                  std::to_string(max_particles) + " (the limit)");
}

}  // namespace

ParticleFrame parse_particles(std::string_view bytes, ParticleFormat format, const std::string& name_for_errors,
                              const ParticleReadLimits& limits) {
  std::string inflated;
  if (is_gzip(bytes)) {
    inflated = gunzip(bytes, name_for_errors, limits.max_bytes);
    bytes = inflated;
  } else if (bytes.size() > limits.max_bytes) {
    too_many_bytes(name_for_errors, limits.max_bytes, "it holds");
  }
  // A raw file tells its count by its size: refused before parsing.
  if (format == ParticleFormat::kBin && bytes.size() / 12 > static_cast<std::uint64_t>(limits.max_particles)) {
    too_many_particles(name_for_errors, bytes.size() / 12, limits.max_particles);
  }
  ParticleFrame frame = parse_format(bytes, format, name_for_errors, limits);
  if (frame.positions.size() > static_cast<std::uint64_t>(limits.max_particles)) {
    too_many_particles(name_for_errors, frame.positions.size(), limits.max_particles);
  }
  return frame;
}

ParticleFrame read_particles(const std::filesystem::path& path, const ParticleReadLimits& limits) {
  const ParticleFormat format = particle_format_from_path(path);
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InvalidInput("file", path.string() + ": cannot open for reading: " + std::strerror(errno));
  // A plain file is its data: one over the limit is not read at all (gzip data is checked as it inflates).
  std::error_code ec;
  const std::uintmax_t size = std::filesystem::file_size(path, ec);
  char magic[2] = {0, 0};
  in.read(magic, 2);
  const bool gzip = in.gcount() == 2 && is_gzip(std::string_view(magic, 2));
  // Deflate never grows data by more than a fraction of a percent (plus a few bytes a member): gzip data much larger
  // than the limit cannot inflate within it.
  const std::uint64_t max_bytes = std::min(limits.max_bytes, std::uint64_t{1} << 62);
  const std::uint64_t max_file = gzip ? max_bytes + max_bytes / 64 + (std::uint64_t{1} << 16) : max_bytes;
  if (!ec && size > max_file) {
    if (!gzip) too_many_bytes(path.string(), max_bytes, "it holds");
    throw ResourceLimit("file", path.string() + ": its gzip data (" + std::to_string(size) +
                                    " bytes) cannot inflate to " + std::to_string(max_bytes) +
                                    " bytes or less (the limit)");
  }
  in.clear();
  in.seekg(0);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) throw InvalidInput("file", path.string() + ": read error");
  return parse_particles(bytes, format, path.string(), limits);
}

std::vector<std::filesystem::path> expand_sequence(const std::string& pattern, int start, int end) {
  if (end < start) {
    throw InvalidInput("end", "end (" + std::to_string(end) + ") must be >= start (" + std::to_string(start) + ")");
  }
  if (static_cast<std::int64_t>(end) - start >= 1000000) {
    throw ResourceLimit("end", "at most 10^6 frames per sequence (start " + std::to_string(start) + ", end " +
                                   std::to_string(end) + ")");
  }
  std::string prefix, suffix;
  int placeholders = 0;
  int width = 0;
  char fill = ' ';
  for (std::size_t i = 0; i < pattern.size(); ++i) {
    std::string& out = placeholders == 0 ? prefix : suffix;
    const char c = pattern[i];
    if (c == '{' && i + 1 < pattern.size() && pattern[i + 1] == '{') {
      out += '{';
      ++i;
    } else if (c == '}' && i + 1 < pattern.size() && pattern[i + 1] == '}') {
      out += '}';
      ++i;
    } else if (c == '{') {
      const std::size_t close = pattern.find('}', i);
      if (close == std::string::npos) {
        throw InvalidInput("pattern", "pattern '" + pattern + "' has an unclosed '{'; use {} or {:04d}");
      }
      const std::string spec = pattern.substr(i + 1, close - i - 1);
      if (!spec.empty()) {
        // ":Nd" or ":0Nd"
        bool ok = spec.size() >= 3 && spec.front() == ':' && spec.back() == 'd';
        std::string digits = ok ? spec.substr(1, spec.size() - 2) : "";
        char f = ' ';
        if (ok && digits.size() > 1 && digits[0] == '0') {
          f = '0';
          digits.erase(0, 1);
        }
        int w = 0;
        if (ok) {
          const auto r = std::from_chars(digits.data(), digits.data() + digits.size(), w);
          ok = r.ec == std::errc() && r.ptr == digits.data() + digits.size() && w >= 1 && w <= 18 && digits[0] != '+';
        }
        if (!ok) {
          throw InvalidInput("pattern", "pattern '" + pattern + "' has an unsupported placeholder '{" + spec +
                                            "}'; use {} or {:0Nd} (e.g. {:04d})");
        }
        width = w;
        fill = f;
      }
      ++placeholders;
      i = close;
    } else if (c == '}') {
      throw InvalidInput("pattern", "pattern '" + pattern + "' has an unmatched '}'; write '}}' for a literal brace");
    } else {
      out += c;
    }
  }
  if (placeholders != 1) {
    throw InvalidInput("pattern", "pattern '" + pattern +
                                      "' must contain exactly one frame placeholder ({} or {:04d}), "
                                      "found " +
                                      std::to_string(placeholders));
  }
  std::vector<std::filesystem::path> paths;
  paths.reserve(static_cast<std::size_t>(end - start) + 1);
  for (std::int64_t f = start; f <= end; ++f) {
    std::string digits = std::to_string(f < 0 ? -f : f);
    std::string number;
    const std::size_t len = digits.size() + (f < 0 ? 1 : 0);
    const std::size_t pad = static_cast<std::size_t>(width) > len ? static_cast<std::size_t>(width) - len : 0;
    if (fill != '0') number.append(pad, ' ');
    if (f < 0) number += '-';
    if (fill == '0') number.append(pad, '0');
    number += digits;
    paths.emplace_back(prefix + number + suffix);
  }
  return paths;
}

}  // namespace surfacer
