#include "core/mesh/mesh_gltf.h"

#include <meshoptimizer.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <map>
#include <numeric>
#include <optional>
#include <tuple>
#include <vector>

#include "core/mesh/mesh_io.h"
#include "core/util/base64.h"
#include "core/util/errors.h"
#include "core/util/json.h"
#include "core/util/json_read.h"

namespace surfacer {
namespace {

constexpr std::uint32_t kMagic = 0x46546C67;      // "glTF"
constexpr std::uint32_t kJsonChunk = 0x4E4F534A;  // "JSON"
constexpr std::uint32_t kBinChunk = 0x004E4942;   // "BIN\0"
using gltf::kByte, gltf::kFloat, gltf::kShort, gltf::kUnsignedByte, gltf::kUnsignedInt, gltf::kUnsignedShort;
// How a vertex is welded: by position (other programs' files), by position and seam tag (1 .. 65535), or never
// (kAlone: in our own files, whose pieces tag every vertex another piece has, an untagged vertex is in no other
// piece, even where it shares its point with another vertex).
constexpr std::uint32_t kByPosition = 0, kAlone = 0x10000;

std::uint32_t u32_at(std::string_view bytes, std::size_t at) {
  std::uint32_t v = 0;
  std::memcpy(&v, bytes.data() + at, 4);  // glTF is little-endian, as are the targets (x86-64, aarch64)
  return v;
}

int component_bytes(int type) {
  switch (type) {
    case kByte:
    case kUnsignedByte:
      return 1;
    case kShort:
    case kUnsignedShort:
      return 2;
    case kUnsignedInt:
    case kFloat:
      return 4;
    default:
      return 0;
  }
}

// An integer component as glTF's normalized value (the spec's conversions: signed values clamp at -1).
double normalized(int type, double v) {
  switch (type) {
    case kByte:
      return std::max(v / 127.0, -1.0);
    case kUnsignedByte:
      return v / 255.0;
    case kShort:
      return std::max(v / 32767.0, -1.0);
    case kUnsignedShort:
      return v / 65535.0;
    default:
      return v;
  }
}

// A little-endian value at p, unaligned (glTF is little-endian, as are the targets).
template <class T>
double load(const char* p) {
  T x;
  std::memcpy(&x, p, sizeof x);
  return static_cast<double>(x);
}

struct Accessor {
  std::size_t count = 0;
  int components = 0;
  int type = 0;  // componentType
  bool normalized = false;
  const char* base = nullptr;
  std::size_t stride = 0;

  double get(std::size_t i, int c) const {
    const char* p = base + i * stride + static_cast<std::size_t>(c) * component_bytes(type);
    double v = 0.0;
    switch (type) {
      case kByte:
        v = load<std::int8_t>(p);
        break;
      case kUnsignedByte:
        v = load<std::uint8_t>(p);
        break;
      case kShort:
        v = load<std::int16_t>(p);
        break;
      case kUnsignedShort:
        v = load<std::uint16_t>(p);
        break;
      case kUnsignedInt:
        v = load<std::uint32_t>(p);
        break;
      case kFloat:
        v = load<float>(p);
        break;
    }
    return normalized ? surfacer::normalized(type, v) : v;
  }
};

class GlbReader {
 public:
  GlbReader(std::string_view bytes, const std::string& name, const MeshReadLimits& limits)
      : bytes_(bytes), name_(name), limits_(limits) {}

  Mesh read() {
    std::string_view json;
    const std::size_t first = bytes_.find_first_not_of(" \t\r\n");
    if (first != std::string_view::npos && bytes_[first] == '{') {
      json = bytes_;  // a .gltf text file: its one buffer a data URI (embedded_buffer())
      text_ = true;
    } else {
      if (bytes_.size() < 20 || u32_at(bytes_, 0) != kMagic) bad("neither glTF JSON nor a glTF binary header");
      if (u32_at(bytes_, 4) != 2) bad("glTF version " + std::to_string(u32_at(bytes_, 4)) + ", not 2");
      if (u32_at(bytes_, 8) > bytes_.size()) bad("the header states more bytes than the file has");
      const std::string_view file = bytes_.substr(0, u32_at(bytes_, 8));
      for (std::size_t at = 12; at + 8 <= file.size();) {
        const std::uint32_t length = u32_at(file, at), type = u32_at(file, at + 4);
        if (length > file.size() - at - 8) bad("a chunk runs past the end of the file");
        const std::string_view data = file.substr(at + 8, length);
        if (at == 12 && type != kJsonChunk) bad("the first chunk is not JSON");
        if (at == 12) json = data;
        if (type == kBinChunk && at > 12 && bin_.data() == nullptr) bin_ = data;
        at += 8 + std::size_t{length};
      }
      if (json.data() == nullptr) bad("no JSON chunk");
    }
    root_ = parse_json(json, "file", name_);
    if (!root_.is_object()) bad("the JSON is not an object");
    if (text_) embedded_buffer();
    const JsonValue* asset = root_.find("asset");
    const JsonValue* version = asset ? asset->find("version") : nullptr;
    if (version == nullptr || version->kind != JsonValue::Kind::kString || version->string.substr(0, 2) != "2.") {
      bad("asset.version is not 2.x");
    }
    const JsonValue* generator = asset->find("generator");
    ours_ = generator && generator->kind == JsonValue::Kind::kString && generator->string == "surfacer";
    for (const JsonValue& r : list("extensionsRequired").items) {
      if (r.string != "KHR_draco_mesh_compression" && r.string != "KHR_mesh_quantization" &&
          r.string != "EXT_meshopt_compression") {
        bad("it requires the extension " + r.string + ", which is not read");
      }
    }
    collect();
    return weld();
  }

 private:
  [[noreturn]] void bad(const std::string& what) const { throw InvalidInput("file", name_ + ": " + what); }

