#include "wire/enums.h"

#include <google/protobuf/descriptor.h>

#include <vector>

#include "core/util/errors.h"

namespace surfacer::wire {

void require_known_enum(const google::protobuf::EnumDescriptor* descriptor, int value, const std::string& field) {
  if (descriptor->FindValueByNumber(value) != nullptr) return;
  std::vector<std::string> names;
  for (int i = 0; i < descriptor->value_count(); ++i) {
    const std::string& name = descriptor->value(i)->name();
    if (descriptor->value(i)->number() != 0) names.push_back(name);
  }
  std::string list;
  for (std::size_t i = 0; i < names.size(); ++i) {
    list += (i == 0 ? "" : i + 1 == names.size() ? " or " : ", ") + names[i];
  }
  throw InvalidInput(field,
                     field + " (" + std::to_string(value) + ") is not a " + descriptor->name() + " value; use " + list);
}

}  // namespace surfacer::wire
