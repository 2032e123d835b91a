#include "core/render/plot.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include "core/util/errors.h"

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wunused-function"
#pragma GCC diagnostic ignored "-Wsign-compare"
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
#include <stb/stb_easy_font.h>
#pragma GCC diagnostic pop

namespace surfacer {
namespace {

constexpr int kScale = 2;  // drawn at twice the size, then averaged down
const Rgb kBlack{0, 0, 0};
const Rgb kGrid{225, 225, 225};
const Rgb kWhite{255, 255, 255};

// Drawing on the supersampled canvas, in its own pixels.
struct Canvas {
  Image image;

  void fill(double x0, double y0, double x1, double y1, Rgb c) {
    const int ax = std::max(0, static_cast<int>(std::floor(std::min(x0, x1))));
    const int bx = std::min(image.width - 1, static_cast<int>(std::ceil(std::max(x0, x1))) - 1);
    const int ay = std::max(0, static_cast<int>(std::floor(std::min(y0, y1))));
    const int by = std::min(image.height - 1, static_cast<int>(std::ceil(std::max(y0, y1))) - 1);
    for (int y = ay; y <= by; ++y) {
      for (int x = ax; x <= bx; ++x) image.set(x, y, c);
    }
  }

  // A segment `width` pixels wide (a square brush stepped along it).
  void line(double x0, double y0, double x1, double y1, double width, Rgb c) {
    const double steps = std::max(1.0, std::ceil(std::max(std::abs(x1 - x0), std::abs(y1 - y0))));
    for (int i = 0; i <= static_cast<int>(steps); ++i) {
      const double t = i / steps;
      const double x = x0 + t * (x1 - x0);
      const double y = y0 + t * (y1 - y0);
      fill(x - 0.5 * width, y - 0.5 * width, x + 0.5 * width, y + 0.5 * width, c);
    }
  }

