// The pieced frame container (little-endian):
//   "SFPC", u8 version (1), u8 codec (1: Draco pieces, 2: meshopt pieces), u8 grid bits, u8 flags (bit 0: normals),
//   f32 grid origin x y z, f32 grid range, u32 pieces, u64 vertices and u64 triangles of the welded mesh,
//   per piece: u32 bytes, u32 vertices, u32 triangles; then the pieces' bytes, in order.
#include "core/mesh/frame_codec.h"

#include <algorithm>
#include <atomic>
#include <cstring>
#include <limits>
#include <vector>

#include "core/mesh/mesh_io.h"
#include "core/mesh/meshopt_codec.h"
#include "core/util/errors.h"

namespace surfacer {
namespace {

constexpr char kMagic[4] = {'S', 'F', 'P', 'C'};
constexpr std::uint8_t kVersion = 1;
constexpr std::uint8_t kNormalsFlag = 1;
constexpr std::size_t kMinPieceTriangles = 1024;
constexpr std::size_t kHeaderBytes = 4 + 4 + 16 + 4 + 16;
constexpr std::size_t kDirectoryEntryBytes = 12;

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

struct PieceEntry {
  std::uint32_t bytes, vertices, triangles;
};

struct Container {
  std::uint8_t codec = 0;
  bool normals = false;
  QuantizationGrid grid;
  std::uint64_t vertices = 0, triangles = 0;
  std::vector<PieceEntry> pieces;
  std::vector<std::string_view> payloads;
};

Container read_container(std::string_view bytes) {
  if (bytes.size() < kHeaderBytes || std::memcmp(bytes.data(), kMagic, 4) != 0) bad("no SFPC header");
  std::size_t at = 4;
  Container c;
  if (get<std::uint8_t>(bytes, at) != kVersion) bad("unknown version");
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
  if ((bytes.size() - at) / kDirectoryEntryBytes < count) bad("directory of " + std::to_string(count) + " pieces");
  c.pieces.resize(count);
  std::uint64_t payload = 0, triangles = 0;
  for (PieceEntry& e : c.pieces) {
    e.bytes = get<std::uint32_t>(bytes, at);
    e.vertices = get<std::uint32_t>(bytes, at);
    e.triangles = get<std::uint32_t>(bytes, at);
    payload += e.bytes;
    triangles += e.triangles;
    if (e.vertices > 3ull * e.triangles) bad("a piece with more vertices than its triangles use");
  }
  if (payload != bytes.size() - at) bad("pieces of " + std::to_string(payload) + " bytes after the directory");
  if (triangles != c.triangles || c.vertices > 3 * c.triangles) bad("piece counts disagree with the header");
  for (const PieceEntry& e : c.pieces) {
    c.payloads.push_back(bytes.substr(at, e.bytes));
    at += e.bytes;
  }
  return c;
}

std::string encode_pieces(const Mesh& mesh, const FrameCodecOptions& options, const Executor& executor,
                          const RunControl& control) {
  const QuantizationGrid grid = quantization_grid(mesh, options.draco, executor);
  control.check();
  MeshPieces cut(mesh, grid, options.max_piece_triangles, executor, control);
  const int n = cut.count();
  const bool normals = options.draco.normals && !mesh.normals.empty();
  std::vector<std::string> payloads(n);
  std::vector<PieceEntry> entries(n);
  std::atomic<int> done{0};
  executor.for_each(n, [&](int p) {
    control.check();
    QuantizedPiece piece = cut.take(p);
    if (!normals) piece.normals.clear();
    payloads[p] = options.codec == FrameCodec::kDracoPieces
                      ? encode_draco_piece(piece, grid.bits, options.draco)
                      : encode_meshopt_piece(piece, grid.bits, options.draco.normal_bits);
    if (payloads[p].size() > std::numeric_limits<std::uint32_t>::max()) {
      throw ResourceLimit("max_piece_triangles", "a piece of over 4 GiB");
    }
    entries[p] = {static_cast<std::uint32_t>(payloads[p].size()), static_cast<std::uint32_t>(piece.positions.size()),
                  static_cast<std::uint32_t>(piece.triangles.size())};
    control.report("encode", static_cast<double>(done.fetch_add(1) + 1) / n);
  });
  std::size_t total = kHeaderBytes + n * kDirectoryEntryBytes;
  for (const std::string& p : payloads) total += p.size();
  std::string out;
  out.reserve(total);
  put(out, kMagic, 4);
  put(out, kVersion);
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
  }
  for (const std::string& p : payloads) out += p;
  return out;
}

Mesh decode_pieces(std::string_view bytes, FrameCodec codec, const Executor& executor) {
  const Container c = read_container(bytes);
  if (c.codec != container_codec(codec)) bad("its pieces are not " + std::string(frame_codec_name(codec)));
  const int n = static_cast<int>(c.pieces.size());
  std::vector<QuantizedPiece> pieces(n);
  executor.for_each(n, [&](int p) {
    QuantizedPiece& piece = pieces[p];
    piece = c.codec == 1 ? decode_draco_piece(c.payloads[p], c.grid.bits)
                         : decode_meshopt_piece(c.payloads[p], c.grid.bits);
    // Draco splits a vertex whose triangles in the piece form separate fans into one point per fan (their seam
    // tags weld them back): a Draco piece may hold more vertices than it was given, never fewer.
    const std::size_t nv = piece.positions.size();
    if ((c.codec == 1 ? nv < c.pieces[p].vertices : nv != c.pieces[p].vertices) ||
        piece.triangles.size() != c.pieces[p].triangles || piece.normals.size() != (c.normals ? nv : 0)) {
      bad("piece " + std::to_string(p) + " does not hold what the directory says");
    }
  });
  Mesh mesh = weld(pieces, c.grid, executor);
  if (c.codec == 1 ? mesh.vertices.size() < c.vertices : mesh.vertices.size() != c.vertices) {
    bad("the pieces weld into " + std::to_string(mesh.vertices.size()) + " vertices, the header says " +
        std::to_string(c.vertices));
  }
  return mesh;
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

std::string encode_frame(const Mesh& mesh, const FrameCodecOptions& options, const Executor& executor,
                         const RunControl& control) {
  validate(options);
  switch (options.codec) {
    case FrameCodec::kDraco:
      return encode_draco(mesh, options.draco);
    case FrameCodec::kPly:
      return write_ply(mesh, /*double_precision=*/true);
    case FrameCodec::kDracoPieces:
    case FrameCodec::kMeshopt:
      return encode_pieces(mesh, options, executor, control);
  }
  throw Internal("unknown frame codec");
}

Mesh decode_frame(std::string_view bytes, FrameCodec codec, const Executor& executor) {
  switch (codec) {
    case FrameCodec::kDraco:
      return decode_draco(bytes);
    case FrameCodec::kPly:
      return parse_mesh(bytes, MeshFormat::kPly, "frame");
    case FrameCodec::kDracoPieces:
    case FrameCodec::kMeshopt:
      return decode_pieces(bytes, codec, executor);
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
  // The grid's cube: Draco takes its origin and longest side, i.e. this grid. Grid points dequantized in float32
  // may stick out of it by an ulp; clamping moves them by less than a step, so they quantize to the same points.
  Aabb cube;
  for (int c = 0; c < 3; ++c) {
    cube.min[c] = grid.origin[c];
    cube.max[c] = static_cast<double>(grid.origin[c]) + static_cast<double>(grid.range);
  }
  DracoOptions options;
  options.quantization_bits = grid.bits;
  options.quantization_bounds = cube;
  options.normals = !decoded.normals.empty();
  Mesh clamped = decoded;
  for (Vec3& p : clamped.vertices) p = p.cwiseMax(cube.min).cwiseMin(cube.max);
  return encode_draco(clamped, options);
}

}  // namespace surfacer
