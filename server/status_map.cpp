#include "server/status_map.h"

#include <grpcpp/support/status.h>

#include <new>

#include "core/util/errors.h"

namespace surfacer::server {

grpc::Status status_from_exception(std::exception_ptr error) {
  try {
    std::rethrow_exception(error);
  } catch (const Error& e) {
    switch (e.kind()) {
      case ErrorKind::kInvalidInput:
        return {grpc::StatusCode::INVALID_ARGUMENT, e.what()};
      case ErrorKind::kResourceLimit:
        return {grpc::StatusCode::RESOURCE_EXHAUSTED, e.what()};
      case ErrorKind::kCancelled:
        return {grpc::StatusCode::CANCELLED, e.what()};
      case ErrorKind::kInternal:
        return {grpc::StatusCode::INTERNAL, e.what()};
    }
    return {grpc::StatusCode::INTERNAL, e.what()};
  } catch (const std::bad_alloc&) {
    return {grpc::StatusCode::RESOURCE_EXHAUSTED, "out of memory; lower the resolution or the input size"};
  } catch (const std::exception& e) {
    return {grpc::StatusCode::INTERNAL, e.what()};
  } catch (...) {
    return {grpc::StatusCode::INTERNAL, "unknown error"};
  }
}

}  // namespace surfacer::server
