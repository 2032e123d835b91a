// An in-process Surfacer server: the whole service on a channel that does not touch the network, for `surfacer
// --local` and the Python package. It lives as long as the handle; destroying it cancels what still runs.
#pragma once

#include <memory>

namespace grpc {
class Channel;
}

namespace surfacer::server {

class SurfacerServer;

class InProcessServer {
 public:
  // Starts a memory-only server with `workers` worker threads (0: hardware threads) that logs warnings and errors
  // only (the caller prints its own progress). Throws std::runtime_error when it cannot start.
  static std::unique_ptr<InProcessServer> start(int workers);
  ~InProcessServer();
  InProcessServer(const InProcessServer&) = delete;
  InProcessServer& operator=(const InProcessServer&) = delete;

  std::shared_ptr<grpc::Channel> channel();

 private:
  explicit InProcessServer(std::unique_ptr<SurfacerServer> server);
  std::unique_ptr<SurfacerServer> server_;
};

}  // namespace surfacer::server
