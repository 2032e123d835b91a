// Uploading inputs with Surfacer.Upload (particle frames, start meshes, velocity grids): bytes cut into chunks of
// at most 1 MiB, the first carrying the name and total_bytes, every one its index and CRC-32 (zlib polynomial); the
// server's answer (bytes stored and CRC-32 of the whole upload) is checked against what was sent.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <string_view>
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
// fires in between.
UploadSummary upload_inputs(Connection& connection, v1::JobSpec& spec, const std::vector<PendingUpload>& uploads,
                            ProgressDisplay& progress, const std::atomic<bool>* stop = nullptr);

}  // namespace surfacer::client
