// surfacer.v1.Surfacer as a gRPC callback service. gRPC threads only validate, enqueue and stream: every frame is
// computed on the worker pool, and WatchJob streams are fed from there.
#pragma once

#include <atomic>
#include <memory>

#include "server/auth.h"
#include "server/job.h"
#include "server/options.h"
#include "server/scheduler.h"
#include "server/uploads.h"
#include "surfacer/v1/surfacer.grpc.pb.h"

namespace surfacer::server {

class MemoryBudget;
class Store;
struct ServerMetrics;
class OpenUploads;
class WatchSlots;

struct ServiceState {
  ServerOptions options;
  int worker_threads = 1;
  Scheduler* scheduler = nullptr;
  UploadStore* uploads = nullptr;
  Store* store = nullptr;           // null: memory only
  const TokenAuth* auth = nullptr;  // null: no authentication, every caller is `open_tenant`
  Tenant open_tenant;
  Usage* usage = nullptr;
  const JobHooks* hooks = nullptr;
  ServerMetrics* metrics = nullptr;
  MemoryBudget* memory = nullptr;  // --memory-budget: uploads being received and watch streams draw from it
  UploadActivity upload_activity;  // each tenant's latest upload chunk (open sequences' idle check)
  std::atomic<bool> accepting{true};
};

// The caller's tenant, or UNAUTHENTICATED.
const Tenant* authenticate(const ServiceState& state, const grpc::CallbackServerContext& context, grpc::Status& status);

// SubmitJob takes its request as bytes and parses it itself (a scene nested too deep gets a clear error).
class SurfacerService final : public v1::Surfacer::WithRawCallbackMethod_SubmitJob<v1::Surfacer::CallbackService> {
 public:
  explicit SurfacerService(ServiceState& state);
  ~SurfacerService() override;

  grpc::ServerUnaryReactor* SubmitJob(grpc::CallbackServerContext* context, const grpc::ByteBuffer* request,
                                      grpc::ByteBuffer* response) override;
  grpc::ServerReadReactor<v1::UploadChunk>* Upload(grpc::CallbackServerContext* context,
                                                   v1::UploadResponse* response) override;
  grpc::ServerUnaryReactor* AppendFrames(grpc::CallbackServerContext* context, const v1::AppendFramesRequest* request,
                                         v1::Job* response) override;
  grpc::ServerWriteReactor<v1::JobEvent>* WatchJob(grpc::CallbackServerContext* context,
                                                   const v1::WatchJobRequest* request) override;
  grpc::ServerUnaryReactor* GetJob(grpc::CallbackServerContext* context, const v1::GetJobRequest* request,
                                   v1::Job* response) override;
  grpc::ServerUnaryReactor* ListJobs(grpc::CallbackServerContext* context, const v1::ListJobsRequest* request,
                                     v1::ListJobsResponse* response) override;
  grpc::ServerUnaryReactor* CancelJob(grpc::CallbackServerContext* context, const v1::CancelJobRequest* request,
                                      v1::Job* response) override;
  grpc::ServerUnaryReactor* GetServerInfo(grpc::CallbackServerContext* context, const v1::GetServerInfoRequest* request,
                                          v1::ServerInfo* response) override;

 private:
  // Validates the spec, creates the job and queues it. Throws surfacer::Error (the refusal's status).
  void submit(const v1::SubmitJobRequest& request, const Tenant& tenant, v1::SubmitJobResponse& response);
  // One page of the tenant's jobs. Throws InvalidInput for a bad filter, page size or token.
  void list_jobs(const v1::ListJobsRequest& request, const Tenant& tenant, v1::ListJobsResponse& response) const;

  ServiceState& state_;
  std::unique_ptr<OpenUploads> open_uploads_;  // ends uploads left idle (--upload-idle-timeout)
  std::unique_ptr<WatchSlots> watch_slots_;    // WatchJob streams per job (--max-watchers-per-job)
};

}  // namespace surfacer::server
