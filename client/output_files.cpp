#include "client/output_files.h"

#include <algorithm>
#include <cctype>
#include <cstdio>

#include "client/exit_codes.h"
#include "client/particle_files.h"
#include "core/particles/particle_io.h"
#include "core/util/errors.h"

namespace surfacer::client {
namespace {

CliError usage(const std::string& message) { return CliError(ExitCode::kUsage, message); }

constexpr FileFormat kAllFormats[] = {FileFormat::kDrc, FileFormat::kPly, FileFormat::kObj, FileFormat::kVtk,
                                      FileFormat::kVtu, FileFormat::kGlb, FileFormat::kGltf, FileFormat::kVdb};

}  // namespace

std::vector<std::string> file_format_names() {
  std::vector<std::string> names;
  for (FileFormat f : kAllFormats) names.emplace_back(file_format_name(f));
  return names;
}

std::optional<FileFormat> file_format_from_name(std::string_view name) {
  for (FileFormat f : kAllFormats) {
    if (name == file_format_name(f)) return f;
  }
  return std::nullopt;
}

const char* file_format_name(FileFormat format) {
  switch (format) {
    case FileFormat::kDrc:
      return "drc";
    case FileFormat::kPly:
      return "ply";
    case FileFormat::kObj:
      return "obj";
    case FileFormat::kVtk:
      return "vtk";
    case FileFormat::kVtu:
      return "vtu";
    case FileFormat::kGlb:
      return "glb";
    case FileFormat::kGltf:
      return "gltf";
    case FileFormat::kVdb:
      return "vdb";
  }
  return "bin";
}

FrameOutputOptions frame_output_options(const std::string& target, const std::vector<std::string>& formats,
                                        const std::string& command) {
  if (target.empty())
    throw usage(command + " needs an output directory: -o DIR (or a file pattern: -o 'out/f_{:04d}.ply')");
  FrameOutputOptions options;
  const std::filesystem::path path(target);
  std::string extension = path.extension().string();
  std::transform(extension.begin(), extension.end(), extension.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  const std::optional<FileFormat> format =
      extension.size() > 1 ? file_format_from_name(std::string_view(extension).substr(1)) : std::nullopt;
  std::error_code ec;
  const bool pattern = is_sequence_pattern(target);
  // -o out/mesh.ply: the one frame of the job in that file (a job of several frames is refused before it runs).
  const bool one_file = !pattern && format && !std::filesystem::is_directory(path, ec);
  if (!pattern && !one_file) {
    options.dir = target;
    for (const std::string& name : formats) {
      const std::optional<FileFormat> f = file_format_from_name(name);
      if (!f) throw usage("--format " + name + ": not a file format; use drc, ply, obj, vtk, vtu or glb");
      if (std::find(options.formats.begin(), options.formats.end(), *f) == options.formats.end()) {
        options.formats.push_back(*f);
      }
    }
    return options;
  }
  if (pattern) {
    if (is_sequence_pattern(path.parent_path().string())) {
      throw usage("-o " + target + ": the frame placeholder must be in the file name, not in a directory name");
    }
    try {
      expand_sequence(target, 0, 0);  // the placeholder's syntax
    } catch (const Error& e) {
      throw usage("-o " + target + ": " + e.what());
    }
    if (!format || is_sequence_pattern(extension)) {
      throw usage("-o " + target +
                  ": a file pattern's extension sets the format; end it in .drc, .ply, .obj, .vtk, .vtu or .glb (e.g. "
                  "-o 'out/surface_{:04d}.ply')");
    }
  }
  // A pattern or one file: the extension sets the one format.
  if (!formats.empty()) {
    throw usage("--format with -o " + target + ": the " + (pattern ? "pattern's" : "file's") +
                " extension sets the one format; drop --format, or write several formats with -o DIR --format LIST");
  }
  options.dir = path.has_parent_path() ? path.parent_path() : std::filesystem::path(".");
  options.formats = {*format};
  if (pattern) {
    options.pattern = target;
  } else {
    options.file = path;
  }
  return options;
}

int output_frame_number(const FrameOutputOptions& options, int index) {
  return index >= 0 && static_cast<std::size_t>(index) < options.frame_numbers.size()
             ? options.frame_numbers[static_cast<std::size_t>(index)]
             : index;
}

void check_one_file(const FrameOutputOptions& options, std::optional<int> frames) {
  if (!options.file || frames == 1) return;
  const std::filesystem::path& f = *options.file;
  const std::string example = (f.parent_path() / (f.stem().string() + "_{:04d}" + f.extension().string())).string();
  throw usage("-o " + f.string() + " names one file, but the job writes " +
              (frames ? std::to_string(*frames) + " frames" : std::string("several frames")) +
              ": give a frame placeholder, e.g. -o '" + example + "', or a directory");
}

std::filesystem::path frame_file_path(const FrameOutputOptions& options, int index, FileFormat format) {
  if (options.file) {
    check_one_file(options, index == 0 ? 1 : index + 1);
    return *options.file;
  }
  const int number = output_frame_number(options, index);
  if (options.pattern) return expand_sequence(*options.pattern, number, number).front();
  char name[48];
  std::snprintf(name, sizeof name, "frame_%04d.%s", number, file_format_name(format));
  return options.dir / name;
}

std::vector<int> output_numbers(const std::vector<std::optional<int>>& numbers) {
  std::vector<int> out;
  for (std::size_t i = 0; i < numbers.size(); ++i) {
    if (!numbers[i] || (i > 0 && *numbers[i] <= out.back())) return {};
    out.push_back(*numbers[i]);
  }
  return out;
}

}  // namespace surfacer::client
