#include "client/frame_writer.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <optional>
#include <set>

#include "client/exit_codes.h"
#include "client/output_files.h"
#include "client/vdb_writer.h"
#include "core/mesh/frame_codec.h"
#include "core/mesh/mesh_gltf.h"
#include "core/mesh/mesh_io.h"
#include "core/mesh/mesh_vtk.h"
#include "core/util/errors.h"
#include "core/util/json.h"
#include "core/util/parallel.h"
#include "wire/output.h"

namespace surfacer::client {
namespace {

std::string format_double(const char* fmt, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, fmt, v);
  return buf;
}

[[noreturn]] void write_failed(const std::filesystem::path& path, int error) {
  throw CliError(ExitCode::kUsage, "cannot write " + path.string() + ": " + std::strerror(error));
}

std::vector<std::string> metric_keys(const std::map<int, v1::FrameStats>& stats) {
  std::set<std::string> keys;
  for (const auto& [index, s] : stats) {
    for (const auto& [key, value] : s.metrics()) keys.insert(key);
  }
  return {keys.begin(), keys.end()};
}

std::string metric_cells(const v1::FrameStats& s, const std::vector<std::string>& keys) {
  std::string cells;
  for (const auto& key : keys) {
    cells += ',';
    const auto it = s.metrics().find(key);
    if (it != s.metrics().end()) cells += format_double("%.9g", it->second);
  }
  return cells;
}

}  // namespace

void write_file_atomically(const std::filesystem::path& path, std::string_view bytes) {
  std::filesystem::path tmp = path;
  tmp += ".tmp-" + std::to_string(::getpid());
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) write_failed(path, errno);
  std::size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      const int error = errno;
      ::close(fd);
      ::unlink(tmp.c_str());
      write_failed(path, error);
    }
    done += static_cast<std::size_t>(n);
  }
  if (::close(fd) != 0) {
    const int error = errno;
    ::unlink(tmp.c_str());
    write_failed(path, error);
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    const int error = errno;
    ::unlink(tmp.c_str());
    write_failed(path, error);
  }
}

std::string frame_file_name(int index, FileFormat format) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "frame_%04d.%s", index, file_format_name(format));
  return buf;
}

std::string pvd_collection(const std::vector<std::pair<double, std::string>>& frames) {
  std::string out = "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\">\n  <Collection>\n";
  for (const auto& [time, file] : frames) {
    out += "    <DataSet timestep=\"" + format_number(time) + "\" part=\"0\" file=\"" + xml_escape(file) + "\"/>\n";
  }
  return out + "  </Collection>\n</VTKFile>\n";
}

std::string file_series(const std::vector<std::pair<double, std::string>>& frames) {
  JsonWriter w;
  w.begin_object().key("file-series-version").value("1.0").key("files").begin_array();
  for (const auto& [time, file] : frames) w.begin_object().key("name").value(file).key("time").value(time).end_object();
  w.end_array().end_object();
  return w.str() + "\n";
}

std::string stats_csv(const std::map<int, v1::FrameStats>& stats) {
  const std::vector<std::string> keys = metric_keys(stats);
  std::vector<std::string> stages;
  for (const auto& [index, s] : stats) {
    for (const auto& t : s.timings()) {
      if (std::find(stages.begin(), stages.end(), t.stage()) == stages.end()) stages.push_back(t.stage());
    }
  }
  std::string csv = "frame,vertices,triangles,closed,manifold,euler,components,min_valence,min_angle,area,volume";
  for (const auto& stage : stages) csv += "," + stage + "_s";
  csv += ",total_s";
  // A metric named like a fixed column (active jobs report "volume", "area", "components") is told apart.
  const std::string header = csv + ",";
  for (const auto& key : keys) {
    csv += header.find("," + key + ",") == std::string::npos && key != "frame" ? "," + key : ",metric_" + key;
  }
  csv += '\n';
  for (const auto& [index, s] : stats) {
    const v1::MeshCheck& c = s.check();
    csv += std::to_string(index) + "," + std::to_string(s.vertices()) + "," + std::to_string(s.triangles()) + "," +
           (c.closed() ? "1" : "0") + "," + (c.edge_manifold() && c.vertex_manifold() ? "1" : "0") + "," +
           std::to_string(c.euler_characteristic()) + "," + std::to_string(c.components()) + "," +
           std::to_string(c.min_valence()) + "," + format_double("%.4f", c.min_angle_degrees()) + "," +
           format_double("%.9g", c.area()) + "," + format_double("%.9g", c.volume());
    double total = 0;
    for (const auto& stage : stages) {
      csv += ",";
      for (const auto& t : s.timings()) {
        if (t.stage() == stage) {
          csv += format_double("%.6f", t.seconds());
          total += t.seconds();
          break;
        }
      }
    }
    csv += ',';
    csv += format_double("%.6f", total);
    csv += metric_cells(s, keys);
    csv += '\n';
  }
  return csv;
}

