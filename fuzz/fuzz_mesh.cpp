// Fuzz target: uploaded meshes (an optimize job's start mesh, the CLI's --start-mesh and --raw frames) through
// core/mesh_io's PLY and OBJ readers and core/mesh_codec's Draco decoder, and the pieced frames a server sends (what
// the CLI and the Python package decode) through core/mesh/frame_codec.
// Input: one selector byte, then the file bytes: 0 PLY, 1 OBJ, 2 Draco (parse_mesh), 3 decode_draco directly,
// 4 the server's format sniffing (server/optimize_job.cpp: "ply" prefix -> PLY, "DRACO" -> Draco, else OBJ),
// 5 a Draco-pieces frame, 6 a meshopt frame (each to_gltf, then decode_frame of the same bytes),
// 7 binary glTF (parse_mesh, as a .glb start mesh; sniffing "glTF" reaches it too).
// Every mesh read is then written as double-precision PLY and read back: it must survive unchanged. A .glb written
// from a frame has glTF's header with its own length.
// Expected failures are surfacer::Error; anything else escaping, a crash, UB or a violated property is a bug.
#include <cstdint>
#include <optional>
#include <string>

#include "core/mesh/frame_codec.h"
#include "core/mesh/mesh_codec.h"
#include "core/mesh/mesh_io.h"
#include "core/util/errors.h"
#include "fuzz/fuzz_input.h"

namespace surfacer::fuzz {
namespace {

// As server/optimize_job.cpp's sniff_mesh_format.
MeshFormat sniff(std::string_view bytes) {
  if (bytes.substr(0, 3) == "ply") return MeshFormat::kPly;
  if (bytes.substr(0, 5) == "DRACO") return MeshFormat::kDraco;
  if (bytes.substr(0, 4) == "glTF") return MeshFormat::kGlb;
  if (bytes.substr(0, 1) == "{") return MeshFormat::kGltf;
  return MeshFormat::kObj;
}

void check_mesh(const Mesh& mesh) {
  require(mesh.normals.empty() || mesh.normals.size() == mesh.vertices.size(), "normals count != vertex count");
  for (const Triangle& t : mesh.triangles) {
    for (std::uint32_t v : t) require(v < mesh.vertices.size(), "triangle references a missing vertex");
  }
  // Lossless round trip through the writer the server uses for raw frames.
  const Mesh back = parse_mesh(write_ply(mesh, /*double_precision=*/true), MeshFormat::kPly, "round trip");
  require(back.triangles == mesh.triangles, "PLY round trip changed the triangles");
  require(back.vertices.size() == mesh.vertices.size(), "PLY round trip changed the vertex count");
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
    const Vec3& a = mesh.vertices[i];
    const Vec3& b = back.vertices[i];
    for (int c = 0; c < 3; ++c) {
      require(a[c] == b[c] || (a[c] != a[c] && b[c] != b[c]), "PLY round trip changed vertex " + std::to_string(i));
    }
  }
}

void check_glb(const std::string& glb) {
  auto u32 = [&](std::size_t at) {
    return std::uint32_t{static_cast<std::uint8_t>(glb[at])} |
           std::uint32_t{static_cast<std::uint8_t>(glb[at + 1])} << 8 |
           std::uint32_t{static_cast<std::uint8_t>(glb[at + 2])} << 16 |
           std::uint32_t{static_cast<std::uint8_t>(glb[at + 3])} << 24;
  };
  require(glb.size() >= 20 && glb.substr(0, 4) == "glTF", "a .glb without glTF's header");
  require(u32(4) == 2 && u32(8) == glb.size(), "a .glb whose header states another version or length");
}

}  // namespace
}  // namespace surfacer::fuzz

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace surfacer;
  if (size == 0) return 0;
  const std::uint8_t selector = data[0] % 8;
  const std::string_view bytes = fuzz::as_view(data + 1, size - 1);
  Mesh mesh;
  try {
    switch (selector) {
      case 0:
        mesh = parse_mesh(bytes, MeshFormat::kPly, "fuzz.ply");
        break;
      case 1:
        mesh = parse_mesh(bytes, MeshFormat::kObj, "fuzz.obj");
        break;
      case 2:
        mesh = parse_mesh(bytes, MeshFormat::kDraco, "fuzz.drc");
        break;
      case 3:
        mesh = decode_draco(bytes);
        break;
      case 7:
        mesh = parse_mesh(bytes, MeshFormat::kGlb, "fuzz.glb");
        break;
      case 5:
      case 6: {
        const FrameCodec codec = selector == 5 ? FrameCodec::kDracoPieces : FrameCodec::kMeshopt;
        const int one = 1;
        std::optional<Mesh> decoded;  // what to_gltf asks for a version 1 meshopt frame
        auto decode = [&]() -> const Mesh& {
          if (!decoded) decoded = decode_frame(bytes, codec, one);
          return *decoded;
        };
        try {  // from the directory alone, so it may succeed where decoding fails, and the other way round
          fuzz::check_glb(to_gltf(bytes, codec, decode, one));
        } catch (const Error& e) {
          fuzz::require(e.what()[0] != '\0', "an Error without a message");
        }
        mesh = decode_frame(bytes, codec, one);
        break;
      }
      default:
        mesh = parse_mesh(bytes, fuzz::sniff(bytes), "upload");
        break;
    }
  } catch (const Error& e) {
    fuzz::require(e.what()[0] != '\0', "an Error without a message");
    return 0;
  }
  fuzz::check_mesh(mesh);  // outside the try: an accepted mesh must write and read back without an Error
  return 0;
}
