// One piece of a frame (core/mesh/mesh_pieces.h) with meshoptimizer's vertex and index codecs, the codecs of glTF's
// EXT_meshopt_compression: fast to encode and decode (GB/s), about three times the size of Draco.
#pragma once

#include <string>
#include <string_view>

#include "core/mesh/mesh_pieces.h"

namespace surfacer {

// Bytes: u32 vertices, u32 triangles, u8 flags (bit 0: normals), then u32-length-prefixed streams (little-endian):
// the vertices (grid x, y, z and the seam tag, 4 x u16 for grids of up to 16 bits, else 4 x u32; meshopt vertex
// codec), the triangles in their order (meshopt index codec) and, with normals, octahedral normals as 2 x i16
// quantized to min(normal_bits, 16) bits (meshopt vertex codec). grid_bits: 1..30; normal_bits: 2..30.
std::string encode_meshopt_piece(const QuantizedPiece& piece, int grid_bits, int normal_bits);
// Throws InvalidInput("frame") for bytes that are not such a piece (truncated streams, counts the bytes cannot hold,
// indices out of range, coordinates beyond 2^grid_bits - 1).
QuantizedPiece decode_meshopt_piece(std::string_view bytes, int grid_bits);

}  // namespace surfacer
