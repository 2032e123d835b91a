// Mesh files for VTK-based tools (ParaView, VisIt, meshio and the Blender sequence loaders built on it):
//   .vtk  legacy VTK 4.2, BINARY (big-endian, as the format requires), DATASET UNSTRUCTURED_GRID of triangles
//         (cell type 5); per-vertex normals as POINT_DATA VECTORS "Normals" (VTK and meshio both read VECTORS;
//         meshio refuses a NORMALS section).
//   .vtu  VTK XML UnstructuredGrid, one Piece, every DataArray inline "binary" (base64) compressed with zlib
//         (compressor="vtkZLibDataCompressor", header_type="UInt64", blocks of 1 MiB): what VTK and meshio write by
//         default, and still well-formed XML; normals as the PointData array "Normals".
// Both are binary: the bit patterns of the values survive (ASCII would need 9 or 17 digits a value), and files are
// 3-5x smaller and faster to load than ASCII. Positions and normals are Float32 unless `double_precision` (the
// positions are then Float64, as for lossless frames). Connectivity is Int32 (Int64 in a .vtu whose offsets pass
// 2^31 - 1).
// Throws InvalidInput what check_mesh_writable (mesh_io.h) throws, and for a .vtk of more than 536870911 triangles
// (legacy readers count the cell list in int32; write .vtu instead).
#pragma once

#include <string>
#include <string_view>

#include "core/mesh/mesh.h"

namespace surfacer {

std::string write_vtk(const Mesh& mesh, bool double_precision = false);
std::string write_vtu(const Mesh& mesh, bool double_precision = false);

// `text` with XML's five special characters escaped, for an attribute value (array names, .pvd file names).
std::string xml_escape(std::string_view text);

}  // namespace surfacer
