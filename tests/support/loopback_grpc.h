// A gRPC server with test-local services (fakes, recorders) on 127.0.0.1 at a port of its choosing.
#pragma once

#include <grpcpp/security/server_credentials.h>
#include <grpcpp/server.h>

#include <memory>
#include <string>
#include <vector>

namespace surfacer::testing {

// Serves `services` (not owned: they must outlive the server); shut down with a one-second grace on destruction.
class LoopbackGrpcServer {
 public:
  explicit LoopbackGrpcServer(const std::vector<grpc::Service*>& services,
                              std::shared_ptr<grpc::ServerCredentials> credentials = nullptr);  // null: plain text
  ~LoopbackGrpcServer();
  LoopbackGrpcServer(const LoopbackGrpcServer&) = delete;
  LoopbackGrpcServer& operator=(const LoopbackGrpcServer&) = delete;

  bool started() const { return server_ != nullptr; }
  int port() const { return port_; }
  std::string address() const { return "127.0.0.1:" + std::to_string(port_); }

 private:
  int port_ = 0;
  std::unique_ptr<grpc::Server> server_;
};

}  // namespace surfacer::testing
