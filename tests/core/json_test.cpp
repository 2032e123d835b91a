// core/util/json.h: what it writes is JSON that an independent parser (Python's json module) reads back to the same
// values, whatever the strings hold.
#include "core/util/json.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "tests/support/json_check.h"

namespace surfacer {
namespace {

using testing::python_json;

TEST(JsonWriter, NestingAndValuesReadBack) {
  JsonWriter w;
  w.begin_object()
      .key("n")
      .value(3)
      .key("x")
      .value(0.1)
      .key("tiny")
      .value(1e-300)
      .key("big")
      .value(std::int64_t{1} << 53)
      .key("ok")
      .value(true)
      .key("none")
      .null()
      .key("nan")
      .value(std::nan(""))
      .key("inf")
      .value(std::numeric_limits<double>::infinity())
      .key("list")
      .begin_array()
      .value(1)
      .begin_object()
      .end_object()
      .begin_array()
      .end_array()
      .value("s")
      .end_array()
      .key("empty")
      .begin_object()
      .end_object()
      .end_object();
  const std::string& text = w.str();
  EXPECT_EQ(python_json(text, "d['n'], d['x'] == 0.1, d['tiny'] == 1e-300, d['big'], d['ok'], d['none']"),
            "(3, True, True, 9007199254740992, True, None)");
  EXPECT_EQ(python_json(text, "d['nan'], d['inf']"), "(None, None)");  // JSON has no NaN: null
  EXPECT_EQ(python_json(text, "d['list'], d['empty']"), "([1, {}, [], 's'], {})");
}

TEST(JsonWriter, StringsAreEscaped) {
  // Quotes, backslashes, every control character, DEL, multi-byte UTF-8 and bytes that are not UTF-8.
  std::string nasty = "a\"b\\c/d\n\r\t\b\f";
  for (char c = 1; c < 0x20; ++c) nasty += c;
  nasty += "\x7f \xc3\xa9 \xe2\x82\xac \xf0\x9f\x98\x80";  // é € 😀
  const std::string invalid = "x\xff\xc3(y\xed\xa0\x80";   // a stray byte, a cut sequence, a surrogate
  JsonWriter w;
  w.begin_object().key(nasty).value(nasty).key("invalid").value(invalid).end_object();
  // Python compares with the same characters it decodes from the escapes.
  EXPECT_EQ(python_json(w.str(), "list(d.values())[0] == list(d.keys())[0]"), "True");
  EXPECT_EQ(python_json(w.str(), "len(list(d.keys())[0])"), std::to_string(12 + 31 + 7));
  EXPECT_EQ(python_json(w.str(), "ascii(list(d.keys())[0][-7:])"), "'\\x7f \\xe9 \\u20ac \\U0001f600'");
  EXPECT_EQ(python_json(w.str(), "ascii(d['invalid'])"), "'x\\ufffd\\ufffd(y\\ufffd\\ufffd\\ufffd'");
  // Every control character is escaped: the raw text has none.
  for (char c : w.str()) EXPECT_GE(static_cast<unsigned char>(c), 0x20) << "raw control character in " << w.str();
}

TEST(JsonWriter, QuoteAlone) {
  EXPECT_EQ(json_quote(""), "\"\"");
  EXPECT_EQ(json_quote("a\"b"), "\"a\\\"b\"");
  EXPECT_EQ(json_quote(std::string("\0", 1)), "\"\\u0000\"");
}

}  // namespace
}  // namespace surfacer
