// One piece of a frame (core/mesh/mesh_pieces.h) with meshoptimizer's vertex and index codecs, the codecs of glTF's
// EXT_meshopt_compression: fast to encode and decode (GB/s), about three times the size of Draco.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "core/mesh/mesh_pieces.h"

namespace surfacer {

// Bytes: u32 vertices, u32 triangles, u8 flags (bit 0: normals, bit 1: attributes), then u32-length-prefixed streams
// (little-endian): the vertices (grid x, y, z and the seam tag, 4 x u16 for grids of up to 16 bits, else 4 x u32;
// meshopt vertex codec), the triangles in their order (meshopt index codec), with normals octahedral normals as
// 2 x i16 quantized to min(normal_bits, 16) bits (meshopt vertex codec) and a u8 of those bits, and with attributes
// a u8 count and per attribute a u8 of components and its float32 values (meshopt vertex codec, lossless: the values
// come back bit for bit; unnamed, a frame names them once, core/mesh/frame_codec.h). grid_bits: 1..30;
// normal_bits: 2..30. Throws InvalidInput("attributes") for more than 255 attributes or one that does not hold 1 to
// 4 values per vertex.
std::string encode_meshopt_piece(const QuantizedPiece& piece, int grid_bits, int normal_bits);
// Throws InvalidInput("frame") for bytes that are not such a piece (truncated streams, counts the bytes cannot hold,
// indices out of range, coordinates beyond 2^grid_bits - 1).
QuantizedPiece decode_meshopt_piece(std::string_view bytes, int grid_bits);

// The streams of such a piece as they lie in its bytes, nothing decoded: what a glTF file with
// EXT_meshopt_compression holds as its buffer views (to_gltf). Throws like decode_meshopt_piece for bytes that are
// not laid out as a piece.
struct MeshoptStreams {
  std::uint32_t vertices = 0, triangles = 0;
  std::string_view vertex, index, normal;  // normal: empty when the piece has no normals
  int normal_bits = 0;
  struct AttributeStream {
    int components = 1;       // float32 values per vertex
    std::string_view stream;  // meshopt vertex codec, byteStride 4 x components
  };
  std::vector<AttributeStream> attributes;
};
MeshoptStreams meshopt_streams(std::string_view bytes);
// The piece's normals as glTF's EXT_meshopt_compression reads them with its OCTAHEDRAL filter: 4 x i16 per vertex
// (octahedral x and y on K = max(normal_bits, 4) bits, K-bit 1.0, 0), meshopt vertex codec. The stored x and y are
// that encoding already (rounded onto 4 bits when normal_bits < 4, the filter's least K): only the layout changes.
std::string gltf_octahedral_normals(const MeshoptStreams& streams);

}  // namespace surfacer
