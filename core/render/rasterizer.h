// Headless pictures of meshes: a pinhole camera framed on a box, and a small z-buffer rasterizer with Lambert +
// ambient shading (flat, per triangle, two-sided so open meshes read as well as closed ones), plus particles as dots
// drawn over the surface. No GPU, no window: an RGB image in memory (core/render/png.h writes it).
//
// A sequence keeps one camera for all of its frames: frame_camera() on the union of the frames' bounds, so the
// picture does not jump from frame to frame.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "core/mesh/mesh.h"
#include "core/util/geometry.h"

namespace surfacer {

using Rgb = std::array<std::uint8_t, 3>;

// 8-bit RGB pixels, rows top to bottom, 3 bytes per pixel.
struct Image {
  int width = 0;
  int height = 0;
  std::vector<std::uint8_t> rgb;

  Image() = default;
  Image(int w, int h, Rgb fill);
  Rgb at(int x, int y) const;
  void set(int x, int y, Rgb c);
};

// Where the camera looks from: degrees around the box's centre. Azimuth turns about +z from +x towards +y;
// elevation lifts the eye above the xy plane (-89..89).
struct ViewOptions {
  double azimuth_degrees = -60.0;
  double elevation_degrees = 25.0;
  double field_of_view_degrees = 30.0;  // the smaller of the image's two angles, 1..120
};

// A pinhole camera: eye, orthonormal basis (right, up, forward) and the focal length in pixels.
struct Camera {
  Vec3 eye = Vec3::Zero();
  Vec3 right = Vec3::UnitX();
  Vec3 up = Vec3::UnitZ();
  Vec3 forward = Vec3::UnitY();
  int width = 0;
  int height = 0;
  double focal_pixels = 1.0;

  // Pixel coordinates (x right, y down, pixel centres at +0.5) and view depth (> 0 in front of the eye).
  Vec3 project(const Vec3& p) const;
};

// The camera that sees the whole of `box` (its bounding sphere fits the field of view with a small margin) from the
// view's direction, for a width x height image. Throws InvalidInput("view") for a size below 1 pixel, a box that is
// not finite (an empty box is taken as a point), or angles out of range.
Camera frame_camera(const Aabb& box, int width, int height, const ViewOptions& view = {});

struct RenderOptions {
  Rgb background{255, 255, 255};
  Rgb surface{176, 196, 222};
  Rgb points{200, 60, 40};
  double ambient = 0.3;  // share of the colour lit regardless of the light, 0..1
  int supersample = 2;   // rendered at this multiple of the size, then averaged down (anti-aliasing), 1..4
  double point_radius_pixels = 1.5;
};

// Draws into a frame buffer of the camera's size; image() averages it down. Depth test on the surface only: dots
// are drawn after it, over it (nearest dot on top), so particles inside a fluid's surface stay visible.
class Rasterizer {
 public:
  Rasterizer(const Camera& camera, const RenderOptions& options = {});

  void draw_mesh(const Mesh& mesh);
  void draw_points(std::span<const Vec3> points);
  Image image() const;

 private:
  Camera camera_;  // at the supersampled size
  RenderOptions options_;
  int scale_ = 1;
  Image buffer_;
  std::vector<float> depth_;  // view depth of the nearest surface, +inf where none
};

// One shot: `mesh` (and `points`, over it) seen by `camera`.
Image render_mesh(const Mesh& mesh, const Camera& camera, const RenderOptions& options = {},
                  std::span<const Vec3> points = {});

}  // namespace surfacer
