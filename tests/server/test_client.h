// Test helpers: a server on a real loopback port and a client that collects a job's frames and checks chunking.
#pragma once

#include <grpcpp/grpcpp.h>

#include <map>
#include <memory>
#include <string>
#include <vector>

#include "server/server.h"
#include "surfacer/v1/surfacer.grpc.pb.h"

namespace surfacer::testing {

struct ReceivedFrame {
  v1::FrameHeader header;
  std::string bytes;
  int chunks = 0;
  std::size_t max_chunk_bytes = 0;
};

struct WatchResult {
  grpc::Status status;
  std::vector<v1::JobState> states;  // every state event, in order
  v1::Job final_job;
  std::map<int, ReceivedFrame> frames;
  std::vector<int> frame_order;  // frame indices in arrival order
  int progress_events = 0;
  std::vector<double> fractions;  // each progress event's fraction, in order
  std::string integrity_error;    // empty when every chunk and frame checksum matched
};

// Watches `job_id` to the end, reassembling frames and verifying chunk indices, sizes and CRC-32s.
// `token`: sent as `authorization: Bearer TOKEN` when not empty.
WatchResult watch_job(v1::Surfacer::Stub& stub, const std::string& job_id, int from_frame = 0,
                      const std::string& token = "");

// A server listening on 127.0.0.1:<free port>, with a stub connected through that real port.
struct LoopbackServer {
  explicit LoopbackServer(server::ServerOptions options = default_options());
  static server::ServerOptions default_options();

  std::unique_ptr<server::SurfacerServer> server;
  std::shared_ptr<grpc::Channel> channel;
  std::unique_ptr<v1::Surfacer::Stub> stub;
};

// Parses a JSON scene (protobuf JSON mapping); fails the test on error.
v1::Scene scene_from_json(const std::string& json);
v1::Scene scene_from_file(const std::string& path);
v1::JobSpec isosurface_spec(const std::vector<v1::Scene>& scenes, int cells);

// A stub on a plain-text channel to `address` ("127.0.0.1:PORT").
std::unique_ptr<v1::Surfacer::Stub> make_stub(const std::string& address);

// GetJob; the call's status in *status.
v1::Job get_job(v1::Surfacer::Stub& stub, const std::string& id, grpc::Status* status = nullptr);

grpc::Status submit(v1::Surfacer::Stub& stub, const v1::JobSpec& spec, std::string* job_id,
                    const std::string& token = "");

// CancelJob of `id`; the job as answered in *job.
grpc::Status cancel_job(v1::Surfacer::Stub& stub, const std::string& id, v1::Job* job = nullptr);

// The value of one sample line `name{labels} value` (labels as printed) of a Prometheus text exposition, or -1.
double metric_sample(const std::string& text, const std::string& series);

// Uploads `bytes` in chunks of 1 MiB and returns the upload id (a failed upload fails the test).
std::string upload(v1::Surfacer::Stub& stub, const std::string& bytes, v1::UploadResponse* response_out = nullptr);

}  // namespace surfacer::testing
