// Expectations on surfacer::Error: what a call that must fail throws.
#pragma once

#include <gtest/gtest.h>

#include <functional>
#include <string>
#include <string_view>

#include "core/util/errors.h"

namespace surfacer::testing {

// Success when `call` throws surfacer::Error of `kind` naming `field` (and, when `message_contains` is not empty,
// with a message containing it); otherwise a failure saying what happened instead. For EXPECT_TRUE.
::testing::AssertionResult throws_error(const std::function<void()>& call, ErrorKind kind, const std::string& field,
                                        std::string_view message_contains = {});

// throws_error(call, ErrorKind::kInvalidInput, field).
::testing::AssertionResult throws_invalid_input(const std::function<void()>& call, const std::string& field);

}  // namespace surfacer::testing
