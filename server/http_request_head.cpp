#include "server/http_request_head.h"

#include <algorithm>

namespace surfacer::server {
namespace {

bool is_token_char(char c) {
  if ((c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9')) return true;
  return std::string_view("!#$%&'*+-.^_`|~").find(c) != std::string_view::npos;
}

RequestHead failure(int status, std::string_view error) {
  RequestHead out;
  out.error_status = status;
  out.error = error;
  return out;
}

}  // namespace

std::size_t request_head_end(std::string_view data) {
  for (std::size_t i = data.find('\n'); i != std::string_view::npos; i = data.find('\n', i + 1)) {
    if (i + 1 < data.size() && data[i + 1] == '\n') return i + 2;
    if (i + 2 < data.size() && data[i + 1] == '\r' && data[i + 2] == '\n') return i + 3;
  }
  return std::string_view::npos;
}

RequestHead parse_request_head(std::string_view head) {
  const std::size_t line_end = head.find('\n');
  std::string_view line = head.substr(0, line_end);
  if (line.ends_with('\r')) line.remove_suffix(1);
  const std::size_t space1 = line.find(' ');
  const std::size_t space2 = space1 == std::string_view::npos ? space1 : line.find(' ', space1 + 1);
  if (space2 == std::string_view::npos || line.find(' ', space2 + 1) != std::string_view::npos) {
    return failure(400, "expected a request line 'METHOD /path HTTP/1.1'");
  }
  const std::string_view method = line.substr(0, space1);
  const std::string_view target = line.substr(space1 + 1, space2 - space1 - 1);
  const std::string_view version = line.substr(space2 + 1);
  if (method.empty() || !std::all_of(method.begin(), method.end(), is_token_char)) {
    return failure(400, "malformed method");
  }
  if (!target.starts_with('/') || std::any_of(target.begin(), target.end(), [](char c) {
        return static_cast<unsigned char>(c) <= 0x20 || c == 0x7f;
      })) {
    return failure(400, "the request target must be a path starting with '/'");
  }
  if (!version.starts_with("HTTP/")) return failure(400, "malformed HTTP version");
  if (version != "HTTP/1.1" && version != "HTTP/1.0") return failure(505, "use HTTP/1.1 or HTTP/1.0");
  // Header lines: "name: value" with a token name. Their content is not needed.
  for (std::size_t start = line_end == std::string_view::npos ? head.size() : line_end + 1; start < head.size();) {
    std::size_t end = head.find('\n', start);
    if (end == std::string_view::npos) end = head.size();
    std::string_view header = head.substr(start, end - start);
    start = end + 1;
    if (header.ends_with('\r')) header.remove_suffix(1);
    if (header.empty()) break;
    const std::size_t colon = header.find(':');
    if (colon == 0 || colon == std::string_view::npos ||
        !std::all_of(header.begin(), header.begin() + static_cast<std::ptrdiff_t>(colon), is_token_char)) {
      return failure(400, "malformed header line");
    }
  }
  RequestHead out;
  out.method = method;
  out.path = target.substr(0, target.find('?'));
  return out;
}

}  // namespace surfacer::server