  // Text with its top-left corner at (x, y), each font pixel `size` canvas pixels.
  void text(double x, double y, const std::string& text, double size, Rgb c) {
    std::string copy = text;
    std::vector<char> buffer(270 * (text.size() + 1) + 1024);
    const int quads = stb_easy_font_print(0, 0, copy.data(), nullptr, buffer.data(), static_cast<int>(buffer.size()));
    for (int q = 0; q < quads; ++q) {
      const float* v0 = reinterpret_cast<const float*>(buffer.data() + q * 64);
      const float* v2 = reinterpret_cast<const float*>(buffer.data() + q * 64 + 32);
      fill(x + v0[0] * size, y + v0[1] * size, x + v2[0] * size, y + v2[1] * size, c);
    }
  }
};

double text_width(const std::string& text, double size) {
  std::string copy = text;
  return stb_easy_font_width(copy.data()) * size;
}

std::string decade_label(int exponent) {
  if (exponent == 0) return "1";
  if (exponent == 1) return "10";
  return "1e" + std::to_string(exponent);
}

std::string tick_label(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

// A step of 1, 2 or 5 x 10^k giving about `count` intervals over `span`.
double nice_step(double span, int count) {
  const double raw = span / count;
  const double magnitude = std::pow(10.0, std::floor(std::log10(raw)));
  for (double m : {1.0, 2.0, 5.0}) {
    if (m * magnitude >= raw) return m * magnitude;
  }
  return 10.0 * magnitude;
}

}  // namespace

Image plot_log_y(std::span<const PlotSeries> series, const PlotOptions& options) {
  if (options.width < 160 || options.height < 120) {
    throw InvalidInput("plot", "a plot of " + std::to_string(options.width) + "x" + std::to_string(options.height) +
                                   " pixels is too small; it needs at least 160x120");
  }
  double x_min = std::numeric_limits<double>::infinity(), x_max = -x_min;
  double y_min = x_min, y_max = -x_min;
  for (const PlotSeries& s : series) {
    if (s.x.size() != s.y.size()) {
      throw InvalidInput("plot", "series " + s.name + " has " + std::to_string(s.x.size()) + " x values but " +
                                     std::to_string(s.y.size()) + " y values");
    }
    for (std::size_t i = 0; i < s.x.size(); ++i) {
      if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i]) || !(s.y[i] > 0)) continue;
      x_min = std::min(x_min, s.x[i]);
      x_max = std::max(x_max, s.x[i]);
      y_min = std::min(y_min, s.y[i]);
      y_max = std::max(y_max, s.y[i]);
    }
  }
  if (!(x_min <= x_max)) throw InvalidInput("plot", "no series has a point with a positive, finite y to plot");
  if (x_max == x_min) {
    x_min -= 0.5;
    x_max += 0.5;
  }
  int decade_lo = static_cast<int>(std::floor(std::log10(y_min)));
  int decade_hi = static_cast<int>(std::ceil(std::log10(y_max)));
  if (decade_hi == decade_lo) ++decade_hi;

  const int S = kScale;
  Canvas canvas{Image(options.width * S, options.height * S, kWhite)};
  const double font = 1.0 * S;  // stb_easy_font: about 6 x 8 pixels a character at size 1
  const double left = 62.0 * S, right = (options.width - 16.0) * S;
  const double top = (options.title.empty() ? 14.0 : 30.0) * S, bottom = (options.height - 40.0) * S;
  const auto px = [&](double x) { return left + (x - x_min) / (x_max - x_min) * (right - left); };
  const auto py = [&](double y) {
    return bottom - (std::log10(y) - decade_lo) / static_cast<double>(decade_hi - decade_lo) * (bottom - top);
  };

  // Grid, ticks and labels: a line per decade on y (every k-th when there are many), 1-2-5 steps on x.
  const int decade_step = std::max(1, (decade_hi - decade_lo + 7) / 8);
  for (int d = decade_lo; d <= decade_hi; d += decade_step) {
    const double y = py(std::pow(10.0, d));
    canvas.line(left, y, right, y, 1.0 * S, kGrid);
    canvas.line(left - 5 * S, y, left, y, 1.0 * S, kBlack);
    const std::string label = decade_label(d);
    canvas.text(left - 8 * S - text_width(label, font), y - 4 * S, label, font, kBlack);
  }
  const double step = nice_step(x_max - x_min, 5);
  for (double x = std::ceil(x_min / step) * step; x <= x_max + 1e-9 * step; x += step) {
    const double X = px(x);
    canvas.line(X, top, X, bottom, 1.0 * S, kGrid);
    canvas.line(X, bottom, X, bottom + 5 * S, 1.0 * S, kBlack);
    const std::string label = tick_label(std::abs(x) < 1e-12 * step ? 0.0 : x);
    canvas.text(X - 0.5 * text_width(label, font), bottom + 9 * S, label, font, kBlack);
  }
  canvas.line(left, top, left, bottom, 1.5 * S, kBlack);
  canvas.line(left, bottom, right, bottom, 1.5 * S, kBlack);
  if (!options.title.empty()) {
    canvas.text(0.5 * (left + right) - 0.5 * text_width(options.title, font * 1.5), 8 * S, options.title, font * 1.5,
                kBlack);
  }
  if (!options.x_label.empty()) {
    canvas.text(0.5 * (left + right) - 0.5 * text_width(options.x_label, font), bottom + 24 * S, options.x_label, font,
                kBlack);
  }
  if (!options.y_label.empty()) canvas.text(left + 4 * S, top - 12 * S, options.y_label, font, kBlack);

  // The series, then the legend in the top right corner.
  for (const PlotSeries& s : series) {
    bool pen_down = false;
    double last_x = 0, last_y = 0;
    for (std::size_t i = 0; i < s.x.size(); ++i) {
      if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i]) || !(s.y[i] > 0)) {
        pen_down = false;
        continue;
      }
      const double X = px(s.x[i]), Y = py(s.y[i]);
      if (pen_down) canvas.line(last_x, last_y, X, Y, 2.0 * S, s.color);
      canvas.fill(X - 2 * S, Y - 2 * S, X + 2 * S, Y + 2 * S, s.color);
      pen_down = true;
      last_x = X;
      last_y = Y;
    }
  }
  double legend_y = top + 6 * S;
  for (const PlotSeries& s : series) {
    if (s.name.empty()) continue;
    const double w = text_width(s.name, font);
    canvas.fill(right - w - 34 * S, legend_y - 2 * S, right - 4 * S, legend_y + 10 * S, kWhite);
    canvas.line(right - w - 30 * S, legend_y + 4 * S, right - w - 14 * S, legend_y + 4 * S, 2.0 * S, s.color);
    canvas.text(right - w - 8 * S, legend_y, s.name, font, kBlack);
    legend_y += 14 * S;
  }

  // Average down.
  Image out(options.width, options.height, kWhite);
  for (int y = 0; y < out.height; ++y) {
    for (int x = 0; x < out.width; ++x) {
      std::array<int, 3> sum{};
      for (int j = 0; j < S; ++j) {
        for (int i = 0; i < S; ++i) {
          const Rgb c = canvas.image.at(x * S + i, y * S + j);
          for (int k = 0; k < 3; ++k) sum[k] += c[k];
        }
      }
      out.set(x, y,
              {static_cast<std::uint8_t>(sum[0] / (S * S)), static_cast<std::uint8_t>(sum[1] / (S * S)),
               static_cast<std::uint8_t>(sum[2] / (S * S))});
    }
  }
  return out;
}

}  // namespace surfacer
