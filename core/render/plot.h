// A line plot as an image: series of (x, y) points over axes with ticks and labels, y on a log scale (optimize
// jobs' e_d and e_n per iteration fall over decades). Text is stb_easy_font's (Debian libstb-dev).
#pragma once

#include <span>
#include <string>
#include <vector>

#include "core/render/rasterizer.h"

namespace surfacer {

struct PlotSeries {
  std::string name;  // in the legend
  std::vector<double> x;
  std::vector<double> y;  // as many as x; points with y <= 0 or not finite are left out (the line breaks there)
  Rgb color{31, 119, 180};
};

struct PlotOptions {
  int width = 480;
  int height = 360;
  std::string title;
  std::string x_label;
  std::string y_label;
};

// Throws InvalidInput("plot") when a series' x and y differ in length, the image is smaller than 160 x 120 pixels,
// or no series has a single point to draw.
Image plot_log_y(std::span<const PlotSeries> series, const PlotOptions& options = {});

}  // namespace surfacer
