#include "client/connection.h"

#include <grpcpp/create_channel.h>
#include <grpcpp/security/credentials.h>

#include <cmath>
#include <stdexcept>

#include "client/health.h"
#include "client/security.h"
#include "server/in_process.h"
#include "wire/protocol.h"

namespace surfacer::client {
namespace {

// Why a channel that never connected failed, as gRPC tells it on a call that does not wait for the connection
// (e.g. "failed to connect to all addresses; last error: ... CERTIFICATE_VERIFY_FAILED"); empty when unknown.
std::string connect_failure_reason(const std::shared_ptr<grpc::Channel>& channel) {
  try {
    check_health(channel, "", std::chrono::system_clock::now() + std::chrono::seconds(2));
  } catch (const CliError& e) {
    std::string text = e.what();
    const std::string prefix = "health check: ";
    if (text.rfind(prefix, 0) == 0) text = text.substr(prefix.size());
    return text;
  }
  return "";
}

}  // namespace

void check_workers(const ConnectOptions& options) {
  if (options.local() || !options.workers) return;
  throw CliError(ExitCode::kUsage, "--workers sizes the in-process server, but the server here is " + *options.server +
                                       "; a remote server's workers are set where it runs (surfacer-server --workers "
                                       "N)");
}

std::unique_ptr<Connection> Connection::open(const ConnectOptions& options) {
  std::unique_ptr<Connection> connection(new Connection());
  connection->options_ = options;
  if (options.local()) {
    try {
      connection->local_server_ = server::InProcessServer::start(options.workers.value_or(0));
    } catch (const std::exception& e) {
      throw CliError(ExitCode::kUnreachable, std::string("cannot start the in-process server: ") + e.what());
    }
    connection->channel_ = connection->local_server_->channel();
  } else {
    const std::string& target = *options.server;
    check_token_transport(target, options.security);
    grpc::ChannelArguments args;
    // Frames are cut into <= 1 MiB chunks and no message exceeds 4 MiB (surfacer.proto), so the defaults hold.
    add_channel_arguments(options.security, args);
    connection->channel_ = grpc::experimental::CreateCustomChannelWithInterceptors(
        target, channel_credentials(options.security), args, auth_interceptors(options.security));
    auto deadline = std::chrono::system_clock::now() +
                    std::chrono::milliseconds(static_cast<long long>(std::llround(options.timeout_seconds * 1000)));
    if (!connection->channel_->WaitForConnected(deadline)) {
      std::string message = "cannot reach a Surfacer server at " + target + " within " +
                            std::to_string(static_cast<int>(std::ceil(options.timeout_seconds))) + " s";
      const std::string reason = connect_failure_reason(connection->channel_);
      if (!reason.empty()) message += ": " + reason;
      if (options.security.tls) {
        message +=
            "; with TLS, check --tls-ca (the CA that signed the server's certificate), --tls-server-name (a name "
            "the certificate carries) and, when the server requires client certificates, --tls-cert/--tls-key";
      } else {
        message +=
            "; is surfacer-server running there? Check --server or $SURFACER_SERVER, or raise --timeout (a server "
            "with TLS needs --tls or --tls-ca FILE)";
      }
      throw CliError(ExitCode::kUnreachable, message);
    }
  }
  connection->stub_ = v1::Surfacer::NewStub(connection->channel_);
  return connection;
}

Connection::~Connection() {
  stub_.reset();
  channel_.reset();
  local_server_.reset();
}

std::string Connection::describe() const {
  if (local()) return "the in-process server";
  return "the server at " + *options_.server + (options_.security.tls ? " (TLS)" : "");
}

bool Connection::wait_connected(std::chrono::system_clock::time_point deadline) {
  return channel_->WaitForConnected(deadline);
}

std::chrono::system_clock::time_point Connection::unary_deadline() const {
  return std::chrono::system_clock::now() +
         std::chrono::milliseconds(static_cast<long long>(std::llround(options_.timeout_seconds * 1000))) +
         std::chrono::seconds(20);
}

namespace {

// What a job spec holds many of, for the message that refuses one too large to send: "2000000 scenes".
std::string bulk_of(const v1::JobSpec& spec) {
  if (spec.has_isosurface()) return std::to_string(spec.isosurface().scenes_size()) + " scenes";
  if (spec.has_particles()) return std::to_string(spec.particles().frames_size()) + " particle frames";
  if (spec.has_active() && spec.active().has_coat()) {
    return std::to_string(spec.active().coat().frames_size()) + " particle frames";
  }
  return "its options";
}

}  // namespace

grpc::Status Connection::submit(const v1::JobSpec& spec, v1::SubmitJobResponse& response) {
  v1::SubmitJobRequest request;
  *request.mutable_spec() = spec;
  if (const std::size_t bytes = request.ByteSizeLong(); bytes > wire::kMaxMessageBytes) {
    // The server would see only gRPC's "larger than max"; say what is large and how to split it.
    std::string frames;
    if (const auto& info = server_info(); info && info->limits().max_frames() > 0) {
      frames = " (the server takes at most " + std::to_string(info->limits().max_frames()) + " frames per job)";
    }
    return {grpc::StatusCode::RESOURCE_EXHAUSTED,
            "not sent: the job spec is " + std::to_string(bytes) + " bytes with " + bulk_of(spec) + ", over the " +
                std::to_string(wire::kMaxMessageBytes) + " a request may carry: split it into several jobs" + frames};
  }
  grpc::ClientContext context;
  context.set_deadline(unary_deadline());
  return stub_->SubmitJob(&context, request, &response);
}

const std::optional<v1::ServerInfo>& Connection::server_info() {
  if (server_info_asked_) return server_info_;
  grpc::ClientContext context;
  context.set_deadline(unary_deadline());
  v1::ServerInfo info;
  const grpc::Status status = stub_->GetServerInfo(&context, v1::GetServerInfoRequest(), &info);
  if (status.ok()) {
    server_info_ = std::move(info);
  } else if (status.error_code() != grpc::StatusCode::UNIMPLEMENTED) {
    throw rpc_error("asking the server's limits", status);
  }
  server_info_asked_ = true;
  return server_info_;
}

bool cancel_job(Connection& connection, const std::string& job_id, std::chrono::milliseconds within) {
  v1::CancelJobRequest request;
  request.set_job_id(job_id);
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + within);
  v1::Job job;
  return connection.stub().CancelJob(&context, request, &job).ok();
}

}  // namespace surfacer::client
