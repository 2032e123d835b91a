// Reading JSON (RFC 8259) into a small tree: the JSON inside files we read (a .glb's JSON chunk). The input is
// untrusted: whatever is not JSON, nesting deeper than kMaxJsonDepth and more than max_values values (each takes
// about 100 bytes in the tree, 50 times the 2 bytes of text "0," takes) throw InvalidInput(field) naming `what` and
// the byte where reading stopped.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace surfacer {

inline constexpr int kMaxJsonDepth = 64;
inline constexpr std::size_t kMaxJsonValues = std::size_t{1} << 20;  // ~100 MB of tree

struct JsonMember;

struct JsonValue {
  enum class Kind { kNull, kBool, kNumber, kString, kArray, kObject };
  Kind kind = Kind::kNull;
  bool boolean = false;
  double number = 0.0;
  std::string string;               // kString
  std::vector<JsonValue> items;     // kArray
  std::vector<JsonMember> members;  // kObject, in the text's order

  bool is_object() const { return kind == Kind::kObject; }
  bool is_array() const { return kind == Kind::kArray; }
  bool is_number() const { return kind == Kind::kNumber; }
  // The member named `key` of an object (the first, if repeated), or nullptr (also for other kinds).
  const JsonValue* find(std::string_view key) const;
};

struct JsonMember {
  std::string name;
  JsonValue value;
};

JsonValue parse_json(std::string_view text, const std::string& field, const std::string& what,
                     std::size_t max_values = kMaxJsonValues);

}  // namespace surfacer
