// A frame's bytes in every codec the service speaks (docs/ALGORITHMS.md §5 "Frames"): one standard Draco mesh, Draco
// pieces or meshoptimizer pieces (encoded and decoded in parallel, welded exactly; core/mesh/mesh_pieces.h), or
// lossless PLY. Every codec but PLY puts the vertices on the job's quantization grid; every codec carries the mesh's
// attributes (Mesh::attributes) as float32, bit for bit.
#pragma once

#include <cstddef>
#include <functional>
#include <string>
#include <string_view>

#include "core/mesh/mesh.h"
#include "core/mesh/mesh_codec.h"
#include "core/util/run_control.h"

namespace surfacer {

enum class FrameCodec {
  kDraco,        // one standard Draco mesh (what Debian's draco_decoder reads); the encoder runs on one thread
  kDracoPieces,  // Draco pieces in a frame container: every core encodes, ~3 % larger than kDraco
  kMeshopt,      // meshoptimizer pieces in a frame container: ~10x faster than Draco, ~3x larger
  kPly,          // binary little-endian PLY with double-precision positions: lossless
};

// "draco", "draco-pieces", "meshopt", "ply".
std::string_view frame_codec_name(FrameCodec codec);

struct FrameCodecOptions {
  FrameCodec codec = FrameCodec::kDraco;
  // The quantization grid (bits, bounds) of every codec but PLY, and Draco's own settings (speed, normal bits);
  // `normals` applies to every codec.
  DracoOptions draco;
  // Pieced codecs: at most this many triangles per piece (>= 1024); a frame up to this size is one piece. Smaller
  // pieces spread over more cores and stop sooner on a cancel; larger ones compress a little better.
  std::size_t max_piece_triangles = std::size_t{1} << 18;
};

// Throws InvalidInput naming the option (DracoOptions' names, "max_piece_triangles").
void validate(const FrameCodecOptions& options);

// The bytes of `mesh` in options.codec. Pieces are encoded by parallel_for on up to `threads` (>= 1) threads (their
// bytes do not depend on it) and `control` is checked between them (Cancelled). Throws like encode_draco (bad mesh,
// vertices outside the quantization box), and for pieced codecs InvalidInput("attributes") for more than 255
// attributes or a name of more than 65535 bytes. A one-piece Draco or PLY frame is encoded on the calling thread,
// uninterruptibly.
std::string encode_frame(const Mesh& mesh, const FrameCodecOptions& options, int threads,
                         const RunControl& control = {});

// The mesh of a frame's bytes in `codec`; pieces are decoded and welded on up to `threads` (>= 1) threads. Throws
// InvalidInput("frame") when the bytes are not such a frame.
Mesh decode_frame(std::string_view bytes, FrameCodec codec, int threads);

// The frame as one standard Draco mesh, what Debian's draco_decoder reads (the CLI's frame_NNNN.drc): kDraco bytes
// as they are; a pieced frame re-encoded from `decoded` (decode_frame of the same bytes) on the frame's own grid, so
// its vertices are those of a kDraco frame of the job; a PLY frame on the mesh's own box with the default bits.
// Runs Draco's encoder on the calling thread. Throws InvalidInput("frame") for bytes that are not such a frame.
std::string to_standard_draco(std::string_view bytes, FrameCodec codec, const Mesh& decoded);

// The frame as a binary glTF 2.0 file (.glb, the CLI's --format glb): one node whose scale and translation map the
// grid to the scene, holding one mesh with one primitive per piece, positions as 16-bit grid coordinates
// (KHR_mesh_quantization) and the seam tags as the application attribute _SEAM (what parse_glb welds by,
// core/mesh/mesh_gltf.h). A pieced frame goes in as received, the accessors' counts and bounds taken from its
// directory: each Draco piece's stream as a KHR_draco_mesh_compression primitive, each meshopt piece's streams as
// EXT_meshopt_compression buffer views (its normals, if any, are laid out again for that extension's OCTAHEDRAL
// filter). The frame's attributes (Mesh::attributes) are FLOAT application attributes named by
// gltf_attribute_semantics (core/mesh/mesh_gltf.h), in the Draco streams or as meshopt buffer views of their own.
// Nothing is decoded, except the pieces of a version 1 Draco frame (from an earlier server: their bounds)
// and a version 1 meshopt frame, which becomes Draco pieces of `decoded()`, as does a one-mesh Draco or PLY frame
// (on the mesh's own box with the default bits). `decoded` (decode_frame of the same bytes) is called only then.
// Throws InvalidInput("quantization_bits") for a grid of more than 16 bits, which glTF cannot hold, and
// InvalidInput("frame") for bytes that are not such a frame.
std::string to_gltf(std::string_view bytes, FrameCodec codec, const std::function<const Mesh&()>& decoded, int threads);
// The most position bits glTF holds (KHR_mesh_quantization's 16-bit integers), and its check: throws
// InvalidInput("quantization_bits") naming the fix for more. to_gltf() and the client's choice of a run's encoding both
// call it.
inline constexpr int kMaxGltfQuantizationBits = 16;
void check_gltf_quantization_bits(int bits);
// Whether to_gltf() writes the frame: false for a pieced frame on a grid of more than 16 bits. Reads a pieced frame's
// header and directory only; throws InvalidInput("frame") for pieced bytes that are not such a frame.
bool gltf_holds(std::string_view bytes, FrameCodec codec);
// `mesh` as such a file: Draco pieces on the mesh's own box with the default bits, encoded on up to `threads` (>= 1)
// threads.
std::string to_gltf(const Mesh& mesh, int threads);

}  // namespace surfacer
