// The error family of core: every failure is one of four kinds. server/status_map.cpp maps each kind to one
// grpc::StatusCode.
#pragma once

#include <stdexcept>
#include <string>
#include <string_view>

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
inline Error Cancelled(const std::string& message = "cancelled") { return Error(ErrorKind::kCancelled, "", message); }
inline Error Internal(const std::string& message) { return Error(ErrorKind::kInternal, "", message); }

// `error` placed at `path` in a larger document: the field becomes "path.field" and the message
// "path.<message>" when the message starts with the field's name (the convention above), else "path: <message>".
inline Error at_path(const Error& error, const std::string& path) {
  const std::string& field = error.field();
  const std::string_view message = error.what();
  const bool names_field =
      !field.empty() && message.starts_with(field) &&
      (message.size() == field.size() || std::string_view(" .[").find(message[field.size()]) != std::string_view::npos);
  return Error(error.kind(), field.empty() ? path : path + "." + field,
               path + (names_field ? "." : ": ") + std::string(message));
}

// Runs f() and returns its result; an InvalidInput it throws is rethrown placed at `path` (at_path above), so a
// builder's "radius (-1) must be > 0" reaches the user as "spec.scenes[0].root.sphere.radius (-1) must be > 0".
// Other errors pass unchanged.
template <class F>
decltype(auto) with_path(const std::string& path, F&& f) {
  try {
    return f();
  } catch (const Error& e) {
    if (e.kind() != ErrorKind::kInvalidInput) throw;
    throw at_path(e, path);
  }
}

}  // namespace surfacer
