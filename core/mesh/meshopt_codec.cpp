#include "core/mesh/meshopt_codec.h"

#include <meshoptimizer.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "core/util/errors.h"

namespace surfacer {
namespace {

constexpr std::uint8_t kNormalsFlag = 1;
constexpr std::uint8_t kAttributesFlag = 2;

// Index codec version 1 (smaller on our meshes); the decoder reads either. Set once, before any encode.
void use_index_codec_v1() {
  static const bool once = [] {
    meshopt_encodeIndexVersion(1);
    return true;
  }();
  (void)once;
}

void put_u32(std::string& out, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) out.push_back(static_cast<char>(v >> (8 * i) & 0xffu));
}

void put_stream(std::string& out, const std::vector<unsigned char>& stream, std::size_t size) {
  put_u32(out, static_cast<std::uint32_t>(size));
  out.append(reinterpret_cast<const char*>(stream.data()), size);
}

[[noreturn]] void bad(const std::string& what) { throw InvalidInput("frame", "a meshopt piece " + what); }

struct Reader {
  std::string_view bytes;
  std::size_t at = 0;
  std::uint32_t u32() {
    if (bytes.size() - at < 4) bad("is truncated");
    std::uint32_t v = 0;
    for (int i = 0; i < 4; ++i) v |= std::uint32_t{static_cast<unsigned char>(bytes[at + i])} << (8 * i);
    at += 4;
    return v;
  }
  std::uint8_t u8() {
    if (at >= bytes.size()) bad("is truncated");
    return static_cast<std::uint8_t>(bytes[at++]);
  }
  std::string_view stream() {
    const std::uint32_t size = u32();
    if (bytes.size() - at < size) bad("is truncated");
    const std::string_view s = bytes.substr(at, size);
    at += size;
    return s;
  }
};

template <class T>
std::size_t encode_vertices(std::vector<unsigned char>& out, const std::vector<T>& values, std::size_t count) {
  constexpr std::size_t stride = sizeof(T);
  out.resize(meshopt_encodeVertexBufferBound(count, stride));
  const std::size_t size = meshopt_encodeVertexBuffer(out.data(), out.size(), values.data(), count, stride);
  if (size == 0 && count > 0) throw Internal("meshopt vertex encoder failed");
  return size;
}

// Float attributes: `components` floats a vertex, one meshopt vertex of 4 x components bytes (lossless).
std::size_t encode_floats(std::vector<unsigned char>& out, const std::vector<float>& values, int components,
                          std::size_t count) {
  const std::size_t stride = sizeof(float) * static_cast<std::size_t>(components);
  out.resize(meshopt_encodeVertexBufferBound(count, stride));
  const std::size_t size = meshopt_encodeVertexBuffer(out.data(), out.size(), values.data(), count, stride);
  if (size == 0 && count > 0) throw Internal("meshopt vertex encoder failed");
  return size;
}

template <class T>
void decode_vertices(std::vector<T>& values, std::size_t count, std::string_view stream, const char* what) {
  values.resize(count);
  if (count == 0) return;
  if (meshopt_decodeVertexBuffer(values.data(), count, sizeof(T), reinterpret_cast<const unsigned char*>(stream.data()),
                                 stream.size()) != 0) {
    bad(std::string("has a malformed ") + what + " stream");
  }
}

// Octahedral mapping of a unit vector to [-1, 1]^2 and back.
std::array<double, 2> octahedral(const Vec3& n) {
  const double l1 = std::abs(n.x()) + std::abs(n.y()) + std::abs(n.z());
  if (!(l1 > 0.0)) return {0.0, 0.0};
  double x = n.x() / l1, y = n.y() / l1;
  if (n.z() < 0.0) {
    const double ox = (1.0 - std::abs(y)) * (x >= 0.0 ? 1.0 : -1.0);
    const double oy = (1.0 - std::abs(x)) * (y >= 0.0 ? 1.0 : -1.0);
    x = ox;
    y = oy;
  }
  return {x, y};
}

Vec3 from_octahedral(double x, double y) {
  Vec3 n(x, y, 1.0 - std::abs(x) - std::abs(y));
  if (n.z() < 0.0) {
    const double ox = (1.0 - std::abs(y)) * (x >= 0.0 ? 1.0 : -1.0);
    const double oy = (1.0 - std::abs(x)) * (y >= 0.0 ? 1.0 : -1.0);
    n.x() = ox;
    n.y() = oy;
  }
  const double len = n.norm();
  return len > 0.0 ? Vec3(n / len) : n;
}

// An octahedral normal as stored: x and y on normal_bits bits.
struct Normal {
  std::int16_t x, y;
};

// Grid x, y, z and the seam tag: one meshopt vertex.
template <class T>
struct PackedVertex {
  T x, y, z, tag;
};

template <class T>
std::vector<PackedVertex<T>> pack_vertices(const QuantizedPiece& piece) {
  std::vector<PackedVertex<T>> values(piece.positions.size());
  for (std::size_t v = 0; v < values.size(); ++v) {
    const auto& q = piece.positions[v];
    values[v] = {static_cast<T>(q[0]), static_cast<T>(q[1]), static_cast<T>(q[2]),
                 static_cast<T>(piece.seam_tags.empty() ? 0 : piece.seam_tags[v])};
  }
  return values;
}

template <class T>
void unpack_vertices(QuantizedPiece& piece, std::size_t nv, std::string_view stream, std::uint32_t max_value) {
  std::vector<PackedVertex<T>> values;
  decode_vertices(values, nv, stream, "vertex");
  piece.positions.resize(nv);
  piece.seam_tags.resize(nv);
  for (std::size_t v = 0; v < nv; ++v) {
    const PackedVertex<T>& in = values[v];
    if (in.x > max_value || in.y > max_value || in.z > max_value || in.tag > 0xffffu) bad("has a vertex off the grid");
    piece.positions[v] = {in.x, in.y, in.z};
    piece.seam_tags[v] = static_cast<std::uint16_t>(in.tag);
  }
}

}  // namespace

