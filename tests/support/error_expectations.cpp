#include "tests/support/error_expectations.h"

namespace surfacer::testing {

::testing::AssertionResult throws_error(const std::function<void()>& call, ErrorKind kind, const std::string& field,
                                        std::string_view message_contains) {
  try {
    call();
  } catch (const Error& e) {
    if (e.kind() != kind) {
      return ::testing::AssertionFailure() << "threw kind " << static_cast<int>(e.kind()) << " instead of "
                                           << static_cast<int>(kind) << ": " << e.what();
    }
    if (e.field() != field) {
      return ::testing::AssertionFailure()
             << "named field \"" << e.field() << "\" instead of \"" << field << "\": " << e.what();
    }
    if (std::string_view(e.what()).find(message_contains) == std::string_view::npos) {
      return ::testing::AssertionFailure() << "message does not contain \"" << message_contains << "\": " << e.what();
    }
    return ::testing::AssertionSuccess();
  }
  return ::testing::AssertionFailure() << "no error; expected one naming " << field;
}

::testing::AssertionResult throws_invalid_input(const std::function<void()>& call, const std::string& field) {
  return throws_error(call, ErrorKind::kInvalidInput, field);
}

}  // namespace surfacer::testing
