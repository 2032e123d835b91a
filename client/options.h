// Parsed command lines of the `surfacer` CLI: plain structs filled by parse_command_line() (cli.h) and consumed
// by run_invocation() (commands.h).
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <variant>
#include <vector>

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

using Box = std::array<double, 6>;  // x0,y0,z0,x1,y1,z1 (min < max on every axis)
using Triple = std::array<double, 3>;

struct IsosurfaceOptions {
  std::vector<std::filesystem::path> scenes;  // one frame per scene, in order
  std::optional<int> cells;                   // cells along the longest axis; default 128 when cell_size is unset
  std::optional<double> cell_size;
  std::optional<Box> bounds;
  std::optional<std::string> method;  // "cubes" or "tiles"; unset: the server's default (tiles)
};

// Particle frames from files: each input is one file or a sequence pattern (`fluid_{}.bgeo`, `fluid_{:04d}.ply`)
// expanded over [start, end]; frames are the inputs' files in order (frame i = the i-th file).
struct ParticleInputOptions {
  std::vector<std::string> inputs;
  std::optional<int> start;
  std::optional<int> end;
};

// `particles` job (Williams 2008). Unset values take the server's defaults.
struct ParticlesOptions {
  ParticleInputOptions input;
  std::optional<double> r_inner;  // exactly one of r_inner / derive_r_inner
  bool derive_r_inner = false;
  std::optional<double> r_outer;
  std::optional<double> spacing_factor;
  std::optional<std::array<int, 3>> sweeps;  // Laplacian, Bilaplacian, polish
  std::optional<double> relaxation;
  std::optional<double> erosion;
  bool unconstrained_polish = false;
  bool vertex_only_band = false;
  std::optional<double> min_angle;
  std::optional<Box> container_box;
  std::optional<std::filesystem::path> container_scene;
  std::optional<int> min_particles;
};

// Which flows an `optimize` job runs (--flows d,n,t).
struct FlowSet {
  bool d = true;
  bool n = true;
  bool t = true;
};

// `optimize` job (Ohtake-Belyaev-Pasko 2002): a start mesh file, or the server polygonizes the scene.
struct OptimizeOptions {
  std::filesystem::path scene;
  std::optional<std::filesystem::path> start_mesh;  // .ply/.obj/.drc, uploaded as is
  std::optional<int> start_cells;
  std::optional<std::string> start_method;  // "cubes" or "tiles"
  std::optional<Box> start_bounds;
  std::optional<int> iterations;
  std::optional<double> tolerance;
  std::optional<int> snapshot_every;
  std::optional<FlowSet> flows;
  std::optional<double> c_d;
  std::optional<double> c_n;
  std::optional<double> c_t;
  std::optional<double> step_bound;
  bool modified_flows = false;
  std::optional<int> t_flow_iterations;
  std::optional<double> subdivide;  // adaptive subdivision threshold
  std::optional<std::int64_t> triangle_budget;
};

// `active coat`: a skin over a particle sequence.
struct ActiveCoatOptions {
  ParticleInputOptions input;
  double kernel_radius = 0;
  std::optional<double> iso;
  std::optional<int> substeps;
};

// `active morph`: scene `from` into scene `to`.
struct ActiveMorphOptions {
  std::filesystem::path from;
  std::filesystem::path to;
  std::optional<double> tolerance;
  std::optional<int> max_frames;
  std::optional<double> frame_time;
};

// A sampled velocity field file: raw little-endian float32 x y z per node, x fastest.
struct VelocityGridOptions {
  std::filesystem::path file;
  Triple origin{};
  Triple spacing{};
  std::array<int, 3> dims{};
};

// `active advect`: a scene carried by the Enright field or an uploaded velocity grid.
struct ActiveAdvectOptions {
  std::filesystem::path scene;
  std::optional<double> enright_period;  // used when `velocity_grid` is unset (Enright); unset: server default
  std::optional<VelocityGridOptions> velocity_grid;
  double frame_interval = 0;
  int frames = 0;
};

// `active` job (Desbrun-Cani 1998): one mode plus the engine's parameters.
struct ActiveOptions {
  std::variant<ActiveCoatOptions, ActiveMorphOptions, ActiveAdvectOptions> mode;
  double grid_spacing = 0;
  std::optional<Box> bounds;
  std::optional<double> alpha;
  std::optional<double> beta;
  std::optional<double> gamma;
  std::optional<double> delta;
  std::optional<double> cfl;
  std::optional<std::string> polygonizer;  // "tiles" or "cubes"
};

// What to submit: a whole JobSpec from JSON (`spec`), or one job type's own options; the output overrides apply
// to all.
struct JobOptions {
  std::optional<std::filesystem::path> spec;
  std::optional<IsosurfaceOptions> isosurface;
  std::optional<ParticlesOptions> particles;
  std::optional<OptimizeOptions> optimize;
  std::optional<ActiveOptions> active;
  std::optional<std::string> name;
  // --encoding: "draco", "meshopt" or "raw" (lossless PLY; --raw is its alias); unset: the server's default (Draco).
  std::optional<std::string> encoding;
  bool normals = false;  // per-vertex normals in every frame
  std::optional<int> quantization_bits;
};

enum class FileFormat { kDrc, kPly, kObj, kVtk, kVtu, kGlb };

struct FrameOutputOptions {
  std::filesystem::path dir;
  // Files written per frame. Empty: one file in the frame's own encoding (.drc for Draco, .ply for meshopt and raw
  // PLY).
  std::vector<FileFormat> formats;
  // -o PATTERN (e.g. out/surface_{:04d}.ply, client/output_files.h): each frame's one file is named by the pattern
  // instead of DIR/frame_NNNN.<ext>; `dir` is then the pattern's directory (stats.csv goes there) and `formats` the
  // format of its extension.
  std::optional<std::string> pattern = std::nullopt;
  // The number in frame i's file name: frame_numbers[i] (the input files' own frame numbers), or i past its end.
  std::vector<int> frame_numbers = {};
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
