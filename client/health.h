// grpc.health.v1.Health/Check through the stub generated from Debian's grpc-proto (grpc/health/v1/health.proto),
// as `surfacer health`, the connection's failure reason and scale-out's liveness test use it.
#pragma once

#include <grpcpp/channel.h>

#include <chrono>
#include <memory>
#include <string>

namespace surfacer::client {

// The values of grpc.health.v1.HealthCheckResponse.ServingStatus.
enum class HealthStatus { kUnknown = 0, kServing = 1, kNotServing = 2, kServiceUnknown = 3 };

// "SERVING", "NOT_SERVING", ...
std::string health_status_name(HealthStatus status);

// A ServingStatus number as received: 0..3 as named, any other (a newer server's value) kUnknown.
HealthStatus health_status_from(int serving_status);

// Calls /grpc.health.v1.Health/Check for `service` ("" the whole server). Throws CliError (see rpc_error) when the
// call fails; NOT_FOUND (unknown service) is returned as kServiceUnknown.
HealthStatus check_health(const std::shared_ptr<grpc::Channel>& channel, const std::string& service,
                          std::chrono::system_clock::time_point deadline);

}  // namespace surfacer::client
