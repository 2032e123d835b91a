// Draco frame encoding (the lossless alternative is write_ply(mesh, true) in core/mesh/mesh_io.h).
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include "core/mesh/mesh.h"
#include "core/mesh/mesh_pieces.h"
#include "core/mesh/quantization.h"

namespace surfacer {

struct DracoOptions {
  int quantization_bits = 14;  // 1..30
  // Quantization box shared by every frame of a job (no cracks or jitter between frames). When absent the mesh's
  // own bounding box is used. Vertices outside the box are an InvalidInput error.
  std::optional<Aabb> quantization_bounds;
  int speed = 8;         // Draco encoder/decoder speed 0..10 (8: faster and smaller than 7 on polygonized surfaces)
  bool normals = true;   // encode mesh.normals when present
  int normal_bits = 10;  // 2..30 (octahedral normal quantization), checked only when normals are encoded
};

// Throws InvalidInput naming the option ("quantization_bits", "speed", "normal_bits", "quantization_bounds").
void validate(const DracoOptions& options);

// Throws InvalidInput for bad options or vertices outside the quantization box, Internal on encoder failure.
// Vertices up to 1e-9 * (box's longest side) outside quantization_bounds are clamped onto it; farther ones are
// InvalidInput("quantization_bounds"). Draco reorders vertices and drops unreferenced ones: compare decoded meshes
// by geometry, not indices. A mesh without triangles is written without points and decodes as an empty Mesh.
// Mesh::attributes travel as GENERIC float32 attributes (unquantized), each named by its Draco attribute metadata
// entry "name"; decode_draco restores them (other GENERIC attributes are ignored).
// Cost: Draco's edgebreaker takes ~0.3-0.5 us per triangle at speeds 0-9; speed 10 (sequential) is ~7x faster but
// ~6x larger.
std::string encode_draco(const Mesh& mesh, const DracoOptions& options);

// encode_draco in two steps, for callers that run Draco's encoder (which cannot be interrupted) on a thread of their
// own: the constructor validates and copies what the encoder needs, so the mesh may go away before encode() runs.
class DracoEncoder {
 public:
  // Throws like encode_draco.
  DracoEncoder(const Mesh& mesh, const DracoOptions& options);
  ~DracoEncoder();
  DracoEncoder(const DracoEncoder&) = delete;
  DracoEncoder& operator=(const DracoEncoder&) = delete;
  // The Draco bytes; call once. Throws Internal on encoder failure.
  std::string encode();

 private:
  struct State;
  std::unique_ptr<State> state_;
};

// What decoding an untrusted mesh may cost.
struct MeshReadLimits {
  // Most triangles the caller will accept (the server's --max-triangles): a decoder may allocate for no more.
  std::int64_t max_triangles = std::int64_t{1} << 32;
};

// Throws InvalidInput("frame") if the bytes are not a Draco triangle mesh (fuzzed with truncated and bit-flipped
// frames). Draco allocates for the element counts a stream declares before it reads the elements, so the decoder runs
// inside an AllocationBudget (core/util/allocation_budget.h) of 64 MiB plus the smaller of 4096 bytes per input byte
// and 256 bytes per triangle of limits.max_triangles. Measured: Draco allocates 60-125 bytes per triangle; per input
// byte 50-500 for polygonized surfaces, 2.1 KB for a flat regular grid of 12.5 M triangles at speed 0 (about the
// most compressible mesh). A stream that needs more throws InvalidInput("frame") (it declares far more than its
// bytes hold) or, when the triangle limit is the smaller bound, ResourceLimit("max_triangles").
Mesh decode_draco(std::string_view bytes, const MeshReadLimits& limits = {});

// The grid `mesh` is quantized on: options.quantization_bounds, else the mesh's own bounding box. Checks the mesh
// first and throws as encode_draco does (non-finite vertices, bad indices, normals, vertices outside the box), with
// blocks of vertices and triangles spread over up to `threads` (>= 1) threads (the same error whatever their number).
QuantizationGrid quantization_grid(const Mesh& mesh, const DracoOptions& options, int threads);
QuantizationGrid quantization_grid(const Mesh& mesh, const DracoOptions& options);  // on the calling thread

// Largest position error quantization can introduce: half a quantization step along the box's longest side
// times sqrt(3) (Draco uses one range, the longest side, for all axes: step = side / (2^bits - 1)), plus a few
// float32 ulps of the box's coordinates because Draco quantizes in float32.
double draco_max_error(const Aabb& box, int quantization_bits);

// What a Draco piece holds for its decoder: its points (Draco writes a vertex whose triangles in the piece form
// separate fans as one point per fan, so there may be more points than the piece's vertices) and the Draco attribute
// ids of its position, normals, seam tags and first attribute (the others follow it; -1: none), which glTF's
// KHR_draco_mesh_compression names.
struct DracoPieceInfo {
  std::size_t points = 0;
  int position = -1;
  int normal = -1;
  int seam = -1;
  int attributes = -1;
  bool operator==(const DracoPieceInfo&) const = default;
};
// One piece of a frame (core/mesh/mesh_pieces.h) as Draco bytes: the grid coordinates as an integer POSITION
// attribute (16-bit for grids of up to 16 bits; Draco's own quantization is not needed, they are on the grid
// already), the seam tags as a 16-bit GENERIC attribute when some are non-zero, and the normals as encode_draco
// writes them (options.normals, options.normal_bits), then the piece's attributes as GENERIC float32 attributes
// (unquantized: bit for bit), in order and without names (a frame names them once, core/mesh/frame_codec.h).
// options.speed applies; its quantization fields do not. Fills `info` (what decode_draco_piece will find) when given.
std::string encode_draco_piece(const QuantizedPiece& piece, int grid_bits, const DracoOptions& options,
                               DracoPieceInfo* info = nullptr);
// Throws InvalidInput("frame") when the bytes are not such a piece (no integer POSITION, coordinates beyond
// 2^grid_bits - 1, attributes of more than 4 components). The seam tags are the GENERIC attribute of unsigned
// integers, the attributes the float ones (returned unnamed, in order of their ids). Fills `info` when given.
QuantizedPiece decode_draco_piece(std::string_view bytes, int grid_bits, DracoPieceInfo* info = nullptr);

}  // namespace surfacer
