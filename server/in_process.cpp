#include "server/in_process.h"

#include <chrono>

#include "server/log.h"
#include "server/memory_budget.h"
#include "server/server.h"

namespace surfacer::server {

std::unique_ptr<InProcessServer> InProcessServer::start(int workers) {
  set_log_level(LogLevel::kWarn);
  ServerOptions options;
  options.listen = "";
  options.workers = workers;
  options.limits.memory_budget_bytes = default_memory_budget();
  return std::unique_ptr<InProcessServer>(new InProcessServer(SurfacerServer::start(options)));
}

InProcessServer::InProcessServer(std::unique_ptr<SurfacerServer> server) : server_(std::move(server)) {}

InProcessServer::~InProcessServer() { server_->shutdown(ShutdownMode::kCancel, std::chrono::seconds(5)); }

std::shared_ptr<grpc::Channel> InProcessServer::channel() { return server_->in_process_channel(); }

}  // namespace surfacer::server
