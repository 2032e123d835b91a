#include "wire/request_limits.h"

#include <google/protobuf/descriptor.h>
#include <google/protobuf/message.h>

#include <algorithm>
#include <cstdint>
#include <optional>

#include "core/util/errors.h"
#include "surfacer/v1/scene.pb.h"
#include "wire/protocol.h"

namespace surfacer::wire {
namespace {

// A scene at the depth limit, inside the deepest request (SubmitJobRequest > JobSpec > ActiveJob > ActiveMorph >
// Scene > Node), with its deepest leaf (Node > Blobs > PointSkeleton > Vec3), parses.
static_assert(6 + 2 * kMaxSceneDepth + 3 < kRequestRecursionLimit);

bool ends_with(const std::string& s, std::string_view tail) {
  return s.size() >= tail.size() && s.compare(s.size() - tail.size(), tail.size(), tail) == 0;
}

class LimitWalker {
 public:
  // `scene_root`: the path of the outermost Node above `message` (empty outside scenes); `depth`: Nodes so far.
  void walk(const google::protobuf::Message& message, const std::string& path, const std::string& scene_root,
            int depth) {
    using FD = google::protobuf::FieldDescriptor;
    const auto* descriptor = message.GetDescriptor();
    const auto* reflection = message.GetReflection();
    if (descriptor == v1::Node::descriptor() && depth > kMaxSceneDepth) {
      throw InvalidInput(scene_root, scene_root + ": " + scene_too_deep());
    }
    for (int i = 0; i < descriptor->field_count(); ++i) {
      const FD* field = descriptor->field(i);
      const std::string name = path.empty() ? field->name() : path + "." + field->name();
      if (field->type() == FD::TYPE_STRING) {
        if (field->is_repeated()) {
          for (int k = 0; k < reflection->FieldSize(message, field); ++k) {
            check_text(field, reflection->GetRepeatedString(message, field, k), name + "[" + std::to_string(k) + "]");
          }
        } else {
          check_text(field, reflection->GetString(message, field), name);
        }
        continue;
      }
      if (field->type() != FD::TYPE_MESSAGE) continue;
      const bool node = field->message_type() == v1::Node::descriptor();
      if (field->is_repeated()) {
        for (int k = 0; k < reflection->FieldSize(message, field); ++k) {
          const std::string item = name + "[" + std::to_string(k) + "]";
          walk(reflection->GetRepeatedMessage(message, field, k), item, scene_root_of(node, depth, scene_root, item),
               depth + (node ? 1 : 0));
        }
      } else if (reflection->HasField(message, field)) {
        walk(reflection->GetMessage(message, field), name, scene_root_of(node, depth, scene_root, name),
             depth + (node ? 1 : 0));
      }
    }
  }

 private:
  static std::string scene_root_of(bool node, int depth, const std::string& scene_root, const std::string& path) {
    return node && depth == 0 ? path : scene_root;
  }

  static void check_text(const google::protobuf::FieldDescriptor* field, const std::string& value,
                         const std::string& path) {
    const bool id = ends_with(field->name(), "id");
    const std::size_t limit = id ? kMaxIdBytes : kMaxNameBytes;
    if (value.size() <= limit) return;
    throw InvalidInput(path,
                       path + " is " + std::to_string(value.size()) + " bytes; " +
                           (id ? "ids are at most " + std::to_string(limit) + " bytes (give the id the server returned)"
                               : "the limit is " + std::to_string(limit) + " bytes (it is a label; shorten it)"));
  }
};

std::optional<std::uint64_t> varint(std::string_view bytes, std::size_t& pos) {
  std::uint64_t value = 0;
  for (int shift = 0; shift < 64 && pos < bytes.size(); shift += 7) {
    const auto byte = static_cast<unsigned char>(bytes[pos++]);
    value |= static_cast<std::uint64_t>(byte & 0x7f) << shift;
    if ((byte & 0x80) == 0) return value;
  }
  return std::nullopt;
}

// Depth of the deepest chain of length-delimited fields in `bytes` that read as messages, counted up to `cap`;
// nullopt when `bytes` is not a sequence of well-formed fields. Every byte is read once per call that holds it
// directly, so the whole scan is linear in the input.
std::optional<int> nesting(std::string_view bytes, int cap) {
  int deepest = 0;
  std::size_t pos = 0;
  while (pos < bytes.size()) {
    const auto tag = varint(bytes, pos);
    if (!tag || (*tag >> 3) == 0) return std::nullopt;
    switch (*tag & 7) {
      case 0:
        if (!varint(bytes, pos)) return std::nullopt;
        break;
      case 1:
        pos += 8;
        break;
      case 5:
        pos += 4;
        break;
      case 2: {
        const auto length = varint(bytes, pos);
        if (!length || *length > bytes.size() - pos) return std::nullopt;
        if (cap > 0 && deepest < cap) {
          if (const auto inner = nesting(bytes.substr(pos, *length), cap - 1)) deepest = std::max(deepest, 1 + *inner);
        }
        pos += *length;
        break;
      }
      default:
        return std::nullopt;
    }
  }
  if (pos > bytes.size()) return std::nullopt;
  return deepest;
}

}  // namespace

std::string scene_too_deep() {
  return "scene nodes are nested more than " + std::to_string(kMaxSceneDepth) +
         " levels deep (the limit); flatten unions into one node with many children and combine transforms";
}

void check_request_limits(const google::protobuf::Message& message, const std::string& path) {
  LimitWalker().walk(message, path, path, 0);
}

bool wire_nests_deeper_than(std::string_view bytes, int levels) {
  const auto depth = nesting(bytes, levels + 1);
  return depth && *depth > levels;
}

int json_object_depth(std::string_view text) {
  int depth = 0, deepest = 0;
  bool in_string = false, escaped = false;
  for (const char c : text) {
    if (in_string) {
      if (escaped) {
        escaped = false;
      } else if (c == '\\') {
        escaped = true;
      } else if (c == '"') {
        in_string = false;
      }
    } else if (c == '"') {
      in_string = true;
    } else if (c == '{') {
      deepest = std::max(deepest, ++depth);
    } else if (c == '}') {
      --depth;
    }
  }
  return deepest;
}

}  // namespace surfacer::wire
