// JSON and PNG outputs read back by independent decoders: Python's json module (strict: NaN and Infinity refused)
// through /usr/bin/python3, and stb_image (Debian libstb-dev).
#pragma once

#include <filesystem>
#include <string>

#include "core/render/rasterizer.h"

namespace surfacer::testing {

// Loads `json` (one document; with `lines`, one document per non-empty line, as a list) with Python's json module
// and prints `expression` evaluated with the document bound to `d`, e.g. "d['job']['state']" or
// "len([e for e in d if e['event'] == 'frame'])". Returns Python's stdout without the trailing newline, or
// "ERROR: ..." with its stderr when loading or evaluating fails (so EXPECT_EQ shows why).
std::string python_json(const std::string& json, const std::string& expression, bool lines = false);

// A PNG file decoded to 8-bit RGB; an empty image (width 0) when it is missing or not a PNG.
Image read_png(const std::filesystem::path& path);

}  // namespace surfacer::testing
