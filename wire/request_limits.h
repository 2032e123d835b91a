// What a request may be, checked the same way by the server (on SubmitJob) and by the CLI (on the spec it builds
// and the JSON files it reads): free-text fields and ids within their lengths, scene nodes nested at most
// kMaxSceneDepth deep (wire/protocol.h). Also the diagnosis of input that did not even parse because it nests
// deeper than the parser allows, so that it gets the same message as a scene one level too deep.
#pragma once

#include <string>
#include <string_view>

namespace google::protobuf {
class Message;
}

namespace surfacer::wire {

// "scene nodes are nested more than 32 levels deep (the limit); flatten ...": the one message for a scene too deep,
// whichever side and parser finds it.
std::string scene_too_deep();

// Protobuf recursion limit for parsing a request: room for kMaxSceneDepth levels (two messages each) and the
// messages around a scene, and more, so that a scene a little too deep parses and is refused by
// check_request_limits with its path.
inline constexpr int kRequestRecursionLimit = 100;

// Walks `message` (a JobSpec, a Scene, ...; `path` names it, e.g. "spec") and throws InvalidInput naming the first
// field over a limit: a string field ending in "id" longer than kMaxIdBytes, any other string field longer than
// kMaxNameBytes ("spec.name is 5000000 bytes; ..."), a scene whose nodes nest deeper than kMaxSceneDepth
// ("spec.isosurface.scenes[0].root: " + scene_too_deep()).
void check_request_limits(const google::protobuf::Message& message, const std::string& path);

// Whether the protobuf wire-format `bytes` hold length-delimited fields nested more than `levels` deep (each field
// that reads as a message counts; no schema needed). For a request that failed to parse: true means it failed on
// its depth.
bool wire_nests_deeper_than(std::string_view bytes, int levels);

// The deepest nesting of JSON objects in `text` (brackets inside strings do not count): protobuf's JSON parser
// refuses 100 and more.
int json_object_depth(std::string_view text);

}  // namespace surfacer::wire
