#include "client/rpc_error.h"

#include "wire/status.h"

namespace surfacer::client {

std::string status_code_name(grpc::StatusCode code) {
  return std::string(wire::status_code_name(static_cast<int>(code)));
}

CliError rpc_error(const std::string& context, const grpc::Status& status) {
  ExitCode code = ExitCode::kJobFailed;
  if (status.error_code() == grpc::StatusCode::UNAVAILABLE ||
      status.error_code() == grpc::StatusCode::DEADLINE_EXCEEDED) {
    code = ExitCode::kUnreachable;
  } else if (status.error_code() == grpc::StatusCode::CANCELLED) {
    code = ExitCode::kCancelled;
  }
  std::string message = context + ": " + status_code_name(status.error_code());
  if (!status.error_message().empty()) message += ": " + status.error_message();
  if (status.error_code() == grpc::StatusCode::UNAUTHENTICATED) {
    message +=
        " (the server wants a valid bearer token: pass --token TOKEN or --token-file FILE, or set "
        "$SURFACER_TOKEN, with a token from the server's --tokens-file)";
  } else if (status.error_code() == grpc::StatusCode::PERMISSION_DENIED) {
    message +=
        " (the server does not allow this for the token or client certificate given: check --token, "
        "--token-file, $SURFACER_TOKEN or --tls-cert)";
  }
  return CliError(code, message, static_cast<int>(status.error_code()));
}

}  // namespace surfacer::client
