// Parsed command lines of the `surfacer` CLI: plain structs filled by parse_command_line() (cli.h) and consumed
// by run_invocation() (commands.h).
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "surfacer/v1/surfacer.pb.h"

namespace surfacer::client {

// How to talk to a remote server: TLS and the bearer token, already read from their files by
// parse_command_line() (so a bad file is a usage error before anything else happens).
struct SecurityOptions {
  std::optional<std::string> token;  // --token, --token-file or $SURFACER_TOKEN: sent as "authorization: Bearer ..."
  std::string token_source;          // "--token", "--token-file FILE" or "$SURFACER_TOKEN", for messages
  bool tls = false;                  // --tls, or implied by --tls-ca / --tls-cert
  std::string ca_pem;                // --tls-ca contents; empty: the system's root certificates
  std::string cert_pem;              // --tls-cert contents (mutual TLS), with key_pem
  std::string key_pem;               // --tls-key contents
  std::optional<std::string> server_name;  // --tls-server-name: the name the server's certificate must carry
  bool allow_insecure = false;             // --allow-insecure: a token may go in plaintext to a non-loopback host
};

// Where the server is. Exactly one of `server` / in-process is used: an explicit --server wins, then
// $SURFACER_SERVER, else an in-process server (--local, or the default). `server` may also be a comma-separated
// list or a dns:/// name with several addresses (scale-out, client/server_list.h); Connection::open() takes one
// target.
struct ConnectOptions {
  std::optional<std::string> server;  // host:port (or a list, see above)
  std::optional<int> workers;         // in-process server's worker threads (0, or unset: hardware threads)
  double timeout_seconds = 10.0;      // how long to wait for the connection (and for unary calls to start)
  SecurityOptions security;
  bool verbose = false;  // -v: which server produced each frame, sub-jobs (scale-out)

  bool local() const { return !server.has_value(); }
};

// Particle frames from files: each input is one file or a sequence pattern (`fluid_{}.bgeo`, `fluid_{:04d}.ply`)
// expanded over [start, end]; frames are the inputs' files in order (frame i = the i-th file).
struct ParticleInputOptions {
  std::vector<std::string> inputs;
  std::optional<int> start;
  std::optional<int> end;
};

// What to submit: a whole JobSpec from a file (`spec_file`), or one job type. Its options are the proto's own fields,
// set in `spec` as the user gave them (flags and Python keywords are derived from the field names:
// client/job_fields.h); nothing is defaulted or range-checked here (prepare_job() checks `spec` with the server's own
// wire::check_job_options()). The inputs below are files (or in-memory stand-ins) that prepare_job() reads into
// `spec` or uploads.
struct JobOptions {
  std::optional<std::filesystem::path> spec_file;
  v1::JobSpec spec;
  // How the user named each field set (request path "spec.particles.r_outer" -> "--r-outer" or "r_outer"), so an
  // error names it their way; fields not in it are named as the CLI spells them, or as Python keywords with
  // `keywords`.
  std::map<std::string, std::string> names;
  bool keywords = false;
  std::optional<std::string> name;  // --name; unset: made from the inputs' file names

  // isosurface: one frame per scene; optimize and active advect: the one scene; active morph: from, to.
  std::vector<std::filesystem::path> scenes;
  ParticleInputOptions particles;                        // particles, active coat
  std::optional<std::filesystem::path> container_scene;  // particles: container.solid
  std::optional<std::filesystem::path> start_mesh;       // optimize: uploaded (else polygonized by the server)
  std::optional<std::filesystem::path> velocity_grid;    // active advect: the values, uploaded (geometry in `spec`)
};

enum class FileFormat { kDrc, kPly, kObj, kVtk, kVtu, kGlb, kGltf, kVdb };

struct FrameOutputOptions {
  std::filesystem::path dir;
  // Files written per frame. Empty: one file in the frame's own encoding (.drc for Draco, .ply for meshopt and raw
  // PLY).
  std::vector<FileFormat> formats;
  // -o PATTERN (e.g. out/surface_{:04d}.ply, client/output_files.h): each frame's one file is named by the pattern
  // instead of DIR/frame_NNNN.<ext>; `dir` is then the pattern's directory (stats.csv goes there) and `formats` the
  // format of its extension.
  std::optional<std::string> pattern = std::nullopt;
  // -o FILE.ext (no placeholder, not an existing directory): a job of one frame written to that one file; `dir` is
  // its directory and `formats` the format of its extension.
  std::optional<std::filesystem::path> file = std::nullopt;
  // The number in frame i's file name: frame_numbers[i] (the input files' own frame numbers), or i past its end.
  std::vector<int> frame_numbers = {};
  // Voxel edge of .vdb files in scene units; 0: each frame's mean edge length (client/vdb_writer.h).
  double vdb_voxel_size = 0.0;
};

// How `run` and `watch` report (client/run_report.h): --progress, --json, --preview.
enum class ProgressFormat { kAuto, kJson };  // auto: a bar on a terminal, plain lines otherwise
struct ReportOptions {
  ProgressFormat progress = ProgressFormat::kAuto;
  bool json = false;     // the summary as one JSON document on stdout
  bool preview = false;  // a PNG per frame (and the optimize plot) in DIR/preview/
};

// Pictures of frame files (client/preview.h): one camera for the whole sequence.
struct PreviewOptions {
  int width = 480;
  int height = 360;
  double azimuth_degrees = -60.0;
  double elevation_degrees = 25.0;
  std::vector<std::filesystem::path> particles;  // none, or one file per frame, drawn as dots over the surface
};

struct RunCommand {
  JobOptions job;
  FrameOutputOptions output;
  ReportOptions report;
};
struct SubmitCommand {
  JobOptions job;
};
struct WatchCommand {
  std::string job_id;
  int from_frame = 0;
  FrameOutputOptions output;
  ReportOptions report;
};
struct StatusCommand {
  std::string job_id;
  bool json = false;
};
struct ListCommand {
  std::vector<std::string> states;  // lower-case state names ("running"); empty: all
  bool json = false;
};
// `surfacer preview`: no server involved.
struct PreviewCommand {
  std::vector<std::filesystem::path> frames;            // mesh files (.drc .ply .obj)
  std::optional<std::filesystem::path> iterations_csv;  // an optimize run's iterations.csv: a plot of e_d, e_n
  std::filesystem::path dir;
  PreviewOptions options;
};
struct CancelCommand {
  std::string job_id;
};
struct HealthCommand {
  std::string service;  // "" = the whole server
};

using Command = std::variant<RunCommand, SubmitCommand, WatchCommand, StatusCommand, ListCommand, CancelCommand,
                             HealthCommand, PreviewCommand>;

struct Invocation {
  ConnectOptions connect;
  Command command;
};

}  // namespace surfacer::client
