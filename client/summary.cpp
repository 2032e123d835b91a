#include "client/summary.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <vector>

#include "client/connection.h"

namespace surfacer::client {
namespace {

std::string seconds_text(double s) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3f", s);
  return buf;
}

std::string pad_left(const std::string& text, std::size_t width) {
  return text.size() >= width ? text : std::string(width - text.size(), ' ') + text;
}

}  // namespace

std::string particles_summary_table(const std::map<int, v1::FrameStats>& stats,
                                    const std::map<int, std::int64_t>& uploaded, double wall_seconds) {
  std::vector<std::array<std::string, 4>> rows;
  rows.push_back({"frame", "particles", "triangles", "seconds"});
  std::int64_t total_particles = 0;
  std::int64_t total_triangles = 0;
  double total_seconds = 0;
  bool particles_known = true;
  for (const auto& [index, s] : stats) {
    std::string particles = "-";
    const auto metric = s.metrics().find("particles");
    if (metric != s.metrics().end() && std::isfinite(metric->second)) {
      const auto n = static_cast<std::int64_t>(std::llround(metric->second));
      particles = std::to_string(n);
      total_particles += n;
    } else if (const auto it = uploaded.find(index); it != uploaded.end()) {
      particles = std::to_string(it->second);
      total_particles += it->second;
    } else {
      particles_known = false;
    }
    double seconds = 0;
    for (const auto& t : s.timings()) seconds += t.seconds();
    total_seconds += seconds;
    total_triangles += s.triangles();
    rows.push_back({std::to_string(index), particles, std::to_string(s.triangles()), seconds_text(seconds)});
  }
  const std::size_t frames = stats.size();
  rows.push_back({"total", particles_known ? std::to_string(total_particles) : std::string("-"),
                  std::to_string(total_triangles), seconds_text(total_seconds)});

  std::array<std::size_t, 4> width{};
  for (const auto& row : rows) {
    for (std::size_t c = 0; c < 4; ++c) width[c] = std::max(width[c], row[c].size());
  }
  std::string text;
  for (const auto& row : rows) {
    for (std::size_t c = 0; c < 4; ++c) text += (c == 0 ? "" : "  ") + pad_left(row[c], width[c]);
    text += '\n';
  }
  char line[160];
  std::snprintf(line, sizeof line, "%zu frame%s, %.3f s per frame on the server", frames, frames == 1 ? "" : "s",
                frames > 0 ? total_seconds / static_cast<double>(frames) : 0.0);
  text += line;
  if (wall_seconds > 0 && frames > 0) {
    std::snprintf(line, sizeof line, ", %.3f s per frame wall-clock (%.1f s in all)",
                  wall_seconds / static_cast<double>(frames), wall_seconds);
    text += line;
  }
  text += '\n';
  return text;
}

std::string elapsed_text(std::chrono::steady_clock::time_point start) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.1f s",
                std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
  return buf;
}

std::string job_error_text(const v1::Job& job) {
  if (job.error().code() == 0 && job.error().message().empty()) return "";
  std::string text = status_code_name(static_cast<grpc::StatusCode>(job.error().code()));
  if (!job.error().message().empty()) text += ": " + job.error().message();
  return text;
}

}  // namespace surfacer::client
