// Mesh files: PLY (ASCII and binary little/big endian, float or double), OBJ (v/f, polygons fan-triangulated),
// Draco (.drc), glTF (.glb and .gltf: read by core/mesh/mesh_gltf.h; .glb written as Draco pieces by to_gltf, .gltf
// plain by write_gltf). Reading throws
// InvalidInput naming the file and the line or byte offset of the problem.
#pragma once

#include <filesystem>
#include <string>
#include <string_view>

#include "core/mesh/mesh.h"
#include "core/mesh/mesh_codec.h"

namespace surfacer {

enum class MeshFormat { kPly, kObj, kDraco, kGlb, kGltf };

// Format from the extension (.ply, .obj, .drc, .glb, .gltf); throws InvalidInput otherwise.
MeshFormat mesh_format_from_path(const std::filesystem::path& path);

// PLY and OBJ allocate in proportion to the bytes present (never for a count a header declares); Draco within
// `limits` (decode_draco). Errors keep their kind, with the file's name in front of the message.
Mesh read_mesh(const std::filesystem::path& path, const MeshReadLimits& limits = {});
Mesh parse_mesh(std::string_view bytes, MeshFormat format, const std::string& name_for_errors,
                const MeshReadLimits& limits = {});

// Throws InvalidInput unless every mesh file can hold `mesh`: at most 2^31 - 1 vertices (files index with int32),
// no normals or one per vertex, every triangle's indices below the vertex count. `format` names the file in messages.
void check_mesh_writable(const Mesh& mesh, std::string_view format);
// Throws InvalidInput("attributes") unless every Mesh::attributes entry has 1..kMaxComponents components and one row
// per vertex (check_mesh_writable and the Draco encoder call it).
void check_attributes(const Mesh& mesh);

// By the extension: .ply, .obj, .drc (one Draco mesh, default options), .glb (to_gltf of Draco pieces on the
// mesh's own box with the default bits, encoded on every core) or .gltf (plain, uncompressed: write_gltf). PLY is written binary little-endian (float positions
// unless `double_precision`); OBJ as text with %.9g.
void write_mesh(const std::filesystem::path& path, const Mesh& mesh);
std::string write_obj(const Mesh& mesh);
std::string write_ply(const Mesh& mesh, bool double_precision = false);

}  // namespace surfacer