std::string iterations_csv(const std::map<int, v1::FrameStats>& stats) {
  const std::vector<std::string> keys = metric_keys(stats);
  std::string csv = "frame,iteration,triangles";
  for (const auto& key : keys) csv += "," + key;
  csv += '\n';
  for (const auto& [index, s] : stats) {
    csv += std::to_string(index) + "," + std::to_string(s.iteration()) + "," + std::to_string(s.triangles()) +
           metric_cells(s, keys) + '\n';
  }
  return csv;
}

FrameWriter::FrameWriter(FrameOutputOptions options)
    : options_(std::move(options)), decode_threads_(resolve_threads(0)) {
  std::error_code ec;
  std::filesystem::create_directories(options_.dir, ec);
  if (ec || !std::filesystem::is_directory(options_.dir)) {
    throw CliError(ExitCode::kUsage, "cannot create the output directory " + options_.dir.string() + ": " +
                                         (ec ? ec.message() : std::string("not a directory")));
  }
  // Before any job runs: a directory that takes no files (read-only, a pseudo file system) is found now.
  const std::filesystem::path probe = options_.dir / (".surfacer-write-check-" + std::to_string(::getpid()));
  const int fd = ::open(probe.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
  if (fd < 0) {
    throw CliError(ExitCode::kUsage, "cannot write in the output directory " + options_.dir.string() + ": " +
                                         std::generic_category().message(errno) +
                                         "; give -o a directory you can write to");
  }
  ::close(fd);
  std::filesystem::remove(probe, ec);
}

std::vector<std::filesystem::path> FrameWriter::write(const ReceivedFrame& frame) {
  const std::optional<FrameCodec> known = wire::frame_codec(frame.encoding);
  if (!known) {
    throw CliError(ExitCode::kIntegrity,
                   "frame " + std::to_string(frame.index) + ": unknown MeshEncoding " + std::to_string(frame.encoding));
  }
  const FrameCodec codec = *known;
  std::vector<FileFormat> formats = options_.formats;
  if (formats.empty()) {
    try {
      formats.push_back(default_format(codec, frame.bytes));
    } catch (const Error& e) {
      throw CliError(ExitCode::kIntegrity, "frame " + std::to_string(frame.index) + ": its " +
                                               std::string(frame_codec_name(codec)) +
                                               " bytes passed the CRC-32 check but are not a frame: " + e.what());
    }
  }

  std::optional<Mesh> mesh;
  auto decoded = [&]() -> const Mesh& {
    if (!mesh) {
      try {
        mesh = decode_frame(frame.bytes, codec, decode_threads_);
      } catch (const std::exception& e) {
        throw CliError(ExitCode::kIntegrity, "frame " + std::to_string(frame.index) + ": its " +
                                                 std::string(frame_codec_name(codec)) +
                                                 " bytes passed the CRC-32 check but do not decode: " + e.what());
      }
    }
    return *mesh;
  };

  std::vector<std::filesystem::path> written;
  for (FileFormat format : formats) {
    const std::filesystem::path path = frame_file_path(options_, frame.index, format);
    std::string converted;
    std::string_view bytes;
    switch (format) {
      case FileFormat::kDrc:
        if (codec == FrameCodec::kDraco) {
          bytes = frame.bytes;
        } else {
          converted = to_standard_draco(frame.bytes, codec, decoded());
          bytes = converted;
        }
        break;
      case FileFormat::kPly:
        if (codec == FrameCodec::kPly) {
          bytes = frame.bytes;  // lossless: double-precision positions as sent
        } else {
          converted = write_ply(decoded());
          bytes = converted;
        }
        break;
      case FileFormat::kObj:
        converted = write_obj(decoded());
        bytes = converted;
        break;
      case FileFormat::kVtk:  // positions in double precision when the frame has them (lossless PLY frames)
        converted = write_vtk(decoded(), codec == FrameCodec::kPly);
        bytes = converted;
        break;
      case FileFormat::kVtu:
        converted = write_vtu(decoded(), codec == FrameCodec::kPly);
        bytes = converted;
        break;
      case FileFormat::kGlb:  // pieced frames as received; one-mesh frames encoded as Draco pieces here, on every core
        if (codec == FrameCodec::kPly) {  // raw frames: plain binary glTF, for readers without Draco
          converted = write_glb(decoded());
          bytes = converted;
          break;
        }
        try {
          converted = to_gltf(frame.bytes, codec, decoded, decode_threads_);
        } catch (const Error& e) {
          if (e.kind() != ErrorKind::kInvalidInput || e.field() != "quantization_bits") throw;
          throw CliError(ExitCode::kUsage, "frame " + std::to_string(frame.index) + ": --format glb: " + e.what());
        }
        bytes = converted;
        break;
      case FileFormat::kGltf:
        converted = write_gltf(decoded());
        bytes = converted;
        break;
      case FileFormat::kVdb:
        converted = write_vdb(decoded(), options_.vdb_voxel_size);
        bytes = converted;
        break;
    }
    write_file_atomically(path, bytes);
    written.push_back(path);
  }
  stats_[frame.index] = frame.stats;
  files_[frame.index] = written;
  write_file_atomically(options_.dir / "stats.csv", stats_csv(stats_));
  if (kind_ == "optimize" || frame.stats.iteration() != 0) iterations_ = true;
  if (iterations_) write_file_atomically(options_.dir / "iterations.csv", iterations_csv(stats_));
  write_time_series();
  return written;
}

void FrameWriter::write_time_series() const {
  if (options_.file) return;  // one frame
  // The files' base name: "frames" in a directory, the pattern's name without its placeholder.
  std::string base = "frames";
  if (options_.pattern) {
    const std::string stem = std::filesystem::path(*options_.pattern).stem().string();
    base = stem.substr(0, stem.find('{')) + stem.substr(stem.find('}') + 1);
    while (!base.empty() && (base.back() == '_' || base.back() == '-' || base.back() == '.')) base.pop_back();
    if (base.empty()) base = "frames";
  }
  for (const FileFormat format : {FileFormat::kVtu, FileFormat::kVtk}) {
    if (std::find(options_.formats.begin(), options_.formats.end(), format) == options_.formats.end()) continue;
    std::vector<std::pair<double, std::string>> frames;  // (time = the frame's number, file relative to the dir)
    for (const auto& [index, files] : files_) {
      const std::filesystem::path file = frame_file_path(options_, index, format);
      frames.emplace_back(output_frame_number(options_, index), file.filename().string());
    }
    if (format == FileFormat::kVtu) {
      write_file_atomically(options_.dir / (base + ".pvd"), pvd_collection(frames));
    } else {
      write_file_atomically(options_.dir / (base + ".vtk.series"), file_series(frames));
    }
  }
}

FileFormat default_format(FrameCodec codec, std::string_view bytes) {
  switch (codec) {
    case FrameCodec::kDracoPieces:
      return gltf_holds(bytes, codec) ? FileFormat::kGlb : FileFormat::kDrc;
    case FrameCodec::kDraco:
      return FileFormat::kDrc;
    case FrameCodec::kMeshopt:
    case FrameCodec::kPly:
      break;
  }
  return FileFormat::kPly;
}

}  // namespace surfacer::client
