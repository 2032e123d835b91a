// core/util/json.h: what it writes is JSON that an independent parser (Python's json module) reads back to the same
// values, whatever the strings hold. core/util/json_read.h: reads what the writer writes, and refuses what is not
// JSON or would take too much memory, naming the place.
#include "core/util/json.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "core/util/errors.h"
#include "core/util/json_read.h"
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

TEST(JsonReader, ReadsWhatTheWriterWrites) {
  JsonWriter w;
  w.begin_object().key("a").begin_array().value(1).value(-2.5e-3).value(true).value(false).end_array();
  w.key("s").value(std::string("tab\t quote\" slash\\ e\xC3\xA9 \x01")).key("o").begin_object().end_object();
  w.key("n").begin_array().end_array().end_object();
  const JsonValue v = parse_json(w.str(), "f", "test");
  ASSERT_TRUE(v.is_object());
  const JsonValue* a = v.find("a");
  ASSERT_TRUE(a && a->is_array() && a->items.size() == 4);
  EXPECT_EQ(a->items[0].number, 1.0);
  EXPECT_EQ(a->items[1].number, -2.5e-3);
  EXPECT_TRUE(a->items[2].boolean);
  EXPECT_EQ(a->items[3].kind, JsonValue::Kind::kBool);
  EXPECT_FALSE(a->items[3].boolean);
  EXPECT_EQ(v.find("s")->string, "tab\t quote\" slash\\ e\xC3\xA9 \x01");
  EXPECT_TRUE(v.find("o")->is_object());
  EXPECT_TRUE(v.find("n")->items.empty());
  EXPECT_EQ(v.find("missing"), nullptr);
  // Escapes the writer does not use: \u with a surrogate pair, \/.
  EXPECT_EQ(parse_json(R"(["\ud83d\ude00\/x"])", "f", "t").items[0].string, "\xF0\x9F\x98\x80/x");
}

TEST(JsonReader, RefusesWhatIsNotJsonOrTooLargeNamingWhere) {
  auto refused = [](const std::string& text, const std::string& words, std::size_t max_values = kMaxJsonValues) {
    try {
      parse_json(text, "file", "x.glb", max_values);
      ADD_FAILURE() << "read: " << text.substr(0, 40);
    } catch (const Error& e) {
      EXPECT_EQ(e.field(), "file");
      const std::string what = e.what();
      EXPECT_NE(what.find("x.glb: not JSON"), std::string::npos) << what;
      EXPECT_NE(what.find(words), std::string::npos) << what;
    }
  };
  refused("", "unexpected end");
  refused("{\"a\":1,}", "expected a member name at byte 7");
  refused("[1 2]", "expected ']'");
  refused("[01]", "expected ']'");
  refused("[1.]", "digits after '.'");
  refused("\"abc", "unterminated string");
  refused("\"a\x01\"", "control character");
  refused("\"\\q\"", "bad escape");
  refused("[1e999]", "out of range");
  refused("{} x", "text after the JSON value");
  refused(std::string(100, '[') + std::string(100, ']'), "nested deeper than 64");
  refused("[1,2,3,4]", "more than 4 values", 4);
  EXPECT_NO_THROW(parse_json("[1,2,3]", "file", "x.glb", 4));
}

}  // namespace
}  // namespace surfacer
