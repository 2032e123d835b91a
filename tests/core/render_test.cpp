// core/render: pictures decoded from their PNG bytes (stb_image) show the mesh where it projects and the background
// elsewhere; one camera frames a whole sequence; particles show over the surface; the plot draws its series.
#include <gtest/gtest.h>

#include <cmath>

#include "core/render/plot.h"
#include "core/render/png.h"
#include "core/render/rasterizer.h"
#include "core/util/errors.h"
#include "tests/support/files.h"
#include "tests/support/json_check.h"
#include "tests/support/test_meshes.h"

namespace surfacer {
namespace {

using testing::icosphere;
using testing::torus_mesh;

const Rgb kBackground{255, 255, 255};

// The image through a PNG file and back.
Image png_round_trip(const Image& image) {
  const auto dir = testing::fresh_temp_dir("render_png");
  testing::write_file(dir / "a.png", encode_png(image));
  Image back = testing::read_png(dir / "a.png");
  std::filesystem::remove_all(dir);
  return back;
}

bool is_background(const Image& image, int x, int y) { return image.at(x, y) == kBackground; }

int shaded_pixels(const Image& image) {
  int n = 0;
  for (int y = 0; y < image.height; ++y) {
    for (int x = 0; x < image.width; ++x) n += !is_background(image, x, y);
  }
  return n;
}

TEST(Render, SphereIsShadedAtTheCentreAndAbsentInTheCorners) {
  const Mesh sphere = icosphere(3, 0.7, Vec3(1, -2, 3));
  for (const auto& [w, h] : {std::pair{480, 360}, std::pair{64, 64}, std::pair{200, 90}, std::pair{90, 200}}) {
    SCOPED_TRACE(std::to_string(w) + "x" + std::to_string(h));
    const Camera camera = frame_camera(Aabb::of(sphere.vertices), w, h);
    const Image image = png_round_trip(render_mesh(sphere, camera));
    ASSERT_EQ(image.width, w);
    ASSERT_EQ(image.height, h);
    EXPECT_FALSE(is_background(image, w / 2, h / 2));
    for (const auto& [x, y] : {std::pair{0, 0}, std::pair{w - 1, 0}, std::pair{0, h - 1}, std::pair{w - 1, h - 1}}) {
      EXPECT_TRUE(is_background(image, x, y)) << x << "," << y;
    }
    // Lambert + ambient: the lit side is brighter than the shadowed side, and nothing is black.
    int darkest = 255, brightest = 0;
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        if (is_background(image, x, y)) continue;
        const Rgb c = image.at(x, y);
        darkest = std::min(darkest, static_cast<int>(c[2]));
        brightest = std::max(brightest, static_cast<int>(c[2]));
      }
    }
    EXPECT_GT(brightest - darkest, 40);
    EXPECT_GT(darkest, 30);
    // The sphere fills a good part of the smaller side (the camera frames its bounding box's bounding sphere, of
    // radius sqrt(3) x the sphere's), and stays inside the picture.
    const double disc = 3.14159 * std::pow(0.5 * std::min(w, h), 2);
    EXPECT_GT(shaded_pixels(image), 0.2 * disc);
    EXPECT_LT(shaded_pixels(image), 1.0 * disc);
  }
}

TEST(Render, EveryPixelWhereTheMeshProjectsIsShaded) {
  // A torus seen from above: the hole in the middle is background, the ring around it is shaded.
  const Mesh torus = torus_mesh(1.0, 0.35, 64, 32);
  ViewOptions top;
  top.elevation_degrees = 89;
  const Camera camera = frame_camera(Aabb::of(torus.vertices), 240, 240, top);
  const Image image = png_round_trip(render_mesh(torus, camera));
  EXPECT_TRUE(is_background(image, 120, 120));  // the hole
  for (const Vec3& p : {Vec3(1, 0, 0.35), Vec3(-1, 0, 0.35), Vec3(0, 1, 0.35), Vec3(0, -1, 0.35)}) {
    const Vec3 s = camera.project(p);
    EXPECT_FALSE(is_background(image, static_cast<int>(s.x()), static_cast<int>(s.y())));
  }
}

TEST(Render, OneCameraFramesTheWholeSequence) {
  // Two frames, a sphere moving from left to right: with the camera on the union of their bounds, frame 0 is in the
  // left half and frame 1 in the right half of the same view, and neither is cut off.
  const Mesh a = icosphere(2, 0.5, Vec3(-2, 0, 0));
  const Mesh b = icosphere(2, 0.5, Vec3(2, 0, 0));
  ViewOptions front;
  front.azimuth_degrees = -90;  // looking along +y: x to the right
  front.elevation_degrees = 0;
  const Camera camera = frame_camera(merged(Aabb::of(a.vertices), Aabb::of(b.vertices)), 320, 240, front);
  for (const auto& [mesh, left] : {std::pair{&a, true}, std::pair{&b, false}}) {
    const Image image = render_mesh(*mesh, camera);
    int in_left = 0, in_right = 0;
    for (int y = 0; y < image.height; ++y) {
      for (int x = 0; x < image.width; ++x) (x < 160 ? in_left : in_right) += !is_background(image, x, y);
    }
    EXPECT_GT(left ? in_left : in_right, 100);
    EXPECT_EQ(left ? in_right : in_left, 0);
    for (int y = 0; y < image.height; ++y) {  // not cut at the sides
      EXPECT_TRUE(is_background(image, 0, y));
      EXPECT_TRUE(is_background(image, image.width - 1, y));
    }
  }
}

