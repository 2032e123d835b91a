#include "tests/support/json_check.h"

#include <unistd.h>

#include <chrono>

#include "tests/support/files.h"
#include "tests/support/process.h"

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
#pragma GCC diagnostic ignored "-Wsign-compare"
#pragma GCC diagnostic ignored "-Wunused-parameter"
#pragma GCC diagnostic ignored "-Wunused-but-set-variable"
#define STB_IMAGE_IMPLEMENTATION
#define STB_IMAGE_STATIC
#define STBI_ONLY_PNG
#include <stb/stb_image.h>
#pragma GCC diagnostic pop

namespace surfacer::testing {

std::string python_json(const std::string& json, const std::string& expression, bool lines) {
  static int counter = 0;
  const std::filesystem::path dir = std::filesystem::temp_directory_path() /
                                    ("surfacer_json_" + std::to_string(getpid()) + "_" + std::to_string(counter++));
  std::filesystem::create_directories(dir);
  write_file(dir / "doc.json", json);
  const std::string script =
      "import json, sys\n"
      "def strict(name): raise ValueError('not JSON: ' + name)\n"
      "text = open(sys.argv[1], encoding='utf-8').read()\n"
      "load = lambda t: json.loads(t, parse_constant=strict)\n"
      "d = [load(l) for l in text.splitlines() if l.strip()] if sys.argv[2] == 'lines' else load(text)\n"
      "print(eval(sys.argv[3]))\n";
  const ProcessResult r =
      run_process({"/usr/bin/python3", "-c", script, (dir / "doc.json").string(), lines ? "lines" : "one", expression},
                  dir / "out", dir / "err", std::chrono::seconds(30));
  std::filesystem::remove_all(dir);
  if (r.code != 0) return "ERROR: " + r.err;
  std::string out = r.out;
  if (!out.empty() && out.back() == '\n') out.pop_back();
  return out;
}

Image read_png(const std::filesystem::path& path) {
  const std::string bytes = read_file(path);
  int w = 0, h = 0, channels = 0;
  unsigned char* pixels = stbi_load_from_memory(reinterpret_cast<const unsigned char*>(bytes.data()),
                                                static_cast<int>(bytes.size()), &w, &h, &channels, 3);
  if (pixels == nullptr) return {};
  Image image;
  image.width = w;
  image.height = h;
  image.rgb.assign(pixels, pixels + static_cast<std::size_t>(w) * h * 3);
  stbi_image_free(pixels);
  return image;
}

}  // namespace surfacer::testing
