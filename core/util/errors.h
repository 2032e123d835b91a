// The error family of core (STYLE.md 7). server/status_map.cpp maps each kind to one grpc::StatusCode.
#pragma once

#include <stdexcept>
#include <string>

namespace surfacer {

enum class ErrorKind {
  kInvalidInput,   // the caller's input or options are wrong; the message says how to fix it
  kResourceLimit,  // the input is valid but exceeds a configured limit; the message names the limit
  kCancelled,      // a CancelToken fired
  kInternal,       // a bug or an environment failure
};

class Error : public std::runtime_error {
 public:
  // `field` names the offending input (e.g. "radius", "bounds.max.x"); may be empty.
  Error(ErrorKind kind, std::string field, const std::string& message)
      : std::runtime_error(message), kind_(kind), field_(std::move(field)) {}

  ErrorKind kind() const { return kind_; }
  const std::string& field() const { return field_; }

 private:
  ErrorKind kind_;
  std::string field_;
};

// Message convention: "<field> <what is wrong>; <how to fix>", e.g.
//   InvalidInput("radius", "radius (-1) must be > 0")
inline Error InvalidInput(std::string field, const std::string& message) {
  return Error(ErrorKind::kInvalidInput, std::move(field), message);
}
inline Error ResourceLimit(std::string field, const std::string& message) {
  return Error(ErrorKind::kResourceLimit, std::move(field), message);
}
inline Error Cancelled(const std::string& message = "cancelled") {
  return Error(ErrorKind::kCancelled, "", message);
}
inline Error Internal(const std::string& message) { return Error(ErrorKind::kInternal, "", message); }

}  // namespace surfacer
