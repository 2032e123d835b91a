// A connection to a Surfacer server: a channel to host:port, or an in-process server that lives as long as the
// Connection (server/in_process.h).
#pragma once

#include <grpcpp/channel.h>
#include <grpcpp/client_context.h>
#include <grpcpp/support/status.h>

#include <chrono>
#include <memory>
#include <optional>
#include <string>

#include "client/exit_codes.h"
#include "client/options.h"
#include "client/rpc_error.h"  // rpc_error, status_code_name: how callers report a failed call
#include "surfacer/v1/surfacer.grpc.pb.h"

namespace surfacer::server {
class InProcessServer;
}

namespace surfacer::client {

// Throws CliError(kUsage) when options.workers is given for a remote server: it sizes the in-process server only.
void check_workers(const ConnectOptions& options);

class Connection {
 public:
  // Connects to `options.server`, waiting up to `options.timeout_seconds` (CliError kUnreachable otherwise), or
  // starts an in-process server with `options.workers` workers (its logs are limited to warnings).
  static std::unique_ptr<Connection> open(const ConnectOptions& options);
  ~Connection();

  Connection(const Connection&) = delete;
  Connection& operator=(const Connection&) = delete;

  v1::Surfacer::Stub& stub() { return *stub_; }
  grpc::Channel& channel() { return *channel_; }
  const std::shared_ptr<grpc::Channel>& channel_ptr() const { return channel_; }
  bool local() const { return local_server_ != nullptr; }
  // "server localhost:50051" or "the in-process server", for messages.
  std::string describe() const;
  // Waits until the channel is connected again (after a broken stream); false when `deadline` passes first.
  bool wait_connected(std::chrono::system_clock::time_point deadline);
  // Deadline for unary calls: the connection timeout plus a margin for the call itself.
  std::chrono::system_clock::time_point unary_deadline() const;
  // SubmitJob with the unary deadline; the caller words and classifies a failure (the CLI and scale-out differ).
  grpc::Status submit(const v1::JobSpec& spec, v1::SubmitJobResponse& response);
  // The server's version and limits (GetServerInfo), asked once; nullopt from a server that predates the call.
  // Throws rpc_error("asking the server's limits", status) when the server cannot answer.
  const std::optional<v1::ServerInfo>& server_info();

 private:
  Connection() = default;

  ConnectOptions options_;
  std::unique_ptr<server::InProcessServer> local_server_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::Surfacer::Stub> stub_;
  bool server_info_asked_ = false;
  std::optional<v1::ServerInfo> server_info_;
};

// Asks the server to cancel `job_id`, waiting at most `within` for the answer. Best effort (a client giving up on a
// job it started): returns whether the server answered OK.
bool cancel_job(Connection& connection, const std::string& job_id,
                std::chrono::milliseconds within = std::chrono::seconds(5));

}  // namespace surfacer::client
