#include "server/server.h"

#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>

#include <condition_variable>
#include <stdexcept>
#include <thread>

#include "server/jobs.h"
#include "server/log.h"
#include "server/service.h"
#include "server/uploads.h"
#include "server/worker_pool.h"

namespace surfacer::server {

struct SurfacerServer::Impl {
  explicit Impl(const ServerOptions& options)
      : threads(options.workers > 0 ? options.workers
                                    : std::max(1, static_cast<int>(std::thread::hardware_concurrency()))),
        pool(threads),
        scheduler(pool, options.max_queued_jobs),
        service(state) {
    state.options = options;
    state.worker_threads = threads;
    state.scheduler = &scheduler;
    state.uploads = &uploads;
  }

  int threads;
  WorkerPool pool;
  UploadStore uploads;
  Scheduler scheduler;
  ServiceState state;
  SurfacerService service;
  std::unique_ptr<grpc::Server> grpc_server;
  int port = 0;

  std::mutex mutex;
  std::condition_variable cv;
  bool shutting_down = false;
  bool done = false;
};

std::unique_ptr<SurfacerServer> SurfacerServer::start(const ServerOptions& options) {
  auto impl = std::make_unique<Impl>(options);
  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  if (!options.listen.empty()) {
    builder.AddListeningPort(options.listen, grpc::InsecureServerCredentials(), &impl->port);
  }
  builder.RegisterService(&impl->service);
  impl->grpc_server = builder.BuildAndStart();
  if (!impl->grpc_server || (!options.listen.empty() && impl->port == 0)) {
    throw std::runtime_error("cannot listen on " + options.listen +
                             " (address in use or not valid?); choose another with --listen");
  }
  if (auto* health = impl->grpc_server->GetHealthCheckService()) {
    health->SetServingStatus(true);
  }
  log_event(LogLevel::kInfo, "server_started",
            {{"listen", options.listen.empty() ? "in-process" : options.listen},
             {"port", std::to_string(impl->port)},
             {"workers", std::to_string(impl->threads)}});
  return std::unique_ptr<SurfacerServer>(new SurfacerServer(std::move(impl)));
}

SurfacerServer::SurfacerServer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

SurfacerServer::~SurfacerServer() { shutdown(ShutdownMode::kCancel, std::chrono::milliseconds(0)); }

int SurfacerServer::port() const { return impl_->port; }

std::shared_ptr<grpc::Channel> SurfacerServer::in_process_channel() {
  return impl_->grpc_server->InProcessChannel(grpc::ChannelArguments());
}

void SurfacerServer::shutdown(ShutdownMode mode, std::chrono::milliseconds deadline) {
  {
    std::unique_lock lock(impl_->mutex);
    if (impl_->shutting_down) {
      impl_->cv.wait(lock, [&] { return impl_->done; });
      return;
    }
    impl_->shutting_down = true;
  }
  Impl& s = *impl_;
  s.state.accepting.store(false);
  if (auto* health = s.grpc_server->GetHealthCheckService()) health->SetServingStatus(false);
  log_event(LogLevel::kInfo, "server_stopping",
            {{"mode", mode == ShutdownMode::kDrain ? "drain" : "cancel"},
             {"active_jobs", std::to_string(s.scheduler.active_jobs())}});
  const auto until = std::chrono::steady_clock::now() + deadline;
  if (mode == ShutdownMode::kDrain) {
    while (s.scheduler.active_jobs() > 0 && std::chrono::steady_clock::now() < until) {
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
  }
  s.scheduler.cancel_all("server shutting down");
  // Running frames see the cancel token within a fraction of a second.
  const auto cancel_until = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while (s.scheduler.active_jobs() > 0 && std::chrono::steady_clock::now() < cancel_until) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  // Watch streams of finished jobs end by themselves; give them a moment, then cancel what is left.
  s.grpc_server->Shutdown(std::chrono::system_clock::now() + std::chrono::seconds(2));
  s.pool.stop();
  log_event(LogLevel::kInfo, "server_stopped");
  {
    std::lock_guard lock(s.mutex);
    s.done = true;
  }
  s.cv.notify_all();
}

void SurfacerServer::cancel_jobs(const std::string& reason) { impl_->scheduler.cancel_all(reason); }

void SurfacerServer::wait() {
  std::unique_lock lock(impl_->mutex);
  impl_->cv.wait(lock, [&] { return impl_->done; });
}

}  // namespace surfacer::server
