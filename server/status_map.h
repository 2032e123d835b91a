// The one place where core errors become gRPC statuses (STYLE.md 7).
#pragma once

#include <exception>

namespace grpc {
class Status;
}

namespace surfacer::server {

// Maps the exception currently being handled (call inside a catch block, or pass std::current_exception()):
// surfacer::Error kinds -> INVALID_ARGUMENT / RESOURCE_EXHAUSTED / CANCELLED / INTERNAL; std::bad_alloc ->
// RESOURCE_EXHAUSTED; anything else -> INTERNAL.
grpc::Status status_from_exception(std::exception_ptr error);

}  // namespace surfacer::server
