// glTF 2.0: reading a .glb or .gltf as a triangle mesh (a start mesh or any mesh input, the files the CLI writes
// included), writing a plain .gltf, and the container and numbers that reading and writing (core/mesh/frame_codec.h,
// to_gltf) share.
#pragma once

#include <string>
#include <string_view>
#include <vector>

#include "core/mesh/mesh.h"
#include "core/mesh/mesh_codec.h"

namespace surfacer {

class JsonWriter;

// glTF's accessor component types.
namespace gltf {
inline constexpr int kByte = 5120;
inline constexpr int kUnsignedByte = 5121;
inline constexpr int kShort = 5122;
inline constexpr int kUnsignedShort = 5123;
inline constexpr int kUnsignedInt = 5125;
inline constexpr int kFloat = 5126;
}  // namespace gltf

// Mesh::attributes in glTF: each is an application-specific vertex attribute (glTF 2.0 §3.7.2.1: its semantic MUST
// begin with an underscore) of an accessor of FLOAT SCALAR, VEC2, VEC3 or VEC4 (gltf_accessor_type). Semantic i is
// "_" and attribute i's name upper-cased, every byte other than A-Z, 0-9 and '_' made '_' (the spec's own semantics
// are upper-case identifiers, and readers that generate shaders map them onto identifiers), with "_2", "_3", ...
// appended to one already taken by an earlier attribute or by _SEAM (our pieces' seam tags): velocity -> _VELOCITY,
// "foam mask" -> _FOAM_MASK. The names themselves go in the mesh's extras, {"attribute_names": {semantic: name}},
// from which parse_glb restores them. Every writer and the reader name them here.
std::vector<std::string> gltf_attribute_semantics(const std::vector<Attribute>& attributes);
inline constexpr const char* kGltfAttributeNamesKey = "attribute_names";
inline constexpr const char* kGltfSeamSemantic = "_SEAM";
// "SCALAR", "VEC2", "VEC3", "VEC4" for 1..4 components. Throws Internal for others.
const char* gltf_accessor_type(int components);
// Writes the mesh's "extras" member (a key and its object) that names `attributes`; nothing when there are none.
void write_gltf_mesh_extras(JsonWriter& w, const std::vector<Attribute>& attributes);

// A .glb of the JSON text `json` and the binary chunk `bin`: the JSON padded with spaces and the binary with zeros to
// whole 4-byte words, no BIN chunk when `bin` is empty. Throws ResourceLimit("frame") for a file of over 4 GiB.
std::string pack_glb(std::string json, std::string bin);

// The triangles of every mesh the file's scene instances (its `scene`, else the first, else every root node),
// through the nodes' transforms (a matrix, or translation, rotation and scale; a mirroring transform keeps the
// triangles' outward side), as one mesh. Primitives of mode 4 (triangles), 5 (strip) and 6 (fan), indexed or not,
// with POSITION as floats or (normalized) integers (KHR_mesh_quantization), compressed by
// KHR_draco_mesh_compression or in buffer views compressed by EXT_meshopt_compression (filters NONE and OCTAHEDRAL).
// Vertices at exactly the same point become one vertex, since exporters split vertices at texture and normal seams; but
// in our own files (asset.generator "surfacer") only the pieces' copies of a seam vertex, named by their _SEAM tags,
// become one, as the client welds a frame, so distinct vertices that quantized onto one point stay apart. Either way a
// closed surface reads back closed. Normals (NORMAL, through each node's inverse transpose, unit length) when every
// primitive has them; application-specific attributes (_NAME, of 1 to 4 components, except _SEAM) as Mesh::attributes
// when every primitive has the same ones, named by the mesh's extras as gltf_attribute_semantics writes them (else
// the semantic without its underscore), the first copy's values where vertices are welded, not transformed by the
// nodes (the Draco streams of other programs' files are not searched for them); texture coordinates and materials
// are not read. Throws InvalidInput("file") naming `name` and
// what is wrong where: anything not such a file, points or lines, sparse accessors, buffers outside the file (a uri),
// non-finite positions or transforms, meshopt views that do not decode or claim more than their bytes can hold;
// ResourceLimit("max_triangles") past limits.max_triangles (checked before the triangles or a meshopt view are
// allocated, so a small file that instances a mesh many times cannot exhaust memory).
// A .gltf (JSON text, glTF 2.0 with no extension) as parse_glb reads it too: its one buffer a base64 data URI.
Mesh parse_glb(std::string_view bytes, const std::string& name, const MeshReadLimits& limits = {});

// `mesh` as a plain .gltf: JSON text whose one buffer is a base64 data URI (a third larger than binary), with float
// POSITION (and its min/max), unit float NORMAL when the mesh has normals, its attributes as float
// application-specific attributes (gltf_attribute_semantics), and uint32 indices; no compression
// extension, for readers without Draco or meshoptimizer (Debian's Blender, VTK's vtkGLTFReader). Positions are
// rounded to float. An empty mesh is a scene with no nodes. Throws InvalidInput as check_mesh_writable.
std::string write_gltf(const Mesh& mesh);
// The same as a plain .glb (binary glTF, the buffer in its BIN chunk): what --encoding raw --format glb writes, for
// glTF readers without Draco that want one binary file.
std::string write_glb(const Mesh& mesh);

}  // namespace surfacer