  // A .gltf's buffer 0 from its base64 data URI, as the binary chunk of a .glb (buffers in other files are not read).
  void embedded_buffer() {
    const JsonValue& buffers = list("buffers");
    if (buffers.items.empty()) return;
    const JsonValue* uri = buffers.items[0].find("uri");
    const std::string_view text =
        uri != nullptr && uri->kind == JsonValue::Kind::kString ? std::string_view(uri->string) : std::string_view();
    const std::size_t comma = text.find(',');
    if (text.substr(0, 5) != "data:" || comma == std::string_view::npos ||
        text.substr(0, comma).find(";base64") == std::string_view::npos) {
      bad("buffer 0 is not a base64 data URI (a buffer in another file is not read: write the file as .glb or embed "
          "its buffer)");
    }
    std::optional<std::string> bytes = decode_base64(text.substr(comma + 1));
    if (!bytes) bad("buffer 0's data URI is not valid base64");
    embedded_ = std::move(*bytes);
    bin_ = embedded_;
  }

  // root_[key] as an array (an empty one when absent).
  const JsonValue& list(const char* key) const {
    static const JsonValue kEmpty = [] {
      JsonValue v;
      v.kind = JsonValue::Kind::kArray;
      return v;
    }();
    const JsonValue* v = root_.find(key);
    if (v == nullptr) return kEmpty;
    if (!v->is_array()) bad(std::string(key) + " is not an array");
    return *v;
  }

  // A non-negative integer (an index below `below` when given).
  std::size_t integer(const JsonValue* v, const std::string& what,
                      std::size_t below = std::numeric_limits<std::size_t>::max()) const {
    if (v == nullptr || !v->is_number() || v->number < 0 || v->number != std::floor(v->number) || v->number >= 9.0e15 ||
        static_cast<std::size_t>(v->number) >= below) {
      bad(what + " is missing or not " + (below == std::numeric_limits<std::size_t>::max() ? "a count" : "an index"));
    }
    return static_cast<std::size_t>(v->number);
  }

  const JsonValue& item(const char* key, std::size_t index, const std::string& what) const {
    const JsonValue& all = list(key);
    if (index >= all.items.size() || !all.items[index].is_object()) bad(what + " names a missing entry of " + key);
    return all.items[index];
  }

  // The bytes of buffer view `index`: a range of the binary chunk, or what EXT_meshopt_compression decodes.
  std::string_view view(std::size_t index, std::size_t* stride, const std::string& what) const {
    const JsonValue& v = item("bufferViews", index, what);
    const std::string where = what + " (bufferView " + std::to_string(index) + ")";
    if (stride) *stride = v.find("byteStride") ? integer(v.find("byteStride"), where + ".byteStride") : 0;
    const JsonValue* extensions = v.find("extensions");
    if (const JsonValue* meshopt = extensions ? extensions->find("EXT_meshopt_compression") : nullptr) {
      return decompressed(index, v, *meshopt, where);
    }
    return range(v, where);
  }

  // The range of the binary chunk that `v` (a buffer view or its EXT_meshopt_compression object) names.
  std::string_view range(const JsonValue& v, const std::string& where) const {
    const std::size_t buffer = integer(v.find("buffer"), where + ".buffer");
    const JsonValue& b = item("buffers", buffer, where);
    if (buffer != 0 || (b.find("uri") != nullptr && !text_)) {
      bad(where + " is in a buffer outside the file's binary chunk; pack the file as one self-contained .glb");
    }
    const std::size_t offset = v.find("byteOffset") ? integer(v.find("byteOffset"), where + ".byteOffset") : 0;
    const std::size_t length = integer(v.find("byteLength"), where + ".byteLength");
    if (offset > bin_.size() || length > bin_.size() - offset) bad(where + " runs past the binary chunk");
    return bin_.substr(offset, length);
  }

  // Buffer view `index` decoded by meshoptimizer as the extension's object `m` says, once. The decoded size is
  // bounded before anything is allocated: by what the compressed bytes can hold at the codecs' best (an attribute
  // block spends at least a byte per 64 values of each byte of the element, a triangle or index at least a byte),
  // and by limits.max_triangles (no primitive needs more than three points or indices a triangle).
  std::string_view decompressed(std::size_t index, const JsonValue& v, const JsonValue& m,
                                const std::string& where) const {
    if (const auto it = decompressed_.find(index); it != decompressed_.end()) return it->second;
    const std::string at = where + " EXT_meshopt_compression";
    const std::string_view data = range(m, at);
    const std::size_t stride = integer(m.find("byteStride"), at + ".byteStride");
    const std::size_t count = integer(m.find("count"), at + ".count");
    auto text = [&](const char* key, const char* absent) {
      const JsonValue* x = m.find(key);
      if (x == nullptr) return std::string(absent);
      if (x->kind != JsonValue::Kind::kString) bad(at + "." + key + " is not a string");
      return x->string;
    };
    const std::string mode = text("mode", ""), filter = text("filter", "NONE");
    const bool attributes = mode == "ATTRIBUTES";
    if (attributes ? (stride == 0 || stride % 4 != 0 || stride > 256) : (stride != 2 && stride != 4)) {
      bad(at + " has byteStride " + std::to_string(stride) + ", which its mode '" + mode + "' does not allow");
    }
    if (!attributes && mode != "TRIANGLES" && mode != "INDICES") bad(at + " has mode '" + mode + "'");
    if (mode == "TRIANGLES" && count % 3 != 0) bad(at + " has a count of triangle indices not divisible by 3");
    if (filter != "NONE" && (filter != "OCTAHEDRAL" || !attributes || (stride != 4 && stride != 8))) {
      bad(at + " has filter '" + filter + "' with mode '" + mode + "' and byteStride " + std::to_string(stride) +
          "; only NONE, and OCTAHEDRAL over 4 or 8 bytes (normals), are read");
    }
    if (v.find("byteStride") && integer(v.find("byteStride"), where + ".byteStride") != stride) {
      bad(where + " has another byteStride than its EXT_meshopt_compression");
    }
    if (integer(v.find("byteLength"), where + ".byteLength") != stride * count) {
      bad(where + ".byteLength is not byteStride times count of its EXT_meshopt_compression");
    }
    const std::size_t most = attributes ? 64 : mode == "TRIANGLES" ? 12 : 4;
    if (stride * count > most * data.size() + 4096)
      bad(at + " claims more data than its " + std::to_string(data.size()) + " bytes hold");
    if (static_cast<double>(count) > 3.0 * static_cast<double>(limits_.max_triangles) + 3.0) {
      throw ResourceLimit("max_triangles", name_ + ": " + at + " holds " + std::to_string(count) +
                                               " values, more than a mesh of " + std::to_string(limits_.max_triangles) +
                                               " triangles (the largest accepted here) needs");
    }
    std::string out(stride * count, '\0');
    const auto* in = reinterpret_cast<const unsigned char*>(data.data());
    const int failed = attributes            ? meshopt_decodeVertexBuffer(out.data(), count, stride, in, data.size())
                       : mode == "TRIANGLES" ? meshopt_decodeIndexBuffer(out.data(), count, stride, in, data.size())
                                             : meshopt_decodeIndexSequence(out.data(), count, stride, in, data.size());
    if (failed != 0) bad(at + " does not decode as meshoptimizer " + mode + " data");
    if (filter == "OCTAHEDRAL") meshopt_decodeFilterOct(out.data(), count, stride);
    return decompressed_.emplace(index, std::move(out)).first->second;
  }