TEST(Render, ParticlesShowOverTheSurface) {
  // Particles inside a sphere would be hidden by a depth test; they are drawn over it in their own colour.
  const Mesh sphere = icosphere(3, 1.0);
  const std::vector<Vec3> inside{Vec3(0, 0, 0)};
  RenderOptions options;
  options.point_radius_pixels = 4;
  const Camera camera = frame_camera(Aabb::of(sphere.vertices), 120, 120);
  const Image plain = render_mesh(sphere, camera, options);
  const Image dotted = render_mesh(sphere, camera, options, inside);
  const Rgb centre = dotted.at(60, 60);
  EXPECT_NE(centre, plain.at(60, 60));
  EXPECT_GT(centre[0], centre[2]);  // the dots' red, not the surface's blue-grey
}

TEST(Render, DegenerateInputsAreRefusedOrDrawnEmpty) {
  EXPECT_THROW(frame_camera(Aabb::empty(), 10, 10), Error);
  EXPECT_THROW(frame_camera(Aabb{Vec3::Zero(), Vec3::Ones()}, 0, 10), Error);
  ViewOptions straight_down;
  straight_down.elevation_degrees = 90;
  EXPECT_THROW(frame_camera(Aabb{Vec3::Zero(), Vec3::Ones()}, 10, 10, straight_down), Error);
  // A point-like box still gets a camera; an empty mesh is all background.
  const Camera camera = frame_camera(Aabb{Vec3::Ones(), Vec3::Ones()}, 16, 16);
  EXPECT_EQ(shaded_pixels(render_mesh(Mesh{}, camera)), 0);
}

TEST(Plot, LogScaleLinesWithAxes) {
  std::vector<double> x, e_d, e_n;
  for (int i = 0; i <= 200; i += 10) {
    x.push_back(i);
    e_d.push_back(1e-2 * std::exp(-0.05 * i));
    e_n.push_back(0.5 * std::exp(-0.01 * i));
  }
  const std::vector<PlotSeries> series{{"e_d", x, e_d, {31, 119, 180}}, {"e_n", x, e_n, {214, 39, 40}}};
  PlotOptions options;
  options.title = "optimize";
  options.x_label = "iteration";
  const Image image = png_round_trip(plot_log_y(series, options));
  ASSERT_EQ(image.width, 480);
  ASSERT_EQ(image.height, 360);
  // Both colours are present; e_n (larger values) is drawn above e_d (smaller), as a log axis puts them.
  const auto rows_of = [&](Rgb color) {
    std::vector<int> rows;
    for (int y = 0; y < image.height; ++y) {
      for (int xx = 0; xx < image.width; ++xx) {
        const Rgb c = image.at(xx, y);
        if (std::abs(c[0] - color[0]) + std::abs(c[1] - color[1]) + std::abs(c[2] - color[2]) < 30) rows.push_back(y);
      }
    }
    return rows;
  };
  const auto blue = rows_of({31, 119, 180});
  const auto red = rows_of({214, 39, 40});
  ASSERT_GT(blue.size(), 50u);
  ASSERT_GT(red.size(), 50u);
  double mean_blue = 0, mean_red = 0;
  for (int y : blue) mean_blue += y;
  for (int y : red) mean_red += y;
  EXPECT_LT(mean_red / red.size(), mean_blue / blue.size());
  // Black axes and labels.
  int black = 0;
  for (std::size_t i = 0; i < image.rgb.size(); i += 3) black += image.rgb[i] < 60 && image.rgb[i + 1] < 60;
  EXPECT_GT(black, 500);
}

TEST(Plot, RefusesWhatCannotBePlotted) {
  const std::vector<PlotSeries> nothing{{"zero", {0, 1}, {0, -1}}};
  EXPECT_THROW(plot_log_y(nothing), Error);
  const std::vector<PlotSeries> mismatched{{"bad", {0, 1}, {1}}};
  EXPECT_THROW(plot_log_y(mismatched), Error);
  // One point is enough.
  const std::vector<PlotSeries> one{{"one", {5}, {1e-3}}};
  EXPECT_EQ(plot_log_y(one).width, 480);
}

}  // namespace
}  // namespace surfacer
