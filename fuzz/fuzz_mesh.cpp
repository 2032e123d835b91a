// Fuzz target: uploaded meshes (an optimize job's start mesh, the CLI's --start-mesh and --raw frames) through
// core/mesh_io's PLY and OBJ readers and core/mesh_codec's Draco decoder.
// Input: one selector byte, then the file bytes: 0 PLY, 1 OBJ, 2 Draco (parse_mesh), 3 decode_draco directly,
// 4 the server's format sniffing (server/optimize_job.cpp: "ply" prefix -> PLY, "DRACO" -> Draco, else OBJ).
// Every mesh read is then written as double-precision PLY and read back: it must survive unchanged.
// Expected failures are surfacer::Error; anything else escaping, a crash, UB or a violated property is a bug.
#include <cstdint>
#include <string>

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

}  // namespace
}  // namespace surfacer::fuzz

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace surfacer;
  if (size == 0) return 0;
  const std::uint8_t selector = data[0] % 5;
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
