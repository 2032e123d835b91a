// Enum fields of a request: proto3 keeps a number it does not know as is, so every enum a request sets is checked
// against its schema before it is used.
#pragma once

#include <string>

namespace google::protobuf {
class EnumDescriptor;
}

namespace surfacer::wire {

// Throws InvalidInput(field, "<field> (<value>) is not a <Enum> value; use A, B or C") unless `value` is one of the
// enum's values (the *_UNSPECIFIED default counts as one; the hint lists the others).
void require_known_enum(const google::protobuf::EnumDescriptor* descriptor, int value, const std::string& field);

}  // namespace surfacer::wire
