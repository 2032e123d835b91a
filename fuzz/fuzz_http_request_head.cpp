// Fuzz target: the metrics endpoint's request-head parser (server/http_request_head.h) on arbitrary bytes, as a
// client on the network could send them. The input is what the server has read from one connection.
// Properties: the head's end, when found, lies within the input just past a blank line; parsing the head (or the
// whole input) never throws; a head accepted as well formed has a token method and a path that starts with '/', holds
// no space, control or DEL byte nor '?', and is a view into the head's request line; an error carries status 400 or
// 505 and a reason.
#include <algorithm>
#include <cstdint>
#include <string>
#include <string_view>

#include "fuzz/fuzz_input.h"
#include "server/http_request_head.h"

namespace surfacer::fuzz {
namespace {

using server::parse_request_head;
using server::request_head_end;
using server::RequestHead;

bool is_token_char(char c) {
  if ((c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9')) return true;
  return std::string_view("!#$%&'*+-.^_`|~").find(c) != std::string_view::npos;
}

bool within(std::string_view part, std::string_view whole) {
  return part.data() >= whole.data() && part.data() + part.size() <= whole.data() + whole.size();
}

void check(std::string_view head) {
  const RequestHead r = parse_request_head(head);
  if (r.error_status != 0) {
    require(r.error_status == 400 || r.error_status == 505, "error status " + std::to_string(r.error_status));
    require(!r.error.empty(), "an error without a reason");
    return;
  }
  const std::string_view line = head.substr(0, head.find('\n'));
  require(!r.method.empty() && std::all_of(r.method.begin(), r.method.end(), is_token_char), "method not a token");
  require(within(r.method, line) && within(r.path, line), "method or path outside the request line");
  require(r.path.starts_with('/'), "path without a leading '/'");
  require(std::none_of(r.path.begin(), r.path.end(),
                       [](char c) { return static_cast<unsigned char>(c) <= 0x20 || c == 0x7f || c == '?'; }),
          "path holds a space, control, DEL or '?'");
}

}  // namespace
}  // namespace surfacer::fuzz

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace surfacer::fuzz;
  const std::string bytes(reinterpret_cast<const char*>(data), size);
  const std::string_view input = bytes;
  const std::size_t end = request_head_end(input);
  if (end != std::string_view::npos) {
    require(end >= 2 && end <= input.size(), "head end outside the input");
    const std::string_view head = input.substr(0, end);
    require(head.ends_with("\n\n") || head.ends_with("\n\r\n"), "head does not end with a blank line");
    require(request_head_end(head) == end, "the head's end moved when the rest was cut off");
    check(head);
  }
  check(input);  // the parser must hold on any bytes, complete head or not
  return 0;
}
