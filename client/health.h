// grpc.health.v1.Health/Check without generated code: Debian's libgrpc++ ships no generated health client, so
// the two tiny messages are encoded by hand (HealthCheckRequest { string service = 1; },
// HealthCheckResponse { ServingStatus status = 1; }) and sent with grpc::GenericStub.
#pragma once

#include <grpcpp/channel.h>

#include <chrono>
#include <string>

namespace surfacer::client {

enum class HealthStatus { kUnknown = 0, kServing = 1, kNotServing = 2, kServiceUnknown = 3 };

// "SERVING", "NOT_SERVING", ...
std::string health_status_name(HealthStatus status);

// Wire bytes of HealthCheckRequest{service}; and the status parsed from HealthCheckResponse bytes (unknown
// fields skipped, a missing status is kUnknown; false when the bytes are not a valid message).
std::string encode_health_request(const std::string& service);
bool decode_health_response(const std::string& bytes, HealthStatus* status);

// Calls /grpc.health.v1.Health/Check. Throws CliError (see rpc_error) when the call fails; NOT_FOUND (unknown
// service) is returned as kServiceUnknown.
HealthStatus check_health(const std::shared_ptr<grpc::Channel>& channel, const std::string& service,
                          std::chrono::system_clock::time_point deadline);

}  // namespace surfacer::client
