#include "core/render/rasterizer.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include "core/util/errors.h"
#include "core/util/format.h"

namespace surfacer {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr float kFar = std::numeric_limits<float>::infinity();

std::uint8_t shade(std::uint8_t channel, double intensity) {
  return static_cast<std::uint8_t>(std::clamp(std::lround(channel * intensity), 0L, 255L));
}

// Signed doubled area of (a, b, p) in screen space: > 0 when p is left of a->b (y down: clockwise on screen).
double edge(const Vec3& a, const Vec3& b, double px, double py) {
  return (b.x() - a.x()) * (py - a.y()) - (b.y() - a.y()) * (px - a.x());
}

}  // namespace

Image::Image(int w, int h, Rgb fill) : width(w), height(h), rgb(static_cast<std::size_t>(w) * h * 3) {
  for (std::size_t i = 0; i < rgb.size(); i += 3) std::copy(fill.begin(), fill.end(), rgb.begin() + i);
}

Rgb Image::at(int x, int y) const {
  const std::size_t i = (static_cast<std::size_t>(y) * width + x) * 3;
  return {rgb[i], rgb[i + 1], rgb[i + 2]};
}

void Image::set(int x, int y, Rgb c) {
  const std::size_t i = (static_cast<std::size_t>(y) * width + x) * 3;
  std::copy(c.begin(), c.end(), rgb.begin() + i);
}

Vec3 Camera::project(const Vec3& p) const {
  const Vec3 d = p - eye;
  const double z = d.dot(forward);
  return {0.5 * width + focal_pixels * d.dot(right) / z, 0.5 * height - focal_pixels * d.dot(up) / z, z};
}

Camera frame_camera(const Aabb& box, int width, int height, const ViewOptions& view) {
  if (width < 1 || height < 1) {
    throw InvalidInput(
        "view", "image size " + std::to_string(width) + "x" + std::to_string(height) + " must be at least 1x1 pixels");
  }
  if (!box.finite()) throw InvalidInput("view", "the box to frame is not finite (a mesh with no vertices?)");
  if (!(std::abs(view.elevation_degrees) < 90.0)) {
    throw InvalidInput(
        "view", "elevation " + format_number(view.elevation_degrees) + " degrees must lie strictly between -90 and 90");
  }
  if (!(view.field_of_view_degrees >= 1.0 && view.field_of_view_degrees <= 120.0)) {
    throw InvalidInput(
        "view", "field of view " + format_number(view.field_of_view_degrees) + " degrees must lie within 1..120");
  }
  if (!std::isfinite(view.azimuth_degrees)) throw InvalidInput("view", "azimuth must be a finite angle");
  const Vec3 center = 0.5 * (box.min + box.max);
  // A flat or point-like box still gets a picture: at least a small fraction of its largest side, or 1.
  double radius = 0.5 * box.size().norm();
  if (!(radius > 0)) radius = std::max(1.0, center.norm() * 1e-3);
  const double azimuth = view.azimuth_degrees * kPi / 180.0;
  const double elevation = view.elevation_degrees * kPi / 180.0;
  const Vec3 towards_eye(std::cos(elevation) * std::cos(azimuth), std::cos(elevation) * std::sin(azimuth),
                         std::sin(elevation));
  const double half_angle = 0.5 * view.field_of_view_degrees * kPi / 180.0;
  const double distance = 1.08 * radius / std::sin(half_angle);  // the bounding sphere inside the cone, 8 % margin

  Camera camera;
  camera.width = width;
  camera.height = height;
  camera.eye = center + distance * towards_eye;
  camera.forward = -towards_eye;
  camera.right = camera.forward.cross(Vec3::UnitZ()).normalized();
  camera.up = camera.right.cross(camera.forward);
  camera.focal_pixels = 0.5 * std::min(width, height) / std::tan(half_angle);
  return camera;
}

Rasterizer::Rasterizer(const Camera& camera, const RenderOptions& options)
    : camera_(camera), options_(options), scale_(std::clamp(options.supersample, 1, 4)) {
  camera_.width *= scale_;
  camera_.height *= scale_;
  camera_.focal_pixels *= scale_;
  buffer_ = Image(camera_.width, camera_.height, options_.background);
  depth_.assign(static_cast<std::size_t>(camera_.width) * camera_.height, kFar);
}