  // The accessor's data; with `with_data` false only its count and how to read its values (a Draco-compressed
  // primitive's accessors have no data of their own).
  Accessor accessor(std::size_t index, const std::string& what, bool with_data = true) const {
    const JsonValue& a = item("accessors", index, what);
    const std::string where = what + " (accessor " + std::to_string(index) + ")";
    if (a.find("sparse")) bad(where + " is sparse, which is not read");
    Accessor out;
    out.count = integer(a.find("count"), where + ".count");
    out.type = static_cast<int>(integer(a.find("componentType"), where + ".componentType"));
    if (component_bytes(out.type) == 0) bad(where + " has componentType " + std::to_string(out.type));
    const JsonValue* type = a.find("type");
    const std::string t = type ? type->string : "";
    out.components = t == "SCALAR" ? 1 : t == "VEC2" ? 2 : t == "VEC3" ? 3 : t == "VEC4" ? 4 : 0;
    if (out.components == 0) bad(where + " has type '" + t + "'");
    const JsonValue* norm = a.find("normalized");
    out.normalized = norm && norm->kind == JsonValue::Kind::kBool && norm->boolean;
    if (!with_data) return out;
    if (!a.find("bufferView")) bad(where + " has no bufferView");
    std::size_t stride = 0;
    const std::string_view data = view(integer(a.find("bufferView"), where + ".bufferView"), &stride, where);
    const std::size_t element = static_cast<std::size_t>(out.components) * component_bytes(out.type);
    out.stride = stride == 0 ? element : stride;
    if (out.stride < element) bad(where + " has a byteStride smaller than its elements");
    const std::size_t offset = a.find("byteOffset") ? integer(a.find("byteOffset"), where + ".byteOffset") : 0;
    if (offset > data.size()) bad(where + " starts past its bufferView");
    if (out.count > 0 && (out.count - 1 > (data.size() - offset) / out.stride ||
                          (out.count - 1) * out.stride + element > data.size() - offset)) {
      bad(where + " runs past its bufferView");
    }
    out.base = data.data() + offset;
    return out;
  }

  // The roots of the scene to read, checked.
  std::vector<std::size_t> roots() const {
    const JsonValue& nodes = list("nodes");
    const JsonValue& scenes = list("scenes");
    std::vector<std::size_t> out;
    if (!scenes.items.empty()) {
      const std::size_t s = root_.find("scene") ? integer(root_.find("scene"), "scene", scenes.items.size()) : 0;
      const JsonValue* listed = scenes.items[s].find("nodes");
      if (listed == nullptr) return out;
      if (!listed->is_array()) bad("scene " + std::to_string(s) + ".nodes is not an array");
      for (const JsonValue& n : listed->items) out.push_back(integer(&n, "a scene node", nodes.items.size()));
      return out;
    }
    std::vector<bool> child(nodes.items.size(), false);
    for (const JsonValue& n : nodes.items) {
      if (const JsonValue* c = n.find("children"); c && c->is_array()) {
        for (const JsonValue& i : c->items) child[integer(&i, "a child node", nodes.items.size())] = true;
      }
    }
    for (std::size_t n = 0; n < nodes.items.size(); ++n) {
      if (!child[n]) out.push_back(n);
    }
    return out;
  }

