#include "client/health.h"

#include <google/protobuf/io/coded_stream.h>
#include <google/protobuf/io/zero_copy_stream_impl_lite.h>
#include <google/protobuf/wire_format_lite.h>
#include <grpcpp/client_context.h>
#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/support/byte_buffer.h>

#include <future>

#include "client/connection.h"

namespace surfacer::client {

using google::protobuf::internal::WireFormatLite;

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

std::string encode_health_request(const std::string& service) {
  std::string bytes;
  if (service.empty()) return bytes;  // proto3: default values are not encoded
  google::protobuf::io::StringOutputStream stream(&bytes);
  google::protobuf::io::CodedOutputStream out(&stream);
  out.WriteTag(WireFormatLite::MakeTag(1, WireFormatLite::WIRETYPE_LENGTH_DELIMITED));
  out.WriteVarint32(static_cast<std::uint32_t>(service.size()));
  out.WriteString(service);
  out.Trim();
  return bytes;
}

bool decode_health_response(const std::string& bytes, HealthStatus* status) {
  google::protobuf::io::CodedInputStream in(reinterpret_cast<const std::uint8_t*>(bytes.data()),
                                            static_cast<int>(bytes.size()));
  std::uint64_t value = 0;  // absent field: UNKNOWN
  while (std::uint32_t tag = in.ReadTag()) {
    if (WireFormatLite::GetTagFieldNumber(tag) == 1 &&
        WireFormatLite::GetTagWireType(tag) == WireFormatLite::WIRETYPE_VARINT) {
      if (!in.ReadVarint64(&value)) return false;
    } else if (!WireFormatLite::SkipField(&in, tag)) {
      return false;
    }
  }
  if (!in.ConsumedEntireMessage()) return false;
  *status = value <= 3 ? static_cast<HealthStatus>(value) : HealthStatus::kUnknown;
  return true;
}

HealthStatus check_health(const std::shared_ptr<grpc::Channel>& channel, const std::string& service,
                          std::chrono::system_clock::time_point deadline) {
  grpc::GenericStub stub(channel);
  grpc::ClientContext context;
  context.set_deadline(deadline);
  const std::string request_bytes = encode_health_request(service);
  grpc::Slice slice(request_bytes);
  grpc::ByteBuffer request(&slice, 1);
  grpc::ByteBuffer response;
  std::promise<grpc::Status> done;
  stub.UnaryCall(&context, "/grpc.health.v1.Health/Check", grpc::StubOptions(), &request, &response,
                 [&done](grpc::Status status) { done.set_value(std::move(status)); });
  const grpc::Status status = done.get_future().get();
  if (status.error_code() == grpc::StatusCode::NOT_FOUND) return HealthStatus::kServiceUnknown;
  if (!status.ok()) throw rpc_error("health check", status);

  std::vector<grpc::Slice> slices;
  if (!response.Dump(&slices).ok()) throw CliError(ExitCode::kIntegrity, "health check: unreadable response");
  std::string bytes;
  for (const auto& s : slices) bytes.append(reinterpret_cast<const char*>(s.begin()), s.size());
  HealthStatus result = HealthStatus::kUnknown;
  if (!decode_health_response(bytes, &result)) {
    throw CliError(ExitCode::kIntegrity, "health check: malformed grpc.health.v1.HealthCheckResponse");
  }
  return result;
}

}  // namespace surfacer::client
