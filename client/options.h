// Parsed command lines of the `surfacer` CLI: plain structs filled by parse_command_line() (cli.h) and consumed
// by run_invocation() (commands.h).
#pragma once

#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <variant>
#include <vector>

namespace surfacer::client {

// Where the server is. Exactly one of `server` / in-process is used: an explicit --server wins, then
// $SURFACER_SERVER, else an in-process server (--local, or the default).
struct ConnectOptions {
  std::optional<std::string> server;  // host:port
  int workers = 0;                    // in-process server's worker threads; 0 = hardware threads
  double timeout_seconds = 10.0;      // how long to wait for the connection (and for unary calls to start)

  bool local() const { return !server.has_value(); }
};

struct IsosurfaceOptions {
  std::vector<std::filesystem::path> scenes;  // one frame per scene, in order
  std::optional<int> cells;                   // cells along the longest axis; default 128 when cell_size is unset
  std::optional<double> cell_size;
  std::optional<std::array<double, 6>> bounds;  // x0,y0,z0,x1,y1,z1
  std::optional<std::string> method;            // "cubes"
};

// What to submit: a whole JobSpec from JSON (`spec`), or a job type's own options; the output overrides apply
// to both.
struct JobOptions {
  std::optional<std::filesystem::path> spec;
  std::optional<IsosurfaceOptions> isosurface;
  std::optional<std::string> name;
  bool raw = false;      // lossless PLY frames instead of Draco
  bool normals = false;  // per-vertex normals in every frame
  std::optional<int> quantization_bits;
};

enum class FileFormat { kDrc, kPly, kObj };

struct FrameOutputOptions {
  std::filesystem::path dir;
  // Files written per frame. Empty: one file in the frame's own encoding (.drc for Draco, .ply for raw PLY).
  std::vector<FileFormat> formats;
};

struct RunCommand {
  JobOptions job;
  FrameOutputOptions output;
};
struct SubmitCommand {
  JobOptions job;
};
struct WatchCommand {
  std::string job_id;
  int from_frame = 0;
  FrameOutputOptions output;
};
struct StatusCommand {
  std::string job_id;
};
struct ListCommand {
  std::vector<std::string> states;  // lower-case state names ("running"); empty: all
};
struct CancelCommand {
  std::string job_id;
};
struct HealthCommand {
  std::string service;  // "" = the whole server
};

using Command =
    std::variant<RunCommand, SubmitCommand, WatchCommand, StatusCommand, ListCommand, CancelCommand, HealthCommand>;

struct Invocation {
  ConnectOptions connect;
  Command command;
};

}  // namespace surfacer::client
