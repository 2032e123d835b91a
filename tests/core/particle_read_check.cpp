// particle_read_check FILE POSITIONS.f32: reads FILE with read_particles and compares its positions, rounded to
// float32, with the little-endian float32 x, y, z triples in POSITIONS.f32. Prints one line; exits 0 when every
// position is bit-equal, 1 on a mismatch or a read error (its message printed), 2 on bad usage.
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <exception>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "core/particles/particle_io.h"

int main(int argc, char** argv) {
  if (argc != 3) {
    std::fprintf(stderr, "usage: particle_read_check FILE POSITIONS.f32\n");
    return 2;
  }
  std::ifstream in(argv[2], std::ios::binary);
  const std::string raw((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::vector<float> expected(raw.size() / sizeof(float));
  std::memcpy(expected.data(), raw.data(), expected.size() * sizeof(float));
  try {
    const surfacer::ParticleFrame frame = surfacer::read_particles(argv[1]);
    if (frame.positions.size() * 3 != expected.size()) {
      std::printf("%s: %zu positions, expected %zu\n", argv[1], frame.positions.size(), expected.size() / 3);
      return 1;
    }
    for (std::size_t i = 0; i < frame.positions.size(); ++i) {
      for (int k = 0; k < 3; ++k) {
        const float got = static_cast<float>(frame.positions[i][k]);
        if (std::memcmp(&got, &expected[3 * i + k], sizeof(float)) != 0) {
          std::printf("%s: position %zu component %d is %.9g, expected %.9g\n", argv[1], i, k, got,
                      expected[3 * i + k]);
          return 1;
        }
      }
    }
    std::printf("%s: %zu positions equal\n", argv[1], frame.positions.size());
    return 0;
  } catch (const std::exception& e) {
    std::printf("%s: %s\n", argv[1], e.what());
    return 1;
  }
}
