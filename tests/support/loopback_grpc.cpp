#include "tests/support/loopback_grpc.h"

#include <grpcpp/server_builder.h>

#include <chrono>

namespace surfacer::testing {

LoopbackGrpcServer::LoopbackGrpcServer(const std::vector<grpc::Service*>& services,
                                       std::shared_ptr<grpc::ServerCredentials> credentials) {
  grpc::ServerBuilder builder;
  builder.AddListeningPort("127.0.0.1:0", credentials ? std::move(credentials) : grpc::InsecureServerCredentials(),
                           &port_);
  for (grpc::Service* service : services) builder.RegisterService(service);
  server_ = builder.BuildAndStart();
}

LoopbackGrpcServer::~LoopbackGrpcServer() {
  if (server_) server_->Shutdown(std::chrono::system_clock::now() + std::chrono::seconds(1));
}

}  // namespace surfacer::testing
