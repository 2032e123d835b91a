#include "client/health.h"

#include <grpcpp/client_context.h>

#include "client/rpc_error.h"
#include "grpc/health/v1/health.grpc.pb.h"

namespace surfacer::client {

std::string health_status_name(HealthStatus status) {
  switch (status) {
    case HealthStatus::kUnknown:
      return "UNKNOWN";
    case HealthStatus::kServing:
      return "SERVING";
    case HealthStatus::kNotServing:
      return "NOT_SERVING";
    case HealthStatus::kServiceUnknown:
      return "SERVICE_UNKNOWN";
  }
  return "UNKNOWN";
}

HealthStatus health_status_from(int serving_status) {
  if (serving_status < 0 || serving_status > static_cast<int>(HealthStatus::kServiceUnknown)) {
    return HealthStatus::kUnknown;
  }
  return static_cast<HealthStatus>(serving_status);
}

HealthStatus check_health(const std::shared_ptr<grpc::Channel>& channel, const std::string& service,
                          std::chrono::system_clock::time_point deadline) {
  const auto stub = grpc::health::v1::Health::NewStub(channel);
  grpc::ClientContext context;
  context.set_deadline(deadline);
  grpc::health::v1::HealthCheckRequest request;
  request.set_service(service);
  grpc::health::v1::HealthCheckResponse response;
  const grpc::Status status = stub->Check(&context, request, &response);
  if (status.error_code() == grpc::StatusCode::NOT_FOUND) return HealthStatus::kServiceUnknown;
  if (!status.ok()) throw rpc_error("health check", status);
  return health_status_from(response.status());
}

}  // namespace surfacer::client
