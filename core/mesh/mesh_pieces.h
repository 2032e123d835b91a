// A frame cut into pieces that encode and decode in parallel, and welded back exactly (docs/ALGORITHMS.md §5
// "Frames"). The cut depends on the mesh alone: runs of consecutive triangles of equal size, as many as needed for at
// most `max_piece_triangles` each, rounded up to a multiple of 4 when there are several. A vertex used by several
// pieces is written in each of them with a seam tag, which together with its grid point names it uniquely, so the
// decoder welds the copies whatever order a codec put them in.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <vector>

#include "core/mesh/mesh.h"
#include "core/mesh/quantization.h"
#include "core/util/run_control.h"

namespace surfacer {

// One piece as a codec sees it: positions on the job's grid, local triangles.
struct QuantizedPiece {
  std::vector<std::array<std::uint32_t, 3>> positions;  // grid coordinates, 0 .. grid.max_value()
  // Per vertex: 0 when no other piece has it; else 1 + its rank among the shared vertices on its grid point (grid
  // point and tag name a shared vertex in every piece that has it).
  std::vector<std::uint16_t> seam_tags;
  std::vector<Triangle> triangles;  // local vertex indices, counter-clockwise as in the mesh
  std::vector<Vec3> normals;        // empty or one unit normal per vertex
  // The mesh's Mesh::attributes, one element per vertex of the piece each, in the mesh's order. A decoder that does
  // not know the names (they travel once per frame, core/mesh/frame_codec.h) leaves them empty.
  std::vector<Attribute> attributes;
};

// The pieces of a mesh: cut once (on up to `threads` threads, cancellable through `control`), then each taken once with
// take(p), from any thread.
class MeshPieces {
 public:
  // Triangles with a repeated vertex index are left out (they carry no surface; Draco drops them as well) and so are
  // vertices no triangle uses. Every vertex must lie in the grid's box (callers clamp or check first). Frames up to
  // max_piece_triangles triangles are one piece. When more than 65535 shared vertices fall on one grid point (never
  // on real surfaces) the whole frame is one piece.
  MeshPieces(const Mesh& mesh, const QuantizationGrid& grid, std::size_t max_piece_triangles, int threads,
             const RunControl& control = {});
  MeshPieces(const MeshPieces&) = delete;
  MeshPieces& operator=(const MeshPieces&) = delete;

  int count() const { return static_cast<int>(pieces_.size()); }
  // Vertices and triangles of the welded mesh (what weld() returns for the pieces).
  std::size_t vertices() const { return vertices_; }
  std::size_t triangles() const { return triangles_; }
  // Piece p, positions quantized on the grid (normals and attributes when the mesh has them). Once per piece: its
  // triangles move out.
  QuantizedPiece take(int p);

 private:
  struct Piece {
    std::vector<std::uint32_t> globals;  // mesh vertex of each local vertex, in order of first use
    std::vector<Triangle> triangles;     // local indices
  };
  void cut(std::size_t max_piece_triangles, int threads, const RunControl& control);
  class WindowPool;
  // Numbers the vertices of triangles [begin, end) in order of first use into `piece`.
  void number(std::size_t begin, std::size_t end, Piece& piece, WindowPool& windows) const;

  const Mesh& mesh_;
  QuantizationGrid grid_;
  std::vector<Piece> pieces_;
  // With more than one piece, per vertex that a piece uses: the number of one piece that uses it, or, when several
  // do, 0x80000000 | its seam tag.
  std::unique_ptr<std::uint32_t[]> owner_;
  std::size_t vertices_ = 0;
  std::size_t triangles_ = 0;
};

// The mesh of decoded pieces: seam vertices (same grid point, same tag) become one vertex, the first copy in piece
// order, then vertex order; the other vertices follow piece by piece. Positions are the grid points as Draco's
// decoder returns them; normals and attributes are the kept copy's (the pieces' copies of a vertex hold the same
// values). Throws InvalidInput("frame") for pieces that contradict each other (a tag without partner, a grid
// coordinate beyond the grid, a triangle index out of range, attributes that differ in count, components or name).
Mesh weld(const std::vector<QuantizedPiece>& pieces, const QuantizationGrid& grid, int threads);

}  // namespace surfacer