  Eigen::Matrix4d local(const JsonValue& node, const std::string& where) const {
    auto numbers = [&](const char* key, std::size_t n) {
      std::vector<double> out;
      const JsonValue* v = node.find(key);
      if (v == nullptr) return out;
      if (!v->is_array() || v->items.size() != n) bad(where + "." + key + " is not " + std::to_string(n) + " numbers");
      for (const JsonValue& x : v->items) {
        if (!x.is_number()) bad(where + "." + key + " is not " + std::to_string(n) + " numbers");
        out.push_back(x.number);
      }
      return out;
    };
    Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
    if (const std::vector<double> mat = numbers("matrix", 16); !mat.empty()) {
      for (int i = 0; i < 16; ++i) m(i % 4, i / 4) = mat[i];  // column-major
      return m;
    }
    if (const std::vector<double> s = numbers("scale", 3); !s.empty()) {
      m = Eigen::Vector4d(s[0], s[1], s[2], 1.0).asDiagonal();
    }
    if (const std::vector<double> r = numbers("rotation", 4); !r.empty()) {
      Eigen::Quaterniond q(r[3], r[0], r[1], r[2]);  // glTF stores x, y, z, w
      if (!(q.norm() > 0.0)) bad(where + ".rotation is not a rotation");
      q.normalize();
      Eigen::Matrix4d rotation = Eigen::Matrix4d::Identity();
      rotation.topLeftCorner<3, 3>() = q.toRotationMatrix();
      m = rotation * m;
    }
    if (const std::vector<double> t = numbers("translation", 3); !t.empty()) {
      Eigen::Matrix4d translation = Eigen::Matrix4d::Identity();
      translation.topRightCorner<3, 1>() = Eigen::Vector3d(t[0], t[1], t[2]);
      m = translation * m;
    }
    return m;
  }

  // Every node under the roots, each once (glTF's nodes form trees), with its world transform.
  void collect() {
    const JsonValue& nodes = list("nodes");
    std::vector<bool> seen(nodes.items.size(), false);
    std::vector<std::pair<std::size_t, Eigen::Matrix4d>> stack;
    for (std::size_t r : roots()) stack.emplace_back(r, Eigen::Matrix4d::Identity());
    while (!stack.empty()) {
      const auto [n, parent] = stack.back();
      stack.pop_back();
      const std::string where = "node " + std::to_string(n);
      if (seen[n]) bad(where + " is reached twice (glTF's nodes form trees)");
      seen[n] = true;
      const JsonValue& node = nodes.items[n];
      if (!node.is_object()) bad(where + " is not an object");
      const Eigen::Matrix4d world = parent * local(node, where);
      if (!world.allFinite()) bad(where + " has a transform that is not finite");
      if (const JsonValue* m = node.find("mesh")) add_mesh(integer(m, where + ".mesh"), world, where);
      if (const JsonValue* c = node.find("children")) {
        if (!c->is_array()) bad(where + ".children is not an array");
        for (const JsonValue& i : c->items)
          stack.emplace_back(integer(&i, where + ".children", nodes.items.size()), world);
      }
    }
  }

  // A primitive's triangles over the points they use, in the file's coordinates.
  struct Part {
    std::vector<Vec3> points;
    std::vector<Vec3> normals;          // one per point, or none
    std::vector<std::uint32_t> weld;    // per point: kByPosition, a seam tag or kAlone
    std::vector<Attribute> attributes;  // application-specific ones, named, one element per point each
    std::vector<Triangle> triangles;
  };

  // The application-specific attributes of a primitive (all but _SEAM), in the file's order, with the names the
  // mesh's extras give them (gltf_attribute_semantics), else the semantic without its underscore; a name that is
  // empty or taken already becomes the semantic itself, and a semantic listed twice is read once (Mesh::attributes
  // have distinct names).
  std::vector<std::pair<std::string, std::string>> custom_attributes(std::size_t mesh, const JsonValue& attributes,
                                                                     const std::string& where) const {
    const JsonValue* extras = item("meshes", mesh, where).find("extras");
    const JsonValue* names = extras ? extras->find(kGltfAttributeNamesKey) : nullptr;
    std::vector<std::pair<std::string, std::string>> out;  // (semantic, name)
    auto taken = [&](const std::string& name) {
      return std::any_of(out.begin(), out.end(), [&](const auto& o) { return o.second == name; });
    };
    for (const JsonMember& m : attributes.members) {
      if (m.name.empty() || m.name[0] != '_' || m.name == kGltfSeamSemantic) continue;
      if (std::any_of(out.begin(), out.end(), [&](const auto& o) { return o.first == m.name; })) continue;
      const JsonValue* given = names ? names->find(m.name) : nullptr;
      std::string name = given && given->kind == JsonValue::Kind::kString ? given->string : m.name.substr(1);
      if (name.empty() || taken(name)) name = m.name;
      if (taken(name)) continue;
      out.emplace_back(m.name, std::move(name));
    }
    return out;
  }

