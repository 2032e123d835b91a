#include "client/preview.h"

#include <fstream>
#include <limits>
#include <ostream>
#include <sstream>

#include "client/frame_writer.h"
#include "core/mesh/mesh_io.h"
#include "core/particles/particle_io.h"
#include "core/render/plot.h"
#include "core/render/png.h"
#include "core/render/rasterizer.h"
#include "core/util/errors.h"
#include "core/util/text.h"

namespace surfacer::client {
namespace {

namespace fs = std::filesystem;

// Core's errors about one input become usage errors (the file is the user's); they already name the file.
template <class F>
auto user_file(F&& f) {
  try {
    return f();
  } catch (const Error& e) {
    throw CliError(ExitCode::kUsage, e.what());
  }
}

Mesh load_mesh(const fs::path& path) {
  return user_file([&] { return read_mesh(path); });
}

std::vector<Vec3> load_particles(const fs::path& path) {
  return user_file([&] { return read_particles(path).positions; });
}

ViewOptions view_of(const PreviewOptions& options) {
  ViewOptions view;
  view.azimuth_degrees = options.azimuth_degrees;
  view.elevation_degrees = options.elevation_degrees;
  return view;
}

fs::path png_path(const fs::path& dir, const fs::path& frame) {
  fs::path name = frame.filename();
  return dir / name.replace_extension(".png");
}

void create_dir(const fs::path& dir) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) throw CliError(ExitCode::kUsage, "cannot create the preview directory " + dir.string() + ": " + ec.message());
}

}  // namespace

std::vector<fs::path> render_frame_previews(const std::vector<fs::path>& frames, const fs::path& dir,
                                            const PreviewOptions& options) {
  if (!options.particles.empty() && options.particles.size() != frames.size()) {
    throw CliError(ExitCode::kUsage, "--particles names " + std::to_string(options.particles.size()) + " file(s) for " +
                                         std::to_string(frames.size()) +
                                         " frame(s); give one particle file per frame, in the frames' order");
  }
  for (std::size_t i = 0; i < frames.size(); ++i) {  // two frames would write one picture
    for (std::size_t j = 0; j < i; ++j) {
      if (frames[i].filename().replace_extension() == frames[j].filename().replace_extension()) {
        throw CliError(ExitCode::kUsage, "frames " + frames[j].string() + " and " + frames[i].string() +
                                             " would both be pictured as " + png_path(dir, frames[i]).string() +
                                             "; preview each one once");
      }
    }
  }
  // First pass: the union of every frame's bounds, so one camera shows the whole sequence. (Meshes are read twice
  // rather than all held at once.)
  Aabb box = Aabb::empty();
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const Mesh mesh = load_mesh(frames[i]);
    for (const Vec3& v : mesh.vertices) box.merge(v);
    if (!options.particles.empty()) {
      for (const Vec3& p : load_particles(options.particles[i])) box.merge(p);
    }
  }
  if (!box.finite()) {
    throw CliError(ExitCode::kUsage, "the frames hold no vertices to picture (" + frames.front().string() + " ...)");
  }
  const Camera camera = user_file([&] { return frame_camera(box, options.width, options.height, view_of(options)); });
  create_dir(dir);
  std::vector<fs::path> written;
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const Mesh mesh = load_mesh(frames[i]);
    std::vector<Vec3> points;
    if (!options.particles.empty()) points = load_particles(options.particles[i]);
    const fs::path out = png_path(dir, frames[i]);
    write_file_atomically(out, encode_png(render_mesh(mesh, camera, {}, points)));
    written.push_back(out);
  }
  return written;
}

fs::path render_iterations_plot(const fs::path& csv, const fs::path& dir, const PreviewOptions& options) {
  std::ifstream in(csv, std::ios::binary);
  if (!in) throw CliError(ExitCode::kUsage, "cannot read " + csv.string());
  std::stringstream buffer;
  buffer << in.rdbuf();
  const std::string text = buffer.str();
  LineReader lines(text);
  std::string_view line;
  const auto split = [](std::string_view l) {
    std::vector<std::string> cells;
    std::size_t pos = 0;
    while (true) {
      const std::size_t comma = l.find(',', pos);
      cells.emplace_back(trim(l.substr(pos, comma == std::string_view::npos ? std::string_view::npos : comma - pos)));
      if (comma == std::string_view::npos) return cells;
      pos = comma + 1;
    }
  };
  if (!lines.next(line)) throw CliError(ExitCode::kUsage, csv.string() + " is empty (an optimize run writes it)");
  const std::vector<std::string> header = split(line);
  const auto column = [&](const std::string& name) -> int {
    for (std::size_t i = 0; i < header.size(); ++i) {
      if (header[i] == name) return static_cast<int>(i);
    }
    return -1;
  };
  const int x_column = column("iteration") >= 0 ? column("iteration") : column("frame");
  if (x_column < 0) {
    throw CliError(ExitCode::kUsage,
                   csv.string() + " has no iteration column (is it an optimize run's iterations.csv?)");
  }
  std::vector<PlotSeries> series{{"e_d", {}, {}, {31, 119, 180}}, {"e_n", {}, {}, {214, 39, 40}}};
  const int columns[2] = {column("e_d"), column("e_n")};
  while (lines.next(line)) {
    if (trim(line).empty()) continue;
    const std::vector<std::string> cells = split(line);
    double x = 0;
    if (static_cast<int>(cells.size()) <= x_column || !parse_double(cells[x_column], x)) {
      throw CliError(ExitCode::kUsage, csv.string() + ": line " + std::to_string(lines.line()) +
                                           ": no number in column " + header[x_column]);
    }
    for (int s = 0; s < 2; ++s) {
      double y = std::numeric_limits<double>::quiet_NaN();
      if (columns[s] >= 0 && columns[s] < static_cast<int>(cells.size())) parse_double(cells[columns[s]], y);
      series[s].x.push_back(x);
      series[s].y.push_back(y);  // empty or non-positive: a gap in the line
    }
  }
  std::vector<PlotSeries> plotted;
  for (int s = 0; s < 2; ++s) {
    if (columns[s] >= 0) plotted.push_back(std::move(series[s]));
  }
  if (plotted.empty()) throw CliError(ExitCode::kUsage, csv.string() + " has neither an e_d nor an e_n column");
  PlotOptions plot;
  plot.width = options.width;
  plot.height = options.height;
  plot.title = "optimize: error per iteration";
  plot.x_label = "iteration";
  plot.y_label = "error (log)";
  const Image image = [&] {
    try {
      return plot_log_y(plotted, plot);
    } catch (const Error& e) {
      throw CliError(ExitCode::kUsage, csv.string() + ": nothing to plot: " + e.what());
    }
  }();
  create_dir(dir);
  const fs::path out = dir / "iterations.png";
  write_file_atomically(out, encode_png(image));
  return out;
}

ExitCode run_preview(const PreviewCommand& command, std::ostream& out) {
  std::vector<fs::path> written;
  if (!command.frames.empty()) written = render_frame_previews(command.frames, command.dir, command.options);
  if (command.iterations_csv)
    written.push_back(render_iterations_plot(*command.iterations_csv, command.dir, command.options));
  for (const fs::path& path : written) out << path.string() << "\n";
  out << std::flush;
  return ExitCode::kSuccess;
}

}  // namespace surfacer::client
