// Mesh files: PLY (ASCII and binary little/big endian, float or double), OBJ (v/f, polygons fan-triangulated),
// Draco (.drc). Reading throws InvalidInput naming the file and the line or byte offset of the problem.
#pragma once

#include <filesystem>
#include <string>
#include <string_view>

#include "core/mesh/mesh.h"

namespace surfacer {

enum class MeshFormat { kPly, kObj, kDraco };

// Format from the extension (.ply, .obj, .drc); throws InvalidInput otherwise.
MeshFormat mesh_format_from_path(const std::filesystem::path& path);

Mesh read_mesh(const std::filesystem::path& path);
Mesh parse_mesh(std::string_view bytes, MeshFormat format, const std::string& name_for_errors);

// PLY is written binary little-endian (float positions unless `double_precision`); OBJ as text with %.9g.
void write_mesh(const std::filesystem::path& path, const Mesh& mesh);
std::string write_obj(const Mesh& mesh);
std::string write_ply(const Mesh& mesh, bool double_precision = false);

}  // namespace surfacer