  // Primitive p of mesh `index`, read and decoded once however many nodes instance it.
  const Part& part(std::size_t index, std::size_t p, const JsonValue& prim, const std::string& where) {
    if (const auto it = parts_.find({index, p}); it != parts_.end()) return it->second;
    if (!prim.is_object()) bad(where + " is not an object");
    const std::size_t mode = prim.find("mode") ? integer(prim.find("mode"), where + ".mode") : 4;
    if (mode < 4 || mode > 6) {
      bad(where + " has mode " + std::to_string(mode) + " (points or lines); only triangles (4, 5, 6) make a surface");
    }
    const JsonValue* attributes = prim.find("attributes");
    const std::size_t position_index =
        integer(attributes ? attributes->find("POSITION") : nullptr, where + ".attributes.POSITION");
    const JsonValue* extensions = prim.find("extensions");
    const JsonValue* draco = extensions ? extensions->find("KHR_draco_mesh_compression") : nullptr;
    const Accessor position = accessor(position_index, where + " POSITION", draco == nullptr);
    if (position.components != 3 || position.type == kUnsignedInt) bad(where + " has a POSITION that is not a VEC3");
    std::vector<Vec3> points;
    std::vector<std::uint32_t> weld;  // per point: kByPosition, a seam tag or kAlone
    std::vector<Vec3> normals;
    std::vector<Attribute> custom;  // per point
    std::vector<std::size_t> indices;
    const JsonValue* seam = attributes->find(kGltfSeamSemantic);
    const auto named = custom_attributes(index, *attributes, where);
    if (draco != nullptr) {
      if (mode != 4) bad(where + " is Draco-compressed with mode " + std::to_string(mode));
      const std::string_view data =
          view(integer(draco->find("bufferView"), where + " Draco bufferView"), nullptr, where + " Draco stream");
      const JsonValue* ids = draco->find("attributes");
      Mesh decoded;
      try {
        // The pieces of a frame: grid coordinates, seam tags (none in a frame of one piece), attributes.
        if (seam != nullptr || (ours_ && !named.empty())) {
          DracoPieceInfo info;
          QuantizedPiece piece = decode_draco_piece(data, 16, &info);
          if (ids == nullptr || info.position < 0 ||
              (seam != nullptr && (info.seam < 0 || integer(ids->find(kGltfSeamSemantic), where + " Draco _SEAM") !=
                                                        static_cast<std::size_t>(info.seam))) ||
              integer(ids->find("POSITION"), where + " Draco POSITION") != static_cast<std::size_t>(info.position)) {
            bad(where + ": the Draco stream's attributes are not the ones the primitive names");
          }
          for (const auto& [semantic, name] : named) {
            const std::size_t id = integer(ids->find(semantic), where + " Draco " + semantic);
            const std::size_t first = info.attributes < 0 ? piece.attributes.size() : info.attributes;
            if (id < first || id - first >= piece.attributes.size()) {
              bad(where + ": the Draco stream has no attribute " + std::to_string(id) + " for " + semantic);
            }
            custom.push_back(std::move(piece.attributes[id - first]));
            custom.back().name = name;
          }
          for (const auto& q : piece.positions) decoded.vertices.emplace_back(q[0], q[1], q[2]);
          for (std::uint16_t tag : piece.seam_tags) weld.push_back(tag == 0 ? kAlone : tag);
          decoded.triangles = std::move(piece.triangles);
          decoded.normals = std::move(piece.normals);
        } else {
          decoded = decode_draco(data, limits_);
        }
      } catch (const Error& e) {
        if (e.kind() != ErrorKind::kInvalidInput)
          throw Error(e.kind(), e.field(), name_ + ": " + where + ": " + e.what());
        bad(where + ": " + e.what());
      }
      // Draco gives the stored values; the accessor says how to read them.
      for (Vec3& v : decoded.vertices) {
        if (position.normalized) {
          for (int c = 0; c < 3; ++c) v[c] = normalized(position.type, v[c]);
        }
      }
      points = std::move(decoded.vertices);
      normals = std::move(decoded.normals);
      indices.reserve(3 * decoded.triangles.size());
      for (const Triangle& t : decoded.triangles) indices.insert(indices.end(), t.begin(), t.end());
    } else {
      points.resize(position.count);
      for (std::size_t i = 0; i < position.count; ++i) {
        points[i] = Vec3(position.get(i, 0), position.get(i, 1), position.get(i, 2));
      }
      if (const JsonValue* idx = prim.find("indices")) {
        const Accessor a = accessor(integer(idx, where + ".indices"), where + " indices");
        if (a.components != 1 || a.type == kFloat || a.type == kByte || a.type == kShort || a.normalized) {
          bad(where + " has indices that are not unsigned integers");
        }
        indices.resize(a.count);
        for (std::size_t i = 0; i < a.count; ++i) indices[i] = static_cast<std::size_t>(a.get(i, 0));
      } else {
        indices.resize(points.size());
        std::iota(indices.begin(), indices.end(), std::size_t{0});
      }
      if (const JsonValue* normal = attributes->find("NORMAL")) {
        const Accessor a = accessor(integer(normal, where + ".attributes.NORMAL"), where + " NORMAL");
        if (a.components != 3 || a.type == kUnsignedInt || a.count != points.size()) {
          bad(where + " has a NORMAL that is not one VEC3 per vertex");
        }
        normals.resize(a.count);
        for (std::size_t i = 0; i < a.count; ++i) normals[i] = Vec3(a.get(i, 0), a.get(i, 1), a.get(i, 2));
      }
      for (const auto& [semantic, name] : named) {
        const Accessor a =
            accessor(integer(attributes->find(semantic), where + ".attributes." + semantic), where + " " + semantic);
        if (a.count != points.size()) bad(where + " has a " + semantic + " that is not one element per vertex");
        Attribute& attribute = custom.emplace_back(Attribute{name, a.components, {}});
        attribute.values.resize(a.count * a.components);
        for (std::size_t i = 0; i < a.count; ++i) {
          for (int c = 0; c < a.components; ++c)
            attribute.values[i * a.components + c] = static_cast<float>(a.get(i, c));
        }
      }
      // Meshopt pieces (and Draco pieces decompressed by another tool) keep the tags as plain data: a SCALAR, or the
      // last component of a VEC4 (meshopt's 8-byte vertices x, y, z, tag: glTF aligns attributes on 4 bytes).
      if (seam != nullptr) {
        const Accessor a = accessor(integer(seam, where + ".attributes._SEAM"), where + " _SEAM");
        if ((a.components != 1 && a.components != 4) || a.type != kUnsignedShort || a.normalized ||
            a.count != points.size()) {
          bad(where + " has a _SEAM that is not one unsigned short (or the last of a VEC4) per vertex");
        }
        for (std::size_t i = 0; i < a.count; ++i) {
          const auto tag = static_cast<std::uint32_t>(a.get(i, a.components - 1));
          weld.push_back(tag == 0 ? kAlone : tag);
        }
      }
    }
    if (weld.empty()) weld.assign(points.size(), ours_ ? kAlone : kByPosition);
    for (std::size_t i : indices) {
      if (i >= points.size()) bad(where + " uses vertex " + std::to_string(i) + " of " + std::to_string(points.size()));
    }
    // The triangles, and only the points they use (a file may list points no triangle of the primitive uses).
    Part out;
    for (const Attribute& a : custom) {
      if (a.values.size() != points.size() * a.components) bad(where + " has a " + a.name + " of another count");
      out.attributes.push_back(Attribute{a.name, a.components, {}});
    }
    std::vector<std::uint32_t> local(points.size(), std::numeric_limits<std::uint32_t>::max());
    auto add = [&](std::size_t a, std::size_t b, std::size_t c) {
      Triangle t;
      const std::size_t corners[3] = {a, b, c};
      for (int k = 0; k < 3; ++k) {
        std::uint32_t& l = local[corners[k]];
        if (l == std::numeric_limits<std::uint32_t>::max()) {
          l = static_cast<std::uint32_t>(out.points.size());
          out.points.push_back(points[corners[k]]);
          out.weld.push_back(weld[corners[k]]);
          if (!normals.empty()) out.normals.push_back(normals[corners[k]]);
          for (std::size_t a = 0; a < custom.size(); ++a) {
            const auto begin = custom[a].values.begin() + corners[k] * custom[a].components;
            out.attributes[a].values.insert(out.attributes[a].values.end(), begin, begin + custom[a].components);
          }
        }
        t[k] = l;
      }
      out.triangles.push_back(t);
    };
    const std::size_t n = indices.size();
    const std::size_t triangles = mode == 4 ? n / 3 : (n >= 3 ? n - 2 : 0);
    out.triangles.reserve(triangles);
    for (std::size_t t = 0; t < triangles; ++t) {
      if (mode == 4) {
        add(indices[3 * t], indices[3 * t + 1], indices[3 * t + 2]);
      } else if (mode == 5) {  // strip: every other triangle is reversed to keep one orientation
        if (t % 2 == 0) {
          add(indices[t], indices[t + 1], indices[t + 2]);
        } else {
          add(indices[t + 1], indices[t], indices[t + 2]);
        }
      } else {  // fan
        add(indices[0], indices[t + 1], indices[t + 2]);
      }
    }
    return parts_.emplace(std::pair{index, p}, std::move(out)).first->second;
  }