void Rasterizer::draw_mesh(const Mesh& mesh) {
  // The light comes from over the viewer's left shoulder.
  const Vec3 light = (-0.4 * camera_.right + 0.6 * camera_.up - camera_.forward).normalized();
  const double ambient = std::clamp(options_.ambient, 0.0, 1.0);
  std::vector<Vec3> screen(mesh.vertices.size());
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) screen[i] = camera_.project(mesh.vertices[i]);
  const int w = camera_.width;
  const int h = camera_.height;
  for (const Triangle& t : mesh.triangles) {
    if (t[0] >= screen.size() || t[1] >= screen.size() || t[2] >= screen.size()) continue;
    const Vec3& a = screen[t[0]];
    const Vec3& b = screen[t[1]];
    const Vec3& c = screen[t[2]];
    if (!(a.z() > 0 && b.z() > 0 && c.z() > 0)) continue;  // behind the eye (the framed box never is)
    const double area = edge(a, b, c.x(), c.y());
    if (area == 0 || !std::isfinite(area)) continue;
    const Vec3& pa = mesh.vertices[t[0]];
    Vec3 normal = (mesh.vertices[t[1]] - pa).cross(mesh.vertices[t[2]] - pa);
    const double length = normal.norm();
    if (!(length > 0)) continue;
    normal /= length;
    const double lambert = std::abs(normal.dot(light));  // two-sided
    const double intensity = ambient + (1.0 - ambient) * lambert;
    const Rgb color{shade(options_.surface[0], intensity), shade(options_.surface[1], intensity),
                    shade(options_.surface[2], intensity)};
    const int x0 = std::max(0, static_cast<int>(std::floor(std::min({a.x(), b.x(), c.x()}))));
    const int x1 = std::min(w - 1, static_cast<int>(std::ceil(std::max({a.x(), b.x(), c.x()}))));
    const int y0 = std::max(0, static_cast<int>(std::floor(std::min({a.y(), b.y(), c.y()}))));
    const int y1 = std::min(h - 1, static_cast<int>(std::ceil(std::max({a.y(), b.y(), c.y()}))));
    // Perspective-correct depth: 1/z is linear in screen space.
    const double ia = 1.0 / a.z(), ib = 1.0 / b.z(), ic = 1.0 / c.z();
    for (int y = y0; y <= y1; ++y) {
      const double py = y + 0.5;
      for (int x = x0; x <= x1; ++x) {
        const double px = x + 0.5;
        const double wa = edge(b, c, px, py) / area;
        const double wb = edge(c, a, px, py) / area;
        const double wc = 1.0 - wa - wb;
        if (wa < 0 || wb < 0 || wc < 0) continue;
        const float z = static_cast<float>(1.0 / (wa * ia + wb * ib + wc * ic));
        float& depth = depth_[static_cast<std::size_t>(y) * w + x];
        if (z >= depth) continue;
        depth = z;
        buffer_.set(x, y, color);
      }
    }
  }
}

void Rasterizer::draw_points(std::span<const Vec3> points) {
  std::vector<Vec3> screen;
  screen.reserve(points.size());
  for (const Vec3& p : points) {
    const Vec3 s = camera_.project(p);
    if (s.z() > 0 && s.allFinite()) screen.push_back(s);
  }
  if (screen.empty()) return;
  // Farthest first, so nearer dots cover them; nearer dots are brighter.
  std::sort(screen.begin(), screen.end(), [](const Vec3& l, const Vec3& r) { return l.z() > r.z(); });
  const double near = screen.back().z();
  const double far = screen.front().z();
  const double r = std::max(0.5, options_.point_radius_pixels) * scale_;
  for (const Vec3& s : screen) {
    const double t = far > near ? (s.z() - near) / (far - near) : 0.0;
    const double intensity = 1.0 - 0.45 * t;
    const Rgb color{shade(options_.points[0], intensity), shade(options_.points[1], intensity),
                    shade(options_.points[2], intensity)};
    const int x0 = std::max(0, static_cast<int>(std::floor(s.x() - r)));
    const int x1 = std::min(camera_.width - 1, static_cast<int>(std::ceil(s.x() + r)));
    const int y0 = std::max(0, static_cast<int>(std::floor(s.y() - r)));
    const int y1 = std::min(camera_.height - 1, static_cast<int>(std::ceil(s.y() + r)));
    for (int y = y0; y <= y1; ++y) {
      for (int x = x0; x <= x1; ++x) {
        const double dx = x + 0.5 - s.x();
        const double dy = y + 0.5 - s.y();
        if (dx * dx + dy * dy <= r * r) buffer_.set(x, y, color);
      }
    }
  }
}

Image Rasterizer::image() const {
  if (scale_ == 1) return buffer_;
  Image out(camera_.width / scale_, camera_.height / scale_, options_.background);
  const int n = scale_ * scale_;
  for (int y = 0; y < out.height; ++y) {
    for (int x = 0; x < out.width; ++x) {
      std::array<int, 3> sum{};
      for (int j = 0; j < scale_; ++j) {
        for (int i = 0; i < scale_; ++i) {
          const Rgb c = buffer_.at(x * scale_ + i, y * scale_ + j);
          for (int k = 0; k < 3; ++k) sum[k] += c[k];
        }
      }
      out.set(x, y,
              {static_cast<std::uint8_t>((sum[0] + n / 2) / n), static_cast<std::uint8_t>((sum[1] + n / 2) / n),
               static_cast<std::uint8_t>((sum[2] + n / 2) / n)});
    }
  }
  return out;
}

Image render_mesh(const Mesh& mesh, const Camera& camera, const RenderOptions& options, std::span<const Vec3> points) {
  Rasterizer rasterizer(camera, options);
  rasterizer.draw_mesh(mesh);
  rasterizer.draw_points(points);
  return rasterizer.image();
}

}  // namespace surfacer
