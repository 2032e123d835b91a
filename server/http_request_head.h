// The HTTP/1.x request-head parser of the metrics endpoint (server/metrics_http.h): where a head ends in the bytes
// received so far, and what it asks for. Pure functions over untrusted bytes, fuzzed by
// fuzz/fuzz_http_request_head.cpp.
#pragma once

#include <cstddef>
#include <string_view>

namespace surfacer::server {

// Where the request head ends in `data`: the index just past its blank line (CRLF or bare LF line endings), or
// std::string_view::npos while it has not arrived.
std::size_t request_head_end(std::string_view data);

// A parsed request head. Views into the head given to parse_request_head().
struct RequestHead {
  // 0 when the head is well formed; else the status to answer: 400 (malformed) or 505 (not HTTP/1.0 or 1.1).
  int error_status = 0;
  std::string_view error;   // what is wrong (for the response body), when error_status != 0
  std::string_view method;  // a token (RFC 9110 tchar), e.g. "GET"
  std::string_view path;    // the request target up to its '?': starts with '/', no controls, spaces or DEL
};

// Parses a complete head (request line "METHOD TARGET HTTP/1.x", then "name: value" header lines, up to the blank
// line; CRLF or LF). Header values are not interpreted. Never throws.
RequestHead parse_request_head(std::string_view head);

}  // namespace surfacer::server
