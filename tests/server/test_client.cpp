#include "tests/server/test_client.h"

#include <google/protobuf/util/json_util.h>
#include <gtest/gtest.h>
#include <zlib.h>

#include <fstream>
#include <sstream>

namespace surfacer::testing {
namespace {

std::uint32_t crc(const std::string& s) {
  return static_cast<std::uint32_t>(::crc32(0, reinterpret_cast<const Bytef*>(s.data()), s.size()));
}

}  // namespace

WatchResult watch_job(v1::Surfacer::Stub& stub, const std::string& job_id, int from_frame, const std::string& token) {
  WatchResult result;
  grpc::ClientContext context;
  if (!token.empty()) context.AddMetadata("authorization", "Bearer " + token);
  v1::WatchJobRequest request;
  request.set_job_id(job_id);
  request.set_from_frame(from_frame);
  auto reader = stub.WatchJob(&context, request);
  v1::JobEvent event;
  ReceivedFrame* current = nullptr;
  while (reader->Read(&event)) {
    switch (event.event_case()) {
      case v1::JobEvent::kState:
        result.states.push_back(event.state().state());
        result.final_job = event.state();
        break;
      case v1::JobEvent::kProgress:
        ++result.progress_events;
        result.fractions.push_back(event.progress().fraction());
        break;
      case v1::JobEvent::kFrame: {
        const int index = event.frame().frame_index();
        current = &result.frames[index];
        current->header = event.frame();
        result.frame_order.push_back(index);
        break;
      }
      case v1::JobEvent::kChunk: {
        const auto& chunk = event.chunk();
        if (!current || chunk.frame_index() != current->header.frame_index()) {
          result.integrity_error = "chunk for a frame that was not announced";
          break;
        }
        if (chunk.chunk_index() != current->chunks) result.integrity_error = "chunk out of order";
        if (crc(chunk.data()) != chunk.crc32()) result.integrity_error = "chunk crc mismatch";
        current->max_chunk_bytes = std::max(current->max_chunk_bytes, chunk.data().size());
        current->bytes += chunk.data();
        ++current->chunks;
        if (chunk.last()) {
          if (current->chunks != current->header.num_chunks()) result.integrity_error = "chunk count mismatch";
          if (current->bytes.size() != current->header.total_bytes()) result.integrity_error = "frame size mismatch";
          if (crc(current->bytes) != current->header.crc32()) result.integrity_error = "frame crc mismatch";
          current = nullptr;
        }
        break;
      }
      case v1::JobEvent::EVENT_NOT_SET:
        result.integrity_error = "empty event";
        break;
    }
  }
  result.status = reader->Finish();
  return result;
}

server::ServerOptions LoopbackServer::default_options() {
  server::ServerOptions options;
  options.listen = "127.0.0.1:0";
  options.workers = 2;
  return options;
}

LoopbackServer::LoopbackServer(server::ServerOptions options) {
  server = server::SurfacerServer::start(options);
  channel = grpc::CreateChannel("127.0.0.1:" + std::to_string(server->port()), grpc::InsecureChannelCredentials());
  stub = v1::Surfacer::NewStub(channel);
}

v1::Scene scene_from_json(const std::string& json) {
  v1::Scene scene;
  const auto status = google::protobuf::util::JsonStringToMessage(json, &scene);
  EXPECT_TRUE(status.ok()) << status.ToString() << "\n" << json;
  return scene;
}

v1::Scene scene_from_file(const std::string& path) {
  std::ifstream in(path);
  EXPECT_TRUE(in.good()) << path;
  std::stringstream ss;
  ss << in.rdbuf();
  return scene_from_json(ss.str());
}

v1::JobSpec isosurface_spec(const std::vector<v1::Scene>& scenes, int cells) {
  v1::JobSpec spec;
  spec.set_name("test");
  auto* iso = spec.mutable_isosurface();
  for (const auto& s : scenes) *iso->add_scenes() = s;
  iso->set_cells(cells);
  return spec;
}

grpc::Status submit(v1::Surfacer::Stub& stub, const v1::JobSpec& spec, std::string* job_id, const std::string& token) {
  grpc::ClientContext context;
  if (!token.empty()) context.AddMetadata("authorization", "Bearer " + token);
  v1::SubmitJobRequest request;
  *request.mutable_spec() = spec;
  v1::SubmitJobResponse response;
  auto status = stub.SubmitJob(&context, request, &response);
  if (job_id) *job_id = response.job_id();
  return status;
}

grpc::Status cancel_job(v1::Surfacer::Stub& stub, const std::string& id, v1::Job* job) {
  grpc::ClientContext context;
  v1::CancelJobRequest request;
  request.set_job_id(id);
  v1::Job answer;
  return stub.CancelJob(&context, request, job ? job : &answer);
}

std::string upload(v1::Surfacer::Stub& stub, const std::string& bytes, v1::UploadResponse* response_out) {
  grpc::ClientContext context;
  v1::UploadResponse response;
  auto writer = stub.Upload(&context, &response);
  for (std::size_t offset = 0; offset < bytes.size() || offset == 0; offset += 1 << 20) {
    v1::UploadChunk chunk;
    if (offset == 0) chunk.set_total_bytes(bytes.size());
    chunk.set_data(bytes.substr(offset, 1 << 20));
    EXPECT_TRUE(writer->Write(chunk));
    if (bytes.empty()) break;
  }
  writer->WritesDone();
  const auto status = writer->Finish();
  EXPECT_TRUE(status.ok()) << status.error_message();
  if (response_out) *response_out = response;
  return response.upload_id();
}

std::unique_ptr<v1::Surfacer::Stub> make_stub(const std::string& address) {
  return v1::Surfacer::NewStub(grpc::CreateChannel(address, grpc::InsecureChannelCredentials()));
}

v1::Job get_job(v1::Surfacer::Stub& stub, const std::string& id, grpc::Status* status) {
  grpc::ClientContext context;
  v1::GetJobRequest request;
  request.set_job_id(id);
  v1::Job job;
  const grpc::Status s = stub.GetJob(&context, request, &job);
  if (status) *status = s;
  return job;
}

double metric_sample(const std::string& text, const std::string& series) {
  const auto at = text.find("\n" + series + " ");
  if (at == std::string::npos) return -1;
  return std::stod(text.substr(at + series.size() + 2));
}

}  // namespace surfacer::testing
