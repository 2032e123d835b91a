// Numbers and bytes in messages, one way everywhere: an error that echoes a value the user gave shows it exactly
// (a tolerance of 1e-9 reads 1e-09, never 0.000000).
#pragma once

#include <algorithm>
#include <array>
#include <charconv>
#include <cstdint>
#include <string>
#include <string_view>

namespace surfacer {

// The shortest text that reads back as exactly `v` ("0.25", "1e-09", "-3", "inf", "nan").
inline std::string format_number(double v) {
  std::array<char, 32> buf;
  const auto result = std::to_chars(buf.data(), buf.data() + buf.size(), v);
  return std::string(buf.data(), result.ptr);
}

// "0x" and 8 lower-case hex digits (CRC-32 values).
inline std::string hex32(std::uint32_t v) {
  static constexpr char kDigits[] = "0123456789abcdef";
  std::string out = "0x00000000";
  for (int i = 0; i < 8; ++i) out[9 - i] = kDigits[(v >> (4 * i)) & 0xF];
  return out;
}

// 'text', cut to at most `max_chars` characters of it (so a hostile token cannot make a message huge).
inline std::string quote(std::string_view text, std::size_t max_chars = 40) {
  std::string out;
  out.reserve(std::min(text.size(), max_chars) + 2);
  out += '\'';
  out.append(text.substr(0, max_chars));
  out += '\'';
  return out;
}

// Length of the valid UTF-8 sequence starting at s[i], or 0 when s[i] does not start one (RFC 3629: no overlong
// forms, no surrogates, nothing above U+10FFFF).
inline std::size_t utf8_sequence_length(std::string_view s, std::size_t i) {
  const auto byte = [&](std::size_t k) { return static_cast<unsigned char>(s[k]); };
  const unsigned char c = byte(i);
  if (c < 0x80) return 1;
  std::size_t length = 0;
  unsigned char lo = 0x80, hi = 0xBF;  // allowed range of the second byte
  if (c >= 0xC2 && c <= 0xDF) {
    length = 2;
  } else if (c >= 0xE0 && c <= 0xEF) {
    length = 3;
    if (c == 0xE0) lo = 0xA0;
    if (c == 0xED) hi = 0x9F;
  } else if (c >= 0xF0 && c <= 0xF4) {
    length = 4;
    if (c == 0xF0) lo = 0x90;
    if (c == 0xF4) hi = 0x8F;
  } else {
    return 0;
  }
  if (i + length > s.size()) return 0;
  if (byte(i + 1) < lo || byte(i + 1) > hi) return 0;
  for (std::size_t k = 2; k < length; ++k) {
    if (byte(i + k) < 0x80 || byte(i + k) > 0xBF) return 0;
  }
  return length;
}

// Appends `text` to `out` as valid UTF-8: an invalid byte becomes U+FFFD, a multi-byte sequence is copied, and each
// ASCII byte goes through escape_ascii(out, c) (the format's own escapes).
template <class EscapeAscii>
void append_utf8_escaped(std::string& out, std::string_view text, EscapeAscii&& escape_ascii) {
  for (std::size_t i = 0; i < text.size();) {
    const std::size_t length = utf8_sequence_length(text, i);
    if (length == 0) {
      out += "\xEF\xBF\xBD";
      ++i;
    } else if (length > 1) {
      out.append(text.substr(i, length));
      i += length;
    } else {
      escape_ascii(out, text[i++]);
    }
  }
}

// The longest prefix of `text` of at most `max_bytes` bytes that does not end inside a UTF-8 sequence.
inline std::string utf8_prefix(std::string_view text, std::size_t max_bytes) {
  std::size_t n = std::min(text.size(), max_bytes);
  while (n > 0 && n < text.size() && (static_cast<unsigned char>(text[n]) & 0xC0) == 0x80) --n;
  return std::string(text.substr(0, n));
}

// `text` without leading and trailing white space.
inline std::string_view trim(std::string_view text) {
  constexpr std::string_view kSpace = " \t\r\n\f\v";
  const std::size_t begin = text.find_first_not_of(kSpace);
  if (begin == std::string_view::npos) return {};
  return text.substr(begin, text.find_last_not_of(kSpace) - begin + 1);
}

}  // namespace surfacer
