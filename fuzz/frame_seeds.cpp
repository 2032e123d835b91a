// Writes the seeds of the mesh fuzz target (fuzz/fuzz_mesh.cpp) that Python cannot encode, so fuzz/make_seeds.py
// runs this (built with the tests as fuzz/fuzz_frame_seeds): pieced frames as a server encodes them (selectors 5 and
// 6: Draco pieces and meshopt pieces, one piece and several, with and without normals and attributes) and binary glTF
// files
// (selector 7: the CLI's .glb of such frames, and another exporter's plain accessors, nodes and fans).
// Usage: fuzz_frame_seeds DIR   (writes DIR/seed_frame_*)
#include <cstdio>
#include <fstream>
#include <string>

#include "core/mesh/frame_codec.h"
#include "core/scene/scene.h"
#include "tests/support/test_meshes.h"

int main(int argc, char** argv) {
  using namespace surfacer;
  if (argc != 2) {
    std::fprintf(stderr, "usage: fuzz_frame_seeds DIR\n");
    return 2;
  }
  const std::string dir = argv[1];
  const FieldPtr sphere = make_sphere(Vec3(0.1, -0.2, 0.05), 1.0);
  struct Seed {
    const char* name;
    FrameCodec codec;
    int cells;  // 8: 544 triangles, one piece; 11: 1052 triangles, four pieces of the smallest size
    bool normals;
    int bits;
    bool attributes = false;  // a scalar and a 3-vector a vertex (Mesh::attributes)
  };
  const Seed seeds[] = {
      {"draco_pieces_one", FrameCodec::kDracoPieces, 8, false, 14},
      {"draco_pieces_four", FrameCodec::kDracoPieces, 11, false, 11},
      {"draco_pieces_normals", FrameCodec::kDracoPieces, 8, true, 10},
      {"meshopt_one", FrameCodec::kMeshopt, 8, false, 14},
      {"meshopt_four", FrameCodec::kMeshopt, 11, false, 8},
      {"meshopt_normals", FrameCodec::kMeshopt, 6, true, 10},
      {"draco_pieces_attributes", FrameCodec::kDracoPieces, 11, false, 12, true},
      {"meshopt_attributes", FrameCodec::kMeshopt, 11, true, 12, true},
  };
  for (const Seed& s : seeds) {
    Mesh mesh = testing::polygonized(sphere, Polygonizer::kCubes, s.cells, s.normals);
    if (s.attributes) {
      Attribute density{"density", 1, {}}, velocity{"velocity", 3, {}};
      for (const Vec3& p : mesh.vertices) {
        density.values.push_back(998.25f);
        for (int c = 0; c < 3; ++c) velocity.values.push_back(static_cast<float>(p[c] - 2.0 * p[(c + 1) % 3]));
      }
      mesh.attributes = {density, velocity};
    }
    FrameCodecOptions o;
    o.codec = s.codec;
    o.draco.quantization_bits = s.bits;
    o.draco.quantization_bounds = Aabb{Vec3::Constant(-1.5), Vec3::Constant(1.5)};
    o.draco.normals = s.normals;
    o.max_piece_triangles = 1024;  // the smallest pieces
    const std::string bytes = encode_frame(mesh, o, 1);
    const char selector = s.codec == FrameCodec::kDracoPieces ? 5 : 6;  // fuzz_mesh.cpp's selectors
    std::ofstream(dir + "/seed_frame_" + s.name, std::ios::binary) << selector << bytes;
    std::printf("seed_frame_%s: %zu triangles, %zu bytes\n", s.name, mesh.triangles.size(), bytes.size() + 1);
    const std::string glb = to_gltf(bytes, s.codec, {}, 1);  // pieced frames: nothing decoded
    std::ofstream(dir + "/seed_glb_" + s.name, std::ios::binary) << char{7} << glb;
  }
  const Mesh cube = testing::unit_cube();
  const std::string nodes = R"([{"mesh":0,"translation":[1,2,3],"rotation":[0,0,0.6,0.8],"children":[1]},)"
                            R"({"mesh":0,"scale":[-1,2,1]},{"mesh":0,"matrix":[1,0,0,0,0,1,0,0,0,0,1,0,5,0,0,1]}])";
  std::ofstream(dir + "/seed_glb_plain_triangles", std::ios::binary)
      << char{7} << testing::plain_glb(cube, nodes, "[0,2]", 5123, 4);
  std::ofstream(dir + "/seed_glb_plain_fans", std::ios::binary)
      << char{7} << testing::plain_glb(cube, R"([{"mesh":0}])", "[0]", 5121, 6);
  return 0;
}
