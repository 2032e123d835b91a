// Uploading inputs with Surfacer.Upload (particle frames, start meshes, velocity grids): bytes cut into chunks of
// at most 1 MiB, the first carrying the name and total_bytes, every one its index and CRC-32 (zlib polynomial); the
// server's answer (bytes stored and CRC-32 of the whole upload) is checked against what was sent.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "client/frame_assembler.h"
#include "client/particle_files.h"
#include "surfacer/v1/surfacer.grpc.pb.h"

namespace surfacer::client {

class Connection;
class ProgressDisplay;

struct UploadResult {
  std::string upload_id;
  std::uint64_t bytes = 0;
  std::uint32_t crc32 = 0;
};

struct UploadSettings {
  std::size_t chunk_bytes = kMaxChunkBytes;  // 1 .. kMaxChunkBytes
  std::chrono::system_clock::time_point deadline = std::chrono::system_clock::time_point::max();
  const std::atomic<bool>* stop = nullptr;  // when it turns true the upload is abandoned (CliError kCancelled)
};

// Uploads `bytes` as one upload named `name`. Throws rpc_error("uploading <name>", status) when the server refuses
// (e.g. RESOURCE_EXHAUSTED naming --max-upload-bytes: exit 4; UNAVAILABLE: exit 3), CliError(kIntegrity) when its
// answer does not match what was sent, CliError(kCancelled) when `settings.stop` fired.
UploadResult upload_bytes(v1::Surfacer::Stub& stub, const std::string& name, std::string_view bytes,
                          const UploadSettings& settings = {});

// Uploads a file as is, streamed from disk one chunk at a time (never held in memory). CliError(kUsage) naming the
// file when it cannot be read or changes size while being read; otherwise as upload_bytes().
UploadResult upload_file(v1::Surfacer::Stub& stub, const std::string& name, const std::filesystem::path& path,
                         const UploadSettings& settings = {});

// A deadline for an upload of `bytes`: the connection timeout and a margin, plus one second per MiB.
std::chrono::system_clock::time_point upload_deadline(const Connection& connection, std::uint64_t bytes);

// What one pending input gives when it is read: bytes in memory, or a file to stream.
struct UploadData {
  std::string name;                           // UploadChunk.name: the input file's name
  std::string bytes;                          // in memory ...
  std::optional<std::filesystem::path> file;  // ... or streamed from this file (then `bytes` is empty)
  std::uint64_t file_bytes = 0;               // size of `file`
  std::optional<std::int64_t> particles;      // particle frames: the number of particles
  std::string detail;                         // for the progress line, e.g. "12000 particles"
};

// An input of a job that is read and uploaded after connecting and before SubmitJob, one at a time, so a long
// sequence is never in memory at once and a bad file fails before any job is queued.
struct PendingUpload {
  std::string description;  // "particle frame 3 (data/fluid_0003.bgeo)"
  int frame = -1;           // the job's frame index this input feeds (particle frames), else -1
  // Reads (and validates) the input, refusing one the server would refuse by `limits`; may record what the content
  // tells in the spec (e.g. with_radius). Throws CliError(kUsage) naming the file and the line or byte offset of a
  // problem.
  std::function<UploadData(v1::JobSpec& spec, const InputLimits& limits)> read;
  // Stores the upload id in the spec.
  std::function<void(v1::JobSpec& spec, const std::string& upload_id)> set_id;
};

struct UploadSummary {
  int uploads = 0;
  std::uint64_t bytes = 0;
  std::map<int, std::int64_t> particles;  // frame index -> particles uploaded for it
};

// What the server of `connection` accepts of an input (GetServerInfo); the defaults when it cannot say.
InputLimits input_limits(Connection& connection);

// Reads and uploads every pending input in order (read within input_limits()), filling the spec's upload ids; one
// progress line per input. Errors as read() and upload_bytes()/upload_file(); CliError(kCancelled) when `stop`
// fires in between. `count`: only the first `count` inputs (an open sequence's first frame).
UploadSummary upload_inputs(Connection& connection, v1::JobSpec& spec, const std::vector<PendingUpload>& uploads,
                            ProgressDisplay& progress, const std::atomic<bool>* stop = nullptr,
                            std::size_t count = SIZE_MAX);

// --- Open sequences (ParticlesJob.open, AppendFrames; docs/ALGORITHMS.md §5, "Open sequences") ---------------------

// Whether the server of `connection` takes open sequences (its ServerInfo says open_sequences; older servers take a
// whole sequence at submit).
bool takes_open_sequences(Connection& connection);
// Whether `spec` can go to the server of `connection` as an open sequence: a particles job whose inputs are its
// frames, each uploaded, more than one, to a server that takes_open_sequences().
bool streams_as_open_sequence(Connection& connection, const v1::JobSpec& spec,
                              const std::vector<PendingUpload>& uploads);
// The spec an open sequence is submitted with: `spec`'s options and first frame, open set.
v1::JobSpec open_sequence_spec(const v1::JobSpec& spec);
// AppendFrames: `frames` join open job `job_id` (`end`: the last ones), or, with `abort_reason`, the job fails with
// it. Throws rpc_error("adding frames to job ID", status) (FAILED_PRECONDITION once the job has finished).
v1::Job append_frames(Connection& connection, const std::string& job_id, const std::vector<v1::ParticleFrame>& frames,
                      bool end, const std::string& abort_reason = "");

// Uploads the inputs after the first of an open sequence on a thread of its own, one at a time, each appended to the
// job once uploaded (the last with end), while the caller watches the job (or waits for finish()): the server
// surfaces frame k while frame k + 1 uploads. A frame that cannot be read or uploaded fails the job (AppendFrames'
// abort_reason), and its error, prefixed with the frame's description, is rethrown by finish(); a job that finished
// meanwhile (cancelled, failed) just stops the uploads (ended() then says false).
class SequenceFeeder {
 public:
  // `spec`: the whole job, `uploads[0]` uploaded (its id in `spec`); `summary`: what uploading it gave. The open
  // job's frames are `spec`'s frames uploads[0].frame, uploads[1].frame, ... in this order (a sub-job of a sequence
  // split across servers takes some of its frames). `stop` (may be null) ends the uploads (Ctrl-C). `progress` must
  // outlive the feeder.
  SequenceFeeder(Connection& connection, std::string job_id, v1::JobSpec spec, std::vector<PendingUpload> uploads,
                 UploadSummary summary, ProgressDisplay& progress, const std::atomic<bool>* stop);
  ~SequenceFeeder();  // stops and joins
  SequenceFeeder(const SequenceFeeder&) = delete;
  SequenceFeeder& operator=(const SequenceFeeder&) = delete;

  // Abandons the uploads still to come and the one in flight (the job has finished).
  void stop();
  // Waits for the uploads to end; returns what was uploaded, or rethrows the error that failed the job.
  UploadSummary finish();
  // After finish(): whether every frame joined the job and its sequence was ended (false when the feeder was
  // stopped or the job finished first).
  bool ended() const { return ended_; }

 private:
  void run();

  Connection& connection_;
  const std::string job_id_;
  v1::JobSpec spec_;
  const std::vector<PendingUpload> uploads_;
  UploadSummary summary_;
  ProgressDisplay& progress_;
  const std::atomic<bool>* stop_;
  std::atomic<bool> quit_{false};
  std::exception_ptr error_;
  bool ended_ = false;
  std::thread thread_;
};

}  // namespace surfacer::client
