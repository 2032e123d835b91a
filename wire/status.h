// Names of gRPC status codes ("INVALID_ARGUMENT") for messages and metrics labels, on both sides of the wire.
#pragma once

#include <string_view>

namespace surfacer::wire {

// The canonical name of grpc::StatusCode `code` (0..16), or "UNKNOWN" for any other value.
std::string_view status_code_name(int code);

}  // namespace surfacer::wire
