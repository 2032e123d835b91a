// PNG files of rendered images, through stb_image_write (Debian libstb-dev; compiled into core, so the binaries
// need no libstb at run time).
#pragma once

#include <filesystem>
#include <string>

#include "core/render/rasterizer.h"

namespace surfacer {

// The image as PNG bytes (8-bit RGB). Throws Internal if the encoder fails, InvalidInput("image") for an empty image.
std::string encode_png(const Image& image);

}  // namespace surfacer