  void add_mesh(std::size_t index, const Eigen::Matrix4d& world, const std::string& node) {
    const JsonValue& mesh = item("meshes", index, node + ".mesh");
    const JsonValue* primitives = mesh.find("primitives");
    if (primitives == nullptr || !primitives->is_array()) bad("mesh " + std::to_string(index) + " has no primitives");
    const Eigen::Matrix3d linear = world.topLeftCorner<3, 3>();
    const bool mirrored = linear.determinant() < 0.0;
    // Normals go through the inverse transpose (a singular transform flattens the surface: its normals are kept).
    const Eigen::Matrix3d normal_map =
        std::abs(linear.determinant()) > 0.0 ? Eigen::Matrix3d(linear.inverse().transpose()) : linear;
    for (std::size_t p = 0; p < primitives->items.size(); ++p) {
      const std::string where = "mesh " + std::to_string(index) + " primitive " + std::to_string(p);
      const Part& part = this->part(index, p, primitives->items[p], where);
      // Each instance adds its triangles and at most three points per triangle: the limit bounds both.
      if (static_cast<double>(triangles_.size()) + static_cast<double>(part.triangles.size()) >
          static_cast<double>(limits_.max_triangles)) {
        throw ResourceLimit("max_triangles", name_ + ": more than " + std::to_string(limits_.max_triangles) +
                                                 " triangles (the largest mesh accepted here)");
      }
      const std::size_t base = vertices_.size();
      if (base + part.points.size() > std::numeric_limits<std::uint32_t>::max()) bad("more than 2^32 - 1 vertices");
      for (const Vec3& q : part.points) {
        const Eigen::Vector4d w = world * Eigen::Vector4d(q.x(), q.y(), q.z(), 1.0);
        const Vec3 v = w.head<3>();
        if (!v.allFinite()) bad(where + " has a position that is not finite in " + node);
        vertices_.push_back(v);
      }
      weld_.insert(weld_.end(), part.weld.begin(), part.weld.end());
      if (part.normals.empty()) all_normals_ = false;
      // The mesh keeps the attributes every primitive has alike (names and components, in order).
      if (base == 0 && attributes_.empty() && same_attributes_) {
        for (const Attribute& a : part.attributes) attributes_.push_back(Attribute{a.name, a.components, {}});
      }
      same_attributes_ = same_attributes_ && part.attributes.size() == attributes_.size();
      for (std::size_t a = 0; same_attributes_ && a < attributes_.size(); ++a) {
        same_attributes_ = part.attributes[a].name == attributes_[a].name &&
                           part.attributes[a].components == attributes_[a].components;
        attributes_[a].values.insert(attributes_[a].values.end(), part.attributes[a].values.begin(),
                                     part.attributes[a].values.end());
      }
      for (const Vec3& n : part.normals) {
        const Vec3 m = normal_map * n;
        const double length = m.norm();
        normals_.push_back(length > 0.0 && std::isfinite(length) ? Vec3(m / length) : Vec3::Zero());
      }
      for (Triangle t : part.triangles) {
        for (std::uint32_t& v : t) v += static_cast<std::uint32_t>(base);
        if (mirrored) std::swap(t[1], t[2]);
        triangles_.push_back(t);
      }
    }
  }

