// The pieced frame container (little-endian):
//   "SFPC", u8 version (2), u8 codec (1: Draco pieces, 2: meshopt pieces), u8 grid bits, u8 flags (bit 0: normals),
//   f32 grid origin x y z, f32 grid range, u32 pieces, u64 vertices and u64 triangles of the welded mesh,
//   per piece: u32 bytes, u32 vertices, u32 triangles, u32 points (what its decoder finds: a Draco piece may hold a
//   vertex as one point per fan), u32 min x y z and u32 max x y z of its points' grid coordinates (0 when it has
//   none), u8 Draco attribute ids of its position, normals and seam tags (255: none, and for meshopt pieces), u8 0;
//   then the pieces' bytes, in order. The directory says all a glTF file needs (to_gltf), so nothing is decoded to
//   write one.
// Version 3, written for meshes with Mesh::attributes (version 2 for the others, which earlier clients read): the
//   directory entry's last byte is the Draco id of the piece's first attribute (255: none, and for meshopt pieces;
//   the others follow it), and the directory is followed by the attributes' names: u8 count, per attribute u8
//   components, u16 name bytes, the name. Each piece holds its vertices' values, unnamed, in this order.
// Version 1 (per piece only bytes, vertices, triangles) is still read: frames an earlier server kept in a job store.
#include "core/mesh/frame_codec.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cstring>
#include <functional>
#include <limits>
#include <utility>
#include <vector>

#include "core/mesh/mesh_gltf.h"
#include "core/mesh/mesh_io.h"
#include "core/mesh/meshopt_codec.h"
#include "core/util/errors.h"
#include "core/util/json.h"
#include "core/util/parallel.h"