std::string encode_meshopt_piece(const QuantizedPiece& piece, int grid_bits, int normal_bits) {
  use_index_codec_v1();
  const std::size_t nv = piece.positions.size();
  const std::size_t nt = piece.triangles.size();
  const bool normals = !piece.normals.empty();
  std::string out;
  put_u32(out, static_cast<std::uint32_t>(nv));
  put_u32(out, static_cast<std::uint32_t>(nt));
  const bool attributes = !piece.attributes.empty();
  if (piece.attributes.size() > 255) throw InvalidInput("attributes", "more than 255 attributes");
  out.push_back(static_cast<char>((normals ? kNormalsFlag : 0) | (attributes ? kAttributesFlag : 0)));
  std::vector<unsigned char> stream;
  if (grid_bits <= 16) {
    put_stream(out, stream, encode_vertices(stream, pack_vertices<std::uint16_t>(piece), nv));
  } else {
    put_stream(out, stream, encode_vertices(stream, pack_vertices<std::uint32_t>(piece), nv));
  }
  stream.resize(meshopt_encodeIndexBufferBound(3 * nt, nv));
  const std::size_t index_size = meshopt_encodeIndexBuffer(
      stream.data(), stream.size(), reinterpret_cast<const std::uint32_t*>(piece.triangles.data()), 3 * nt);
  if (index_size == 0 && nt > 0) throw Internal("meshopt index encoder failed");
  put_stream(out, stream, index_size);
  if (normals) {
    const int bits = std::clamp(normal_bits, 2, 16);
    const double scale = std::ldexp(1.0, bits - 1) - 1.0;
    std::vector<Normal> values(nv);
    for (std::size_t v = 0; v < nv; ++v) {
      const auto o = octahedral(piece.normals[v]);
      values[v] = {static_cast<std::int16_t>(std::lround(o[0] * scale)),
                   static_cast<std::int16_t>(std::lround(o[1] * scale))};
    }
    put_stream(out, stream, encode_vertices(stream, values, nv));
    out.push_back(static_cast<char>(bits));
  }
  if (attributes) {
    out.push_back(static_cast<char>(piece.attributes.size()));
    for (const Attribute& a : piece.attributes) {
      if (a.components < 1 || a.components > Attribute::kMaxComponents ||
          a.values.size() != nv * static_cast<std::size_t>(a.components)) {
        throw InvalidInput("attributes", "a piece's attribute " + a.name + " does not hold 1 to " +
                                             std::to_string(Attribute::kMaxComponents) + " values per vertex");
      }
      out.push_back(static_cast<char>(a.components));
      put_stream(out, stream, encode_floats(stream, a.values, a.components, nv));
    }
  }
  return out;
}