  // One vertex per distinct (point, weld class), but every kAlone vertex on its own; in the order of first
  // appearance.
  Mesh weld() {
    const std::size_t n = vertices_.size();
    std::vector<std::uint32_t> first(n);  // each vertex's first copy
    std::vector<std::uint32_t> order;
    for (std::size_t v = 0; v < n; ++v) {
      first[v] = static_cast<std::uint32_t>(v);
      if (weld_[v] != kAlone) order.push_back(static_cast<std::uint32_t>(v));
    }
    auto key = [&](std::uint32_t i) {
      return std::tuple(vertices_[i].x(), vertices_[i].y(), vertices_[i].z(), weld_[i]);
    };
    std::stable_sort(order.begin(), order.end(), [&](std::uint32_t a, std::uint32_t b) { return key(a) < key(b); });
    for (std::size_t i = 1; i < order.size(); ++i) {
      if (key(order[i]) == key(order[i - 1])) first[order[i]] = first[order[i - 1]];
    }
    std::vector<std::uint32_t> id(n, std::numeric_limits<std::uint32_t>::max());
    Mesh mesh;
    const bool normals = all_normals_ && n > 0;
    if (same_attributes_ && n > 0) {
      for (const Attribute& a : attributes_) mesh.attributes.push_back(Attribute{a.name, a.components, {}});
    }
    for (std::size_t v = 0; v < n; ++v) {
      if (first[v] != v) continue;
      id[v] = static_cast<std::uint32_t>(mesh.vertices.size());
      mesh.vertices.push_back(vertices_[v]);
      if (normals) mesh.normals.push_back(normals_[v]);  // a welded vertex takes its first copy's normal (and values)
      for (std::size_t a = 0; a < mesh.attributes.size(); ++a) {
        const auto begin = attributes_[a].values.begin() + v * attributes_[a].components;
        mesh.attributes[a].values.insert(mesh.attributes[a].values.end(), begin, begin + attributes_[a].components);
      }
    }
    mesh.triangles = std::move(triangles_);
    for (Triangle& t : mesh.triangles) {
      for (std::uint32_t& v : t) v = id[first[v]];
    }
    return mesh;
  }

