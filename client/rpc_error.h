// A failed gRPC call as the CLI reports it: the status code's name and the CliError (exit code and message) it
// becomes.
#pragma once

#include <grpcpp/support/status.h>

#include <string>

#include "client/exit_codes.h"

namespace surfacer::client {

// "INVALID_ARGUMENT", "UNAVAILABLE", ... for a grpc::StatusCode.
std::string status_code_name(grpc::StatusCode code);

// "<context>: CODE: message" as a CliError: UNAVAILABLE and DEADLINE_EXCEEDED -> kUnreachable, CANCELLED ->
// kCancelled, everything else -> kJobFailed. UNAUTHENTICATED and PERMISSION_DENIED add which flags to check.
CliError rpc_error(const std::string& context, const grpc::Status& status);

}  // namespace surfacer::client
