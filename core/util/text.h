// Reading text formats: lines with their numbers, whitespace tokens, and whole-token numbers (never locale-dependent,
// never accepting a partial token).
#pragma once

#include <charconv>
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

namespace surfacer {

inline bool is_blank(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v'; }

// A name written as one whitespace-free token (VTK legacy array names, PLY property names): '%', white space and
// control characters as %XX (upper-case hex), as VTK's legacy writer does and its reader decodes.
inline std::string token_name(std::string_view name) {
  static constexpr char kHex[] = "0123456789ABCDEF";
  std::string out;
  for (const char c : name) {
    const auto byte = static_cast<unsigned char>(c);
    if (c == '%' || byte <= ' ' || byte == 0x7f) {
      out += '%';
      out += kHex[byte >> 4];
      out += kHex[byte & 15];
    } else {
      out += c;
    }
  }
  return out;
}

// The name a token_name() token stands for: every %XX (hex, either case) decoded; anything else kept as it is.
inline std::string token_name_decoded(std::string_view token) {
  const auto hex = [](char c) {
    return c >= '0' && c <= '9'   ? c - '0'
           : c >= 'a' && c <= 'f' ? c - 'a' + 10
           : c >= 'A' && c <= 'F' ? c - 'A' + 10
                                  : -1;
  };
  std::string out;
  for (std::size_t i = 0; i < token.size(); ++i) {
    if (token[i] == '%' && i + 2 < token.size() && hex(token[i + 1]) >= 0 && hex(token[i + 2]) >= 0) {
      out += static_cast<char>(hex(token[i + 1]) * 16 + hex(token[i + 2]));
      i += 2;
    } else {
      out += token[i];
    }
  }
  return out;
}

// Splits a line into whitespace-separated tokens (reusing `out`).
inline void tokenize(std::string_view line, std::vector<std::string_view>& out) {
  out.clear();
  std::size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && is_blank(line[i])) ++i;
    const std::size_t start = i;
    while (i < line.size() && !is_blank(line[i])) ++i;
    if (i > start) out.push_back(line.substr(start, i - start));
  }
}

// The whole token as a number (an optional leading '+' allowed); false otherwise.
template <class T>
bool parse_whole(std::string_view token, T& value) {
  const char* begin = token.data();
  const char* end = token.data() + token.size();
  if (begin != end && *begin == '+') ++begin;
  const auto result = std::from_chars(begin, end, value);
  return begin != end && result.ec == std::errc() && result.ptr == end;
}
inline bool parse_double(std::string_view token, double& value) { return parse_whole(token, value); }
inline bool parse_int(std::string_view token, std::int64_t& value) { return parse_whole(token, value); }

// Lines of a text buffer, numbered from 1, without their line terminator ("\n" or "\r\n").
class LineReader {
 public:
  explicit LineReader(std::string_view data) : data_(data) {}
  bool next(std::string_view& line) {
    if (pos_ >= data_.size()) return false;
    const std::size_t end = data_.find('\n', pos_);
    const std::size_t stop = end == std::string_view::npos ? data_.size() : end;
    line = data_.substr(pos_, stop - pos_);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    pos_ = end == std::string_view::npos ? data_.size() : end + 1;
    ++line_;
    return true;
  }
  std::size_t line() const { return line_; }  // number of the last line returned
  std::size_t pos() const { return pos_; }    // offset of the next line

 private:
  std::string_view data_;
  std::size_t pos_ = 0;
  std::size_t line_ = 0;
};

}  // namespace surfacer