  std::string_view bytes_;
  const std::string& name_;
  const MeshReadLimits& limits_;
  std::string_view bin_;
  bool text_ = false;     // a .gltf (JSON) file, not a .glb
  std::string embedded_;  // a .gltf's buffer 0, decoded from its data URI
  JsonValue root_;
  bool ours_ = false;  // written by to_gltf (asset.generator "surfacer"): welded through _SEAM only
  std::vector<Vec3> vertices_;
  std::vector<std::uint32_t> weld_;    // per vertex, its weld class
  std::vector<Vec3> normals_;          // per vertex of the primitives that have normals
  bool all_normals_ = true;            // every primitive has them: the mesh gets normals
  std::vector<Attribute> attributes_;  // per vertex, while every primitive has the same ones
  bool same_attributes_ = true;
  std::vector<Triangle> triangles_;
  std::map<std::pair<std::size_t, std::size_t>, Part> parts_;  // by (mesh, primitive)
  mutable std::map<std::size_t, std::string> decompressed_;    // EXT_meshopt_compression buffer views, by index
};

}  // namespace

std::vector<std::string> gltf_attribute_semantics(const std::vector<Attribute>& attributes) {
  std::vector<std::string> out;
  auto taken = [&](const std::string& semantic) {
    return semantic == kGltfSeamSemantic || std::find(out.begin(), out.end(), semantic) != out.end();
  };
  for (const Attribute& a : attributes) {
    std::string semantic = "_";
    for (const char c : a.name) {
      const auto u = static_cast<unsigned char>(c);
      semantic += std::isalnum(u) && u < 0x80 ? static_cast<char>(std::toupper(u)) : '_';
    }
    std::string unique = semantic;
    for (int k = 2; taken(unique); ++k) unique = semantic + "_" + std::to_string(k);
    out.push_back(std::move(unique));
  }
  return out;
}

const char* gltf_accessor_type(int components) {
  switch (components) {
    case 1:
      return "SCALAR";
    case 2:
      return "VEC2";
    case 3:
      return "VEC3";
    case 4:
      return "VEC4";
    default:
      throw Internal("a glTF accessor of " + std::to_string(components) + " components");
  }
}

void write_gltf_mesh_extras(JsonWriter& w, const std::vector<Attribute>& attributes) {
  if (attributes.empty()) return;
  const std::vector<std::string> semantics = gltf_attribute_semantics(attributes);
  w.key("extras").begin_object().key(kGltfAttributeNamesKey).begin_object();
  for (std::size_t a = 0; a < attributes.size(); ++a) w.key(semantics[a]).value(attributes[a].name);
  w.end_object().end_object();
}

std::string pack_glb(std::string json, std::string bin) {
  while (json.size() % 4 != 0) json.push_back(' ');
  while (bin.size() % 4 != 0) bin.push_back('\0');
  const std::size_t total = 12 + 8 + json.size() + (bin.empty() ? 0 : 8 + bin.size());
  if (total > std::numeric_limits<std::uint32_t>::max()) throw ResourceLimit("frame", "a glTF file of over 4 GiB");
  std::string out;
  out.reserve(total);
  auto u32 = [&out](std::uint32_t v) { out.append(reinterpret_cast<const char*>(&v), 4); };  // little-endian targets
  u32(kMagic);
  u32(2);
  u32(static_cast<std::uint32_t>(total));
  u32(static_cast<std::uint32_t>(json.size()));
  u32(kJsonChunk);
  out += json;
  if (!bin.empty()) {
    u32(static_cast<std::uint32_t>(bin.size()));
    u32(kBinChunk);
    out += bin;
  }
  return out;
}

namespace {

// `mesh` as plain glTF (write_gltf, write_glb): the JSON text, and the binary buffer either embedded in it as a
// base64 data URI (`embed`) or returned in `bin` for a .glb's BIN chunk.
std::string plain_gltf(const Mesh& mesh, bool embed, std::string& bin) {
  check_mesh_writable(mesh, embed ? ".gltf" : ".glb");
  const std::string asset = R"("asset": {"version": "2.0", "generator": "surfacer"})";
  bin.clear();
  if (mesh.triangles.empty()) return "{" + asset + R"(, "scene": 0, "scenes": [{"nodes": []}]})" + "\n";
  const std::size_t n = mesh.vertices.size();
  const bool normals = !mesh.normals.empty();
  bin.reserve(n * (normals ? 24 : 12) + mesh.triangles.size() * 12);
  auto put = [&bin](auto value) { bin.append(reinterpret_cast<const char*>(&value), sizeof value); };
  std::array<float, 3> lo{}, hi{};
  lo.fill(std::numeric_limits<float>::max());
  hi.fill(std::numeric_limits<float>::lowest());
  for (const Vec3& p : mesh.vertices) {
    for (int c = 0; c < 3; ++c) {
      const auto v = static_cast<float>(p[c]);
      lo[c] = std::min(lo[c], v);
      hi[c] = std::max(hi[c], v);
      put(v);
    }
  }
  const std::size_t positions_bytes = bin.size();
  if (normals) {
    for (const Vec3& normal : mesh.normals) {
      const double length = normal.norm();
      const Vec3 unit = length > 0 ? Vec3(normal / length) : Vec3(0, 0, 1);  // glTF requires unit NORMALs
      for (int c = 0; c < 3; ++c) put(static_cast<float>(unit[c]));
    }
  }
  // Each attribute's floats, in a buffer view of its own (after the normals: 4-byte values keep every view aligned).
  std::vector<std::size_t> attribute_offsets;
  for (const Attribute& a : mesh.attributes) {
    attribute_offsets.push_back(bin.size());
    bin.append(reinterpret_cast<const char*>(a.values.data()), a.values.size() * sizeof(float));
  }
  const std::size_t indices_offset = bin.size();
  for (const Triangle& t : mesh.triangles) {
    for (const std::uint32_t v : t) put(v);
  }
  auto number = [](float v) {
    char text[32];
    std::snprintf(text, sizeof text, "%.9g", static_cast<double>(v));  // 9 digits: exact for a float
    return std::string(text);
  };
  auto triple = [&](const std::array<float, 3>& v) {
    return "[" + number(v[0]) + ", " + number(v[1]) + ", " + number(v[2]) + "]";
  };
  const std::string count = std::to_string(n), length = std::to_string(bin.size());
  std::string json = "{" + asset + R"(, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],)";
  // Accessors and buffer views: 0 positions, 1 indices, 2 normals (with normals), then one per attribute.
  const std::size_t first_attribute = normals ? 3 : 2;
  const std::vector<std::string> semantics = gltf_attribute_semantics(mesh.attributes);
  json += R"( "meshes": [{"primitives": [{"attributes": {"POSITION": 0)";
  if (normals) json += R"(, "NORMAL": 2)";
  for (std::size_t a = 0; a < semantics.size(); ++a) {
    json += ", " + json_quote(semantics[a]) + ": " + std::to_string(first_attribute + a);
  }
  json += R"(}, "indices": 1, "mode": 4}])";
  if (!mesh.attributes.empty()) {
    JsonWriter extras;
    extras.begin_object();
    write_gltf_mesh_extras(extras, mesh.attributes);
    extras.end_object();
    json += ", " + extras.str().substr(1, extras.str().size() - 2);
  }
  json += "}],";
  json += R"( "accessors": [{"bufferView": 0, "componentType": 5126, "count": )" + count +
          R"(, "type": "VEC3", "min": )" + triple(lo) + R"(, "max": )" + triple(hi) + "}, ";
  json += R"({"bufferView": 1, "componentType": 5125, "count": )" + std::to_string(3 * mesh.triangles.size()) +
          R"(, "type": "SCALAR"})";
  if (normals) json += R"(, {"bufferView": 2, "componentType": 5126, "count": )" + count + R"(, "type": "VEC3"})";
  for (std::size_t a = 0; a < mesh.attributes.size(); ++a) {
    json += R"(, {"bufferView": )" + std::to_string(first_attribute + a) + R"(, "componentType": 5126, "count": )" +
            count + R"(, "type": ")" + gltf_accessor_type(mesh.attributes[a].components) + "\"}";
  }
  json += R"(], "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": )" + std::to_string(positions_bytes) +
          R"(, "target": 34962}, {"buffer": 0, "byteOffset": )" + std::to_string(indices_offset) +
          R"(, "byteLength": )" + std::to_string(bin.size() - indices_offset) + R"(, "target": 34963})";
  if (normals) {
    const std::size_t end = attribute_offsets.empty() ? indices_offset : attribute_offsets[0];
    json += R"(, {"buffer": 0, "byteOffset": )" + std::to_string(positions_bytes) + R"(, "byteLength": )" +
            std::to_string(end - positions_bytes) + R"(, "target": 34962})";
  }
  for (std::size_t a = 0; a < mesh.attributes.size(); ++a) {
    const std::size_t end = a + 1 < attribute_offsets.size() ? attribute_offsets[a + 1] : indices_offset;
    json += R"(, {"buffer": 0, "byteOffset": )" + std::to_string(attribute_offsets[a]) + R"(, "byteLength": )" +
            std::to_string(end - attribute_offsets[a]) + R"(, "target": 34962})";
  }
  json += R"(], "buffers": [{"byteLength": )" + length;
  if (embed) {
    json += R"(, "uri": "data:application/octet-stream;base64,)";
    append_base64(json, bin);
    json += "\"";
    bin.clear();
  }
  json += "}]}\n";
  return json;
}

}  // namespace

std::string write_gltf(const Mesh& mesh) {
  std::string bin;
  return plain_gltf(mesh, /*embed=*/true, bin);
}

std::string write_glb(const Mesh& mesh) {
  std::string bin;
  std::string json = plain_gltf(mesh, /*embed=*/false, bin);
  return pack_glb(std::move(json), std::move(bin));
}

Mesh parse_glb(std::string_view bytes, const std::string& name, const MeshReadLimits& limits) {
  return GlbReader(bytes, name, limits).read();
}

}  // namespace surfacer