namespace surfacer {
namespace {

constexpr char kMagic[4] = {'S', 'F', 'P', 'C'};
constexpr std::uint8_t kVersion = 3;
constexpr std::uint8_t kVersionWithoutAttributes = 2;
constexpr std::uint8_t kNormalsFlag = 1;
constexpr std::size_t kMinPieceTriangles = 1024;
constexpr std::size_t kHeaderBytes = 4 + 4 + 16 + 4 + 16;
constexpr std::size_t kDirectoryEntryBytes[4] = {0, 12, 44, 44};  // by version
constexpr std::uint8_t kNoAttribute = 255;

std::uint8_t container_codec(FrameCodec codec) { return codec == FrameCodec::kDracoPieces ? 1 : 2; }

void put(std::string& out, const void* value, std::size_t size) {
  out.append(static_cast<const char*>(value), size);  // the targets are little-endian (x86-64, aarch64)
}
template <class T>
void put(std::string& out, T value) {
  put(out, &value, sizeof value);
}

[[noreturn]] void bad(const std::string& what) { throw InvalidInput("frame", "not a pieced frame: " + what); }

template <class T>
T get(std::string_view bytes, std::size_t& at) {
  if (bytes.size() - at < sizeof(T)) bad("truncated header");
  T value;
  std::memcpy(&value, bytes.data() + at, sizeof value);
  at += sizeof value;
  return value;
}

using GridPoint = std::array<std::uint32_t, 3>;

struct PieceEntry {
  std::uint32_t bytes = 0, vertices = 0, triangles = 0;
  // Version 2 on: what the piece's decoder finds, and its points' bounds on the grid.
  DracoPieceInfo found;
  GridPoint min{}, max{};
};

// The bounds of a piece's points (0 when it has none).
void set_bounds(const std::vector<GridPoint>& points, PieceEntry& e) {
  e.min = e.max = GridPoint{};
  if (points.empty()) return;
  e.min.fill(std::numeric_limits<std::uint32_t>::max());
  for (const GridPoint& q : points) {
    for (int a = 0; a < 3; ++a) {
      e.min[a] = std::min(e.min[a], q[a]);
      e.max[a] = std::max(e.max[a], q[a]);
    }
  }
}

std::uint8_t attribute_byte(int id) { return id < 0 ? kNoAttribute : static_cast<std::uint8_t>(id); }
int attribute_id(std::uint8_t byte) { return byte == kNoAttribute ? -1 : byte; }

struct Container {
  std::uint8_t version = 0;
  std::uint8_t codec = 0;
  bool normals = false;
  QuantizationGrid grid;
  std::uint64_t vertices = 0, triangles = 0;
  std::vector<PieceEntry> pieces;
  // Version 3: the attributes' names and components (no values), in the pieces' order.
  std::vector<Attribute> attributes;
  std::vector<std::string_view> payloads;
};

Container read_container(std::string_view bytes) {
  if (bytes.size() < kHeaderBytes || std::memcmp(bytes.data(), kMagic, 4) != 0) bad("no SFPC header");
  std::size_t at = 4;
  Container c;
  c.version = get<std::uint8_t>(bytes, at);
  if (c.version < 1 || c.version > kVersion) bad("unknown version " + std::to_string(c.version));
  c.codec = get<std::uint8_t>(bytes, at);
  c.grid.bits = get<std::uint8_t>(bytes, at);
  const auto flags = get<std::uint8_t>(bytes, at);
  if (c.codec != 1 && c.codec != 2) bad("unknown piece codec " + std::to_string(c.codec));
  if (c.grid.bits < 1 || c.grid.bits > 30) bad("grid of " + std::to_string(c.grid.bits) + " bits");
  if (flags & ~kNormalsFlag) bad("unknown flags");
  c.normals = flags & kNormalsFlag;
  for (float& o : c.grid.origin) o = get<float>(bytes, at);
  c.grid.range = get<float>(bytes, at);
  if (!std::all_of(c.grid.origin.begin(), c.grid.origin.end(), [](float o) { return std::isfinite(o); }) ||
      !(c.grid.range > 0.0f) || !std::isfinite(c.grid.range)) {
    bad("invalid quantization grid");
  }
  const auto count = get<std::uint32_t>(bytes, at);
  c.vertices = get<std::uint64_t>(bytes, at);
  c.triangles = get<std::uint64_t>(bytes, at);
  if ((bytes.size() - at) / kDirectoryEntryBytes[c.version] < count) {
    bad("directory of " + std::to_string(count) + " pieces");
  }
  c.pieces.resize(count);
  std::uint64_t payload = 0, triangles = 0;
  for (PieceEntry& e : c.pieces) {
    e.bytes = get<std::uint32_t>(bytes, at);
    e.vertices = get<std::uint32_t>(bytes, at);
    e.triangles = get<std::uint32_t>(bytes, at);
    if (c.version >= 2) {
      e.found.points = get<std::uint32_t>(bytes, at);
      for (std::uint32_t& m : e.min) m = get<std::uint32_t>(bytes, at);
      for (std::uint32_t& m : e.max) m = get<std::uint32_t>(bytes, at);
      e.found.position = attribute_id(get<std::uint8_t>(bytes, at));
      e.found.normal = attribute_id(get<std::uint8_t>(bytes, at));
      e.found.seam = attribute_id(get<std::uint8_t>(bytes, at));
      const auto last = get<std::uint8_t>(bytes, at);
      if (c.version >= 3) {
        e.found.attributes = attribute_id(last);
      } else if (last != 0) {
        bad("a directory entry with unknown fields");
      }
      for (int a = 0; a < 3; ++a) {
        if (e.min[a] > e.max[a] || e.max[a] > c.grid.max_value()) bad("a piece's bounds off the grid");
      }
      if (e.found.points < e.vertices) bad("a piece with fewer points than vertices");
      if (c.codec == 1 && e.triangles > 0 && e.found.position < 0) bad("a Draco piece without a position attribute");
    }
    payload += e.bytes;
    triangles += e.triangles;
    if (e.vertices > 3ull * e.triangles) bad("a piece with more vertices than its triangles use");
  }
  if (c.version >= 3) {
    const auto count = get<std::uint8_t>(bytes, at);
    for (std::uint8_t a = 0; a < count; ++a) {
      Attribute& attribute = c.attributes.emplace_back();
      attribute.components = get<std::uint8_t>(bytes, at);
      const auto length = get<std::uint16_t>(bytes, at);
      if (bytes.size() - at < length) bad("truncated attribute names");
      attribute.name = std::string(bytes.substr(at, length));
      at += length;
      if (attribute.components < 1 || attribute.components > Attribute::kMaxComponents || attribute.name.empty()) {
        bad("an attribute of " + std::to_string(attribute.components) + " components named '" + attribute.name + "'");
      }
    }
  }
  if (payload != bytes.size() - at) bad("pieces of " + std::to_string(payload) + " bytes after the directory");
  if (triangles != c.triangles || c.vertices > 3 * c.triangles) bad("piece counts disagree with the header");
  for (const PieceEntry& e : c.pieces) {
    c.payloads.push_back(bytes.substr(at, e.bytes));
    at += e.bytes;
  }
  return c;
}

// Draco options that put a mesh on `grid`: its cube (Draco takes the origin and longest side, i.e. this grid).
DracoOptions on_grid(const QuantizationGrid& grid, const Mesh& mesh) {
  Aabb cube;
  for (int c = 0; c < 3; ++c) {
    cube.min[c] = grid.origin[c];
    cube.max[c] = static_cast<double>(grid.origin[c]) + static_cast<double>(grid.range);
  }
  DracoOptions options;
  options.quantization_bits = grid.bits;
  options.quantization_bounds = cube;
  options.normals = !mesh.normals.empty();
  return options;
}

// Grid points dequantized in float32 may stick out of the grid's cube by an ulp; clamping moves them by less than a
// step, so they quantize to the same points.
Mesh clamped_to(const Mesh& mesh, const Aabb& cube) {
  Mesh clamped = mesh;
  for (Vec3& p : clamped.vertices) p = p.cwiseMax(cube.min).cwiseMin(cube.max);
  return clamped;
}

std::string encode_pieces(const Mesh& mesh, const FrameCodecOptions& options, int threads, const RunControl& control) {
  const QuantizationGrid grid = quantization_grid(mesh, options.draco, threads);
  check_attributes(mesh);
  if (mesh.attributes.size() > std::numeric_limits<std::uint8_t>::max()) {
    throw InvalidInput(
        "attributes", "a frame of " + std::to_string(mesh.attributes.size()) + " attributes; frames carry at most 255");
  }
  for (const Attribute& a : mesh.attributes) {
    if (a.name.empty() || a.name.size() > std::numeric_limits<std::uint16_t>::max()) {
      throw InvalidInput("attributes", "an attribute name of " + std::to_string(a.name.size()) +
                                           " bytes; frames carry names of 1 to 65535 bytes");
    }
  }
  control.check();
  MeshPieces cut(mesh, grid, options.max_piece_triangles, threads, control);
  const int n = cut.count();
  const bool normals = options.draco.normals && !mesh.normals.empty();
  std::vector<std::string> payloads(n);
  std::vector<PieceEntry> entries(n);
  std::atomic<int> done{0};
  parallel_for(n, threads, [&](int p) {
    control.check();
    QuantizedPiece piece = cut.take(p);
    if (!normals) piece.normals.clear();
    PieceEntry& e = entries[p];
    if (options.codec == FrameCodec::kDracoPieces) {
      payloads[p] = encode_draco_piece(piece, grid.bits, options.draco, &e.found);
    } else {
      payloads[p] = encode_meshopt_piece(piece, grid.bits, options.draco.normal_bits);
      e.found.points = piece.positions.size();
    }
    if (payloads[p].size() > std::numeric_limits<std::uint32_t>::max()) {
      throw ResourceLimit("max_piece_triangles", "a piece of over 4 GiB");
    }
    e.bytes = static_cast<std::uint32_t>(payloads[p].size());
    e.vertices = static_cast<std::uint32_t>(piece.positions.size());
    e.triangles = static_cast<std::uint32_t>(piece.triangles.size());
    if (e.found.points > 0) set_bounds(piece.positions, e);
    control.report("encode", static_cast<double>(done.fetch_add(1) + 1) / n);
  });
  const std::uint8_t version = mesh.attributes.empty() ? kVersionWithoutAttributes : kVersion;
  std::size_t total = kHeaderBytes + n * kDirectoryEntryBytes[version] + (version >= 3 ? 1 : 0);
  for (const Attribute& a : mesh.attributes) total += 3 + a.name.size();
  for (const std::string& p : payloads) total += p.size();
  std::string out;
  out.reserve(total);
  put(out, kMagic, 4);
  put(out, version);
  put(out, container_codec(options.codec));
  put(out, static_cast<std::uint8_t>(grid.bits));
  put(out, static_cast<std::uint8_t>(normals ? kNormalsFlag : 0));
  for (float o : grid.origin) put(out, o);
  put(out, grid.range);
  put(out, static_cast<std::uint32_t>(n));
  put(out, static_cast<std::uint64_t>(cut.vertices()));
  put(out, static_cast<std::uint64_t>(cut.triangles()));
  for (const PieceEntry& e : entries) {
    put(out, e.bytes);
    put(out, e.vertices);
    put(out, e.triangles);
    put(out, static_cast<std::uint32_t>(e.found.points));
    for (std::uint32_t m : e.min) put(out, m);
    for (std::uint32_t m : e.max) put(out, m);
    put(out, attribute_byte(e.found.position));
    put(out, attribute_byte(e.found.normal));
    put(out, attribute_byte(e.found.seam));
    put(out, version >= 3 ? attribute_byte(e.found.attributes) : std::uint8_t{0});
  }
  if (version >= 3) {
    put(out, static_cast<std::uint8_t>(mesh.attributes.size()));
    for (const Attribute& a : mesh.attributes) {
      put(out, static_cast<std::uint8_t>(a.components));
      put(out, static_cast<std::uint16_t>(a.name.size()));
      put(out, a.name.data(), a.name.size());
    }
  }
  for (const std::string& p : payloads) out += p;
  return out;
}

Mesh decode_pieces(std::string_view bytes, FrameCodec codec, int threads) {
  const Container c = read_container(bytes);
  if (c.codec != container_codec(codec)) bad("its pieces are not " + std::string(frame_codec_name(codec)));
  const int n = static_cast<int>(c.pieces.size());
  std::vector<QuantizedPiece> pieces(n);
  parallel_for(n, threads, [&](int p) {
    QuantizedPiece& piece = pieces[p];
    PieceEntry found;
    if (c.codec == 1) {
      piece = decode_draco_piece(c.payloads[p], c.grid.bits, &found.found);
    } else {
      piece = decode_meshopt_piece(c.payloads[p], c.grid.bits);
      found.found.points = piece.positions.size();
    }
    if (c.version >= 2) {
      set_bounds(piece.positions, found);
      const PieceEntry& e = c.pieces[p];
      if (found.found != e.found || found.min != e.min || found.max != e.max) {
        bad("piece " + std::to_string(p) + " does not hold the points the directory says");
      }
    }
    // Draco splits a vertex whose triangles in the piece form separate fans into one point per fan (their seam
    // tags weld them back): a Draco piece may hold more vertices than it was given, never fewer.
    const std::size_t nv = piece.positions.size();
    if ((c.codec == 1 ? nv < c.pieces[p].vertices : nv != c.pieces[p].vertices) ||
        piece.triangles.size() != c.pieces[p].triangles || piece.normals.size() != (c.normals ? nv : 0)) {
      bad("piece " + std::to_string(p) + " does not hold what the directory says");
    }
    // A piece without points holds no attributes (Draco writes none); the others hold the frame's, unnamed.
    if (nv == 0) piece.attributes.clear();
    if (nv > 0 && piece.attributes.size() != c.attributes.size()) {
      bad("piece " + std::to_string(p) + " holds " + std::to_string(piece.attributes.size()) +
          " attributes, the frame names " + std::to_string(c.attributes.size()));
    }
    for (std::size_t a = 0; a < piece.attributes.size(); ++a) {
      if (piece.attributes[a].components != c.attributes[a].components) {
        bad("piece " + std::to_string(p) + "'s attribute " + c.attributes[a].name + " has " +
            std::to_string(piece.attributes[a].components) + " components, the frame says " +
            std::to_string(c.attributes[a].components));
      }
      piece.attributes[a].name = c.attributes[a].name;
    }
    if (nv == 0) {
      for (const Attribute& a : c.attributes) piece.attributes.push_back(Attribute{a.name, a.components, {}});
    }
  });
  Mesh mesh = weld(pieces, c.grid, threads);
  if (c.codec == 1 ? mesh.vertices.size() < c.vertices : mesh.vertices.size() != c.vertices) {
    bad("the pieces weld into " + std::to_string(mesh.vertices.size()) + " vertices, the header says " +
        std::to_string(c.vertices));
  }
  return mesh;
}

void check_gltf_bits(const Container& c) { check_gltf_quantization_bits(c.grid.bits); }

// What every .glb of a frame begins with: the asset and, when it has a mesh, the extensions it needs.
void begin_gltf(JsonWriter& w, bool has_mesh, const char* compression) {
  w.begin_object().key("asset").begin_object().key("version").value("2.0").key("generator").value("surfacer");
  w.end_object();
  if (has_mesh) {
    for (const char* list : {"extensionsUsed", "extensionsRequired"}) {
      w.key(list).begin_array().value(compression).value("KHR_mesh_quantization").end_array();
    }
  }
}

// ... and ends with: one node whose scale and translation put grid point q at q * delta + origin, Draco's
// dequantization (in float32, as Draco computes it).
std::string end_gltf(JsonWriter& w, const QuantizationGrid& grid, bool has_mesh, std::string bin) {
  const double delta = static_cast<double>(grid.range / static_cast<float>(grid.max_value()));
  w.key("scene").value(0).key("scenes").begin_array().begin_object().key("nodes").begin_array().value(0);
  w.end_array().end_object().end_array();
  w.key("nodes").begin_array().begin_object().key("translation").begin_array();
  for (const float o : grid.origin) w.value(static_cast<double>(o));
  w.end_array().key("scale").begin_array().value(delta).value(delta).value(delta).end_array();
  if (has_mesh) w.key("mesh").value(0);
  w.end_object().end_array().end_object();
  return pack_glb(w.str(), std::move(bin));
}

void write_bounds(JsonWriter& w, const PieceEntry& e) {
  for (const auto& [name, bound] : {std::pair{"min", &e.min}, std::pair{"max", &e.max}}) {
    w.key(name).begin_array().value((*bound)[0]).value((*bound)[1]).value((*bound)[2]).end_array();
  }
}

// Appends `data` to the binary chunk at a 4-byte boundary; returns its offset.
std::size_t append_aligned(std::string& bin, std::string_view data) {
  while (bin.size() % 4 != 0) bin.push_back('\0');
  const std::size_t offset = bin.size();
  bin += data;
  return offset;
}

// A Draco-pieces frame as a .glb: one KHR_draco_mesh_compression primitive per piece, its stream as received.
std::string draco_gltf(const Container& c, int threads) {
  if (c.codec != container_codec(FrameCodec::kDracoPieces)) bad("its pieces are not Draco pieces");
  check_gltf_bits(c);
  // Each piece's counts, its points' bounds and the Draco ids of its attributes: the directory's, or for a version 1
  // frame what decoding the pieces finds.
  const int n = static_cast<int>(c.pieces.size());
  std::vector<PieceEntry> primitives = c.pieces;
  if (c.version < 2) {
    parallel_for(n, threads, [&](int p) {
      const QuantizedPiece piece = decode_draco_piece(c.payloads[p], c.grid.bits, &primitives[p].found);
      if (piece.triangles.size() != c.pieces[p].triangles) bad("piece " + std::to_string(p) + " has other triangles");
      set_bounds(piece.positions, primitives[p]);
    });
  }
  // The binary chunk: the pieces with triangles (glTF has no empty accessors).
  std::vector<int> kept;
  std::vector<std::size_t> offsets;
  std::string bin;
  for (int p = 0; p < n; ++p) {
    if (primitives[p].triangles == 0) continue;
    kept.push_back(p);
    offsets.push_back(append_aligned(bin, c.payloads[p]));
  }
  append_aligned(bin, {});  // the buffer's byteLength is the padded chunk's
  // The JSON: per primitive the accessors POSITION, indices, NORMAL (when the piece has normals) and _SEAM (when it
  // has seam tags) in that order, and buffer view k for kept piece k. _SEAM (an application attribute, which other
  // readers pass over) names the seam vertices as the frame's tags do, so a reader can weld the pieces' copies
  // exactly as the client welds a frame (parse_glb does).
  // The frame's attributes follow, each a FLOAT accessor under its semantic (gltf_attribute_semantics).
  const std::vector<std::string> semantics = gltf_attribute_semantics(c.attributes);
  JsonWriter w;
  begin_gltf(w, !kept.empty(), "KHR_draco_mesh_compression");
  if (!kept.empty()) {
    w.key("meshes").begin_array().begin_object().key("primitives").begin_array();
    int accessor = 0;
    for (std::size_t k = 0; k < kept.size(); ++k) {
      const DracoPieceInfo& ids = primitives[kept[k]].found;
      if (!semantics.empty() && ids.attributes < 0) bad("piece " + std::to_string(kept[k]) + " has no attributes");
      const int normal = ids.normal >= 0 ? accessor + 2 : -1;
      const int seam = ids.seam >= 0 ? accessor + (normal >= 0 ? 3 : 2) : -1;
      const int first_attribute = accessor + 2 + (normal >= 0 ? 1 : 0) + (seam >= 0 ? 1 : 0);
      w.begin_object().key("attributes").begin_object().key("POSITION").value(accessor);
      if (normal >= 0) w.key("NORMAL").value(normal);
      if (seam >= 0) w.key(kGltfSeamSemantic).value(seam);
      for (std::size_t a = 0; a < semantics.size(); ++a)
        w.key(semantics[a]).value(first_attribute + static_cast<int>(a));
      w.end_object().key("indices").value(accessor + 1);
      w.key("extensions").begin_object().key("KHR_draco_mesh_compression").begin_object();
      w.key("bufferView").value(static_cast<int>(k)).key("attributes").begin_object();
      w.key("POSITION").value(ids.position);
      if (normal >= 0) w.key("NORMAL").value(ids.normal);
      if (seam >= 0) w.key(kGltfSeamSemantic).value(ids.seam);
      for (std::size_t a = 0; a < semantics.size(); ++a)
        w.key(semantics[a]).value(ids.attributes + static_cast<int>(a));
      w.end_object().end_object().end_object().end_object();
      accessor = first_attribute + static_cast<int>(semantics.size());
    }
    w.end_array();
    write_gltf_mesh_extras(w, c.attributes);
    w.end_object().end_array();
    w.key("accessors").begin_array();
    for (const int p : kept) {
      const PieceEntry& prim = primitives[p];
      w.begin_object().key("componentType").value(gltf::kUnsignedShort).key("type").value("VEC3");
      w.key("count").value(std::uint64_t{prim.found.points});
      write_bounds(w, prim);
      w.end_object();
      w.begin_object().key("componentType").value(gltf::kUnsignedInt).key("type").value("SCALAR");
      w.key("count").value(std::uint64_t{3 * prim.triangles}).end_object();
      if (prim.found.normal >= 0) {
        w.begin_object().key("componentType").value(gltf::kFloat).key("type").value("VEC3");
        w.key("count").value(std::uint64_t{prim.found.points}).end_object();
      }
      if (prim.found.seam >= 0) {
        w.begin_object().key("componentType").value(gltf::kUnsignedShort).key("type").value("SCALAR");
        w.key("count").value(std::uint64_t{prim.found.points}).end_object();
      }
      for (const Attribute& a : c.attributes) {
        w.begin_object().key("componentType").value(gltf::kFloat).key("type").value(gltf_accessor_type(a.components));
        w.key("count").value(std::uint64_t{prim.found.points}).end_object();
      }
    }
    w.end_array().key("bufferViews").begin_array();
    for (std::size_t k = 0; k < kept.size(); ++k) {
      w.begin_object().key("buffer").value(0).key("byteOffset").value(std::uint64_t{offsets[k]});
      w.key("byteLength").value(std::uint64_t{c.payloads[kept[k]].size()}).end_object();
    }
    w.end_array().key("buffers").begin_array().begin_object().key("byteLength").value(std::uint64_t{bin.size()});
    w.end_object().end_array();
  }
  return end_gltf(w, c.grid, !kept.empty(), std::move(bin));
}

// A meshopt frame as a .glb: one primitive per piece whose buffer views are the piece's meshoptimizer streams as
// received (EXT_meshopt_compression). Its 8-byte vertices (x, y, z, tag) are read whole as _SEAM, a VEC4 whose last
// component is the tag (glTF aligns attributes on 4 bytes, so the tag at byte 6 cannot be an accessor of its own),
// and their first three components as POSITION. Normals are the one stream laid out again, for the extension's
// OCTAHEDRAL filter.
std::string meshopt_gltf(const Container& c, int threads) {
  check_gltf_bits(c);
  const int n = static_cast<int>(c.pieces.size());
  std::vector<MeshoptStreams> streams(n);
  std::vector<std::string> normals(n);
  parallel_for(n, threads, [&](int p) {
    streams[p] = meshopt_streams(c.payloads[p]);
    const PieceEntry& e = c.pieces[p];
    if (streams[p].vertices != e.vertices || streams[p].triangles != e.triangles ||
        (streams[p].normal_bits > 0) != c.normals || streams[p].attributes.size() != c.attributes.size()) {
      bad("piece " + std::to_string(p) + " does not hold what the directory says");
    }
    normals[p] = gltf_octahedral_normals(streams[p]);
  });
  // A buffer view: its stream in the binary chunk, its decoded bytes in the fallback buffer (which has none: the
  // extension is required).
  struct View {
    std::size_t offset, length, fallback_offset, stride, count;
    const char* mode;
    const char* filter;  // nullptr: none
    int target;
  };
  std::vector<View> views;
  std::string bin;
  std::size_t fallback = 0;
  auto add_view = [&](std::string_view stream, std::size_t stride, std::size_t count, const char* mode,
                      const char* filter, int target) {
    views.push_back({0, stream.size(), fallback, stride, count, mode, filter, target});
    views.back().offset = append_aligned(bin, stream);
    fallback += stride * count;  // a multiple of 4 bytes a value: stays 4-byte aligned
  };
  std::vector<int> kept;
  for (int p = 0; p < n; ++p) {
    if (c.pieces[p].triangles == 0) continue;
    kept.push_back(p);
    add_view(streams[p].vertex, 8, streams[p].vertices, "ATTRIBUTES", nullptr, 34962);
    add_view(streams[p].index, 4, 3 * std::size_t{streams[p].triangles}, "TRIANGLES", nullptr, 34963);
    if (c.normals) add_view(normals[p], 8, streams[p].vertices, "ATTRIBUTES", "OCTAHEDRAL", 34962);
    for (std::size_t a = 0; a < c.attributes.size(); ++a) {
      const MeshoptStreams::AttributeStream& stream = streams[p].attributes[a];
      if (stream.components != c.attributes[a].components) {
        bad("piece " + std::to_string(p) + " does not hold the attributes the frame names");
      }
      add_view(stream.stream, 4 * std::size_t(stream.components), streams[p].vertices, "ATTRIBUTES", nullptr, 34962);
    }
  }
  append_aligned(bin, {});  // the buffer's byteLength is the padded chunk's
  // Per primitive the accessors POSITION, indices, _SEAM, NORMAL (with normals) and the frame's attributes, over its
  // buffer views: vertices, triangles, normals and one per attribute. _SEAM's tags name the seam vertices as the
  // frame's do (see draco_gltf).
  const std::vector<std::string> semantics = gltf_attribute_semantics(c.attributes);
  const int named = static_cast<int>(semantics.size());
  JsonWriter w;
  begin_gltf(w, !kept.empty(), "EXT_meshopt_compression");
  if (!kept.empty()) {
    const int per = (c.normals ? 4 : 3) + named;  // accessors per primitive
    const int views_per = (c.normals ? 3 : 2) + named;
    w.key("meshes").begin_array().begin_object().key("primitives").begin_array();
    for (std::size_t k = 0; k < kept.size(); ++k) {
      const int a = static_cast<int>(k) * per;
      w.begin_object().key("attributes").begin_object().key("POSITION").value(a).key(kGltfSeamSemantic).value(a + 2);
      if (c.normals) w.key("NORMAL").value(a + 3);
      for (int i = 0; i < named; ++i) w.key(semantics[i]).value(a + (c.normals ? 4 : 3) + i);
      w.end_object().key("indices").value(a + 1).end_object();
    }
    w.end_array();
    write_gltf_mesh_extras(w, c.attributes);
    w.end_object().end_array();
    w.key("accessors").begin_array();
    for (std::size_t k = 0; k < kept.size(); ++k) {
      const PieceEntry& e = c.pieces[kept[k]];
      const int v = static_cast<int>(k) * views_per;
      w.begin_object().key("bufferView").value(v).key("componentType").value(gltf::kUnsignedShort);
      w.key("type").value("VEC3").key("count").value(std::uint64_t{e.vertices});
      write_bounds(w, e);
      w.end_object();
      w.begin_object().key("bufferView").value(v + 1).key("componentType").value(gltf::kUnsignedInt);
      w.key("type").value("SCALAR").key("count").value(std::uint64_t{3 * std::uint64_t{e.triangles}}).end_object();
      w.begin_object().key("bufferView").value(v).key("componentType").value(gltf::kUnsignedShort);
      w.key("type").value("VEC4").key("count").value(std::uint64_t{e.vertices}).end_object();
      if (c.normals) {
        w.begin_object().key("bufferView").value(v + 2).key("componentType").value(gltf::kShort);
        w.key("normalized").value(true).key("type").value("VEC3");
        w.key("count").value(std::uint64_t{e.vertices}).end_object();
      }
      for (int i = 0; i < named; ++i) {
        w.begin_object().key("bufferView").value(v + (c.normals ? 3 : 2) + i).key("componentType").value(gltf::kFloat);
        w.key("type").value(gltf_accessor_type(c.attributes[i].components));
        w.key("count").value(std::uint64_t{e.vertices}).end_object();
      }
    }
    w.end_array().key("bufferViews").begin_array();
    for (const View& view : views) {
      w.begin_object().key("buffer").value(1).key("byteOffset").value(std::uint64_t{view.fallback_offset});
      w.key("byteLength").value(std::uint64_t{view.stride * view.count});
      if (view.target == 34962) w.key("byteStride").value(std::uint64_t{view.stride});
      w.key("target").value(view.target);
      w.key("extensions").begin_object().key("EXT_meshopt_compression").begin_object();
      w.key("buffer").value(0).key("byteOffset").value(std::uint64_t{view.offset});
      w.key("byteLength").value(std::uint64_t{view.length}).key("byteStride").value(std::uint64_t{view.stride});
      w.key("mode").value(view.mode).key("count").value(std::uint64_t{view.count});
      if (view.filter) w.key("filter").value(view.filter);
      w.end_object().end_object().end_object();
    }
    w.end_array().key("buffers").begin_array();
    w.begin_object().key("byteLength").value(std::uint64_t{bin.size()}).end_object();
    w.begin_object().key("byteLength").value(std::uint64_t{fallback}).key("extensions").begin_object();
    w.key("EXT_meshopt_compression").begin_object().key("fallback").value(true).end_object().end_object();
    w.end_object().end_array();
  }
  return end_gltf(w, c.grid, !kept.empty(), std::move(bin));
}

}  // namespace

std::string_view frame_codec_name(FrameCodec codec) {
  switch (codec) {
    case FrameCodec::kDraco:
      return "draco";
    case FrameCodec::kDracoPieces:
      return "draco-pieces";
    case FrameCodec::kMeshopt:
      return "meshopt";
    case FrameCodec::kPly:
      return "ply";
  }
  return "unknown";
}

void validate(const FrameCodecOptions& options) {
  validate(options.draco);
  if (options.max_piece_triangles < kMinPieceTriangles) {
    throw InvalidInput("max_piece_triangles", "max_piece_triangles (" + std::to_string(options.max_piece_triangles) +
                                                  ") must be at least " + std::to_string(kMinPieceTriangles) +
                                                  "; the default is " +
                                                  std::to_string(FrameCodecOptions{}.max_piece_triangles));
  }
}

std::string encode_frame(const Mesh& mesh, const FrameCodecOptions& options, int threads, const RunControl& control) {
  validate(options);
  switch (options.codec) {
    case FrameCodec::kDraco:
      return encode_draco(mesh, options.draco);
    case FrameCodec::kPly:
      return write_ply(mesh, /*double_precision=*/true);
    case FrameCodec::kDracoPieces:
    case FrameCodec::kMeshopt:
      return encode_pieces(mesh, options, threads, control);
  }
  throw Internal("unknown frame codec");
}

Mesh decode_frame(std::string_view bytes, FrameCodec codec, int threads) {
  switch (codec) {
    case FrameCodec::kDraco:
      return decode_draco(bytes);
    case FrameCodec::kPly:
      return parse_mesh(bytes, MeshFormat::kPly, "frame");
    case FrameCodec::kDracoPieces:
    case FrameCodec::kMeshopt:
      return decode_pieces(bytes, codec, threads);
  }
  throw Internal("unknown frame codec");
}

std::string to_standard_draco(std::string_view bytes, FrameCodec codec, const Mesh& decoded) {
  switch (codec) {
    case FrameCodec::kDraco:
      return std::string(bytes);
    case FrameCodec::kPly:
      return encode_draco(decoded, DracoOptions{});
    case FrameCodec::kDracoPieces:
    case FrameCodec::kMeshopt:
      break;
  }
  const QuantizationGrid grid = read_container(bytes).grid;
  DracoOptions options = on_grid(grid, decoded);
  return encode_draco(clamped_to(decoded, *options.quantization_bounds), options);
}

void check_gltf_quantization_bits(int bits) {
  if (bits > kMaxGltfQuantizationBits) {
    throw InvalidInput("quantization_bits",
                       "quantization_bits (" + std::to_string(bits) +
                           ") is more than glTF holds: positions of at most " +
                           std::to_string(kMaxGltfQuantizationBits) + " bits (KHR_mesh_quantization); use " +
                           std::to_string(kMaxGltfQuantizationBits) + " or fewer, or another file format");
  }
}

bool gltf_holds(std::string_view bytes, FrameCodec codec) {
  if (codec != FrameCodec::kDracoPieces && codec != FrameCodec::kMeshopt) return true;  // encoded on default bits
  return read_container(bytes).grid.bits <= kMaxGltfQuantizationBits;
}

std::string to_gltf(std::string_view bytes, FrameCodec codec, const std::function<const Mesh&()>& decoded,
                    int threads) {
  auto mesh = [&]() -> const Mesh& {
    if (!decoded) throw Internal("to_gltf needs the decoded mesh of this frame");
    return decoded();
  };
  if (codec == FrameCodec::kDracoPieces) return draco_gltf(read_container(bytes), threads);
  if (codec == FrameCodec::kMeshopt) {
    const Container c = read_container(bytes);
    if (c.codec != container_codec(FrameCodec::kMeshopt)) bad("its pieces are not meshopt pieces");
    if (c.version >= 2) return meshopt_gltf(c, threads);
    // A version 1 frame (kept by an earlier server) has no bounds in its directory: Draco pieces of its mesh.
    FrameCodecOptions options;
    options.codec = FrameCodec::kDracoPieces;
    options.draco = on_grid(c.grid, mesh());
    const std::string pieced = encode_frame(clamped_to(mesh(), *options.draco.quantization_bounds), options, threads);
    return draco_gltf(read_container(pieced), threads);
  }
  return to_gltf(mesh(), threads);
}

std::string to_gltf(const Mesh& mesh, int threads) {
  FrameCodecOptions options;
  options.codec = FrameCodec::kDracoPieces;
  options.draco.normals = !mesh.normals.empty();
  return draco_gltf(read_container(encode_frame(mesh, options, threads)), threads);
}

}  // namespace surfacer