MeshoptStreams meshopt_streams(std::string_view bytes) {
  Reader in{bytes};
  MeshoptStreams s;
  s.vertices = in.u32();
  s.triangles = in.u32();
  const std::uint8_t flags = in.u8();
  if (flags & ~(kNormalsFlag | kAttributesFlag)) bad("has unknown flags");
  s.vertex = in.stream();
  s.index = in.stream();
  // Bounds before anyone allocates: a vertex takes at least 1/16 byte of its stream, a triangle at least half a byte.
  const std::size_t nv = s.vertices, nt = s.triangles;
  if (nv > 16 * s.vertex.size() + 256 || nt > 2 * s.index.size() + 16 || nv > 3 * nt) {
    bad("claims " + std::to_string(nv) + " vertices and " + std::to_string(nt) + " triangles its streams cannot hold");
  }
  if (flags & kNormalsFlag) {
    s.normal = in.stream();
    s.normal_bits = in.u8();
    if (s.normal_bits < 2 || s.normal_bits > 16) bad("has normals of " + std::to_string(s.normal_bits) + " bits");
  }
  if (flags & kAttributesFlag) {
    const std::uint8_t count = in.u8();
    if (count == 0) bad("has an empty attribute list");
    for (std::uint8_t a = 0; a < count; ++a) {
      const int components = in.u8();
      if (components < 1 || components > Attribute::kMaxComponents) {
        bad("has an attribute of " + std::to_string(components) + " components");
      }
      s.attributes.push_back({components, in.stream()});
    }
  }
  if (in.at != bytes.size()) bad("has trailing bytes");
  return s;
}

QuantizedPiece decode_meshopt_piece(std::string_view bytes, int grid_bits) {
  const MeshoptStreams s = meshopt_streams(bytes);
  const std::size_t nv = s.vertices, nt = s.triangles;
  QuantizedPiece piece;
  const std::uint32_t max_value = (std::uint32_t{1} << grid_bits) - 1u;
  if (grid_bits <= 16) {
    unpack_vertices<std::uint16_t>(piece, nv, s.vertex, max_value);
  } else {
    unpack_vertices<std::uint32_t>(piece, nv, s.vertex, max_value);
  }
  piece.triangles.resize(nt);
  if (nt > 0 &&
      meshopt_decodeIndexBuffer(reinterpret_cast<std::uint32_t*>(piece.triangles.data()), 3 * nt, sizeof(std::uint32_t),
                                reinterpret_cast<const unsigned char*>(s.index.data()), s.index.size()) != 0) {
    bad("has a malformed index stream");
  }
  for (const Triangle& t : piece.triangles) {
    if (t[0] >= nv || t[1] >= nv || t[2] >= nv) bad("has a triangle that uses a missing vertex");
  }
  if (s.normal_bits > 0) {
    std::vector<Normal> values;
    decode_vertices(values, nv, s.normal, "normal");
    const double scale = std::ldexp(1.0, s.normal_bits - 1) - 1.0;
    piece.normals.resize(nv);
    for (std::size_t v = 0; v < nv; ++v) {
      piece.normals[v] =
          from_octahedral(std::clamp(values[v].x / scale, -1.0, 1.0), std::clamp(values[v].y / scale, -1.0, 1.0));
    }
  }
  for (const MeshoptStreams::AttributeStream& a : s.attributes) {
    Attribute& attribute = piece.attributes.emplace_back(Attribute{"", a.components, {}});
    attribute.values.resize(nv * static_cast<std::size_t>(a.components));
    if (nv > 0 &&
        meshopt_decodeVertexBuffer(attribute.values.data(), nv, sizeof(float) * a.components,
                                   reinterpret_cast<const unsigned char*>(a.stream.data()), a.stream.size()) != 0) {
      bad("has a malformed attribute stream");
    }
  }
  return piece;
}

std::string gltf_octahedral_normals(const MeshoptStreams& streams) {
  if (streams.normal_bits == 0) return {};
  std::vector<Normal> values;
  decode_vertices(values, streams.vertices, streams.normal, "normal");
  // The filter's K is 4..16 bits: fewer stored bits are rounded onto 4.
  const int bits = std::max(streams.normal_bits, 4);
  const int one = (1 << (bits - 1)) - 1;
  const double rescale = static_cast<double>(one) / ((1 << (streams.normal_bits - 1)) - 1);
  struct FilterInput {
    std::int16_t x, y, one, unused;
  };
  std::vector<FilterInput> filtered(values.size());
  for (std::size_t v = 0; v < values.size(); ++v) {
    filtered[v] = {static_cast<std::int16_t>(std::lround(values[v].x * rescale)),
                   static_cast<std::int16_t>(std::lround(values[v].y * rescale)), static_cast<std::int16_t>(one), 0};
  }
  std::vector<unsigned char> stream;
  const std::size_t size = encode_vertices(stream, filtered, filtered.size());
  return std::string(reinterpret_cast<const char*>(stream.data()), size);
}

}  // namespace surfacer
