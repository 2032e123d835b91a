// Base64 (RFC 4648, the standard alphabet with '=' padding): what VTK's XML files and glTF's data URIs hold.
#pragma once

#include <optional>
#include <string>
#include <string_view>

namespace surfacer {

// Appends the base64 text of `bytes` to `out` (4 characters per 3 bytes, padded).
void append_base64(std::string& out, std::string_view bytes);

// The bytes of base64 `text` (padded or not); nullopt for a character outside the alphabet, a '=' before the end or
// a length that no encoding has (1 mod 4). Allocates 3/4 of the text's size.
std::optional<std::string> decode_base64(std::string_view text);

}  // namespace surfacer
