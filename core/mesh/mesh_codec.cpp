// Draco encoding with explicit position quantization (so every frame of a job shares one quantization grid).
#include "core/mesh/mesh_codec.h"

#include <draco/compression/decode.h>
#include <draco/compression/encode.h>
#include <draco/core/decoder_buffer.h>
#include <draco/core/encoder_buffer.h>
#include <draco/mesh/mesh.h>
#include <draco/metadata/geometry_metadata.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>
#include <new>
#include <optional>

#include "core/mesh/mesh_io.h"
#include "core/util/allocation_budget.h"
#include "core/util/checks.h"
#include "core/util/errors.h"
#include "core/util/parallel.h"

namespace surfacer {

void validate(const DracoOptions& options) {
  const DracoOptions defaults;
  require_count(
      "quantization_bits", options.quantization_bits, 1, 30,
      "the default " + std::to_string(defaults.quantization_bits) + " keeps errors below 1e-4 of the quantization box");
  require_count("speed", options.speed, 0, 10,
                "0: smallest output, 10: fastest; the default is " + std::to_string(defaults.speed));
  if (options.normals) {
    require_count("normal_bits", options.normal_bits, 2, 30, "the default is " + std::to_string(defaults.normal_bits));
  }
  if (options.quantization_bounds) require_box("quantization_bounds", *options.quantization_bounds);
}

namespace {

// The quantization box as Draco sees it: origin and one range for all axes (the box's longest side).
struct QuantizationBox {
  Vec3 origin;
  double range;
};

// Checks the mesh for encoding and returns its quantization box: options.quantization_bounds, else the mesh's own
// box. Throws for the first problem in this order: the options, the normals' count, the lowest non-finite vertex, the
// lowest triangle with an index out of range, the lowest vertex outside quantization_bounds. Blocks of vertices and
// of triangles are items of one parallel_for on `threads` threads; the error is the same whatever their number.
QuantizationBox checked_box(const Mesh& mesh, const DracoOptions& options, int threads) {
  validate(options);
  if (!mesh.normals.empty() && mesh.normals.size() != mesh.vertices.size()) {
    throw InvalidInput("normals", "mesh has " + std::to_string(mesh.normals.size()) + " normals for " +
                                      std::to_string(mesh.vertices.size()) +
                                      " vertices; give one normal per vertex or none");
  }
  constexpr std::size_t kBlock = std::size_t{1} << 16;
  const std::size_t nv = mesh.vertices.size(), nf = mesh.triangles.size();
  const int vertex_blocks = static_cast<int>((nv + kBlock - 1) / kBlock);
  const int triangle_blocks = static_cast<int>((nf + kBlock - 1) / kBlock);
  const std::optional<Aabb>& bounds = options.quantization_bounds;
  // Vertices may touch the box (marching cubes puts them exactly on its faces), and a frame's grid points may lie
  // outside it by float32 rounding (QuantizationGrid::frame_point): allow rounding slack only.
  const double tolerance =
      bounds ? 1e-9 * bounds->size().maxCoeff() + QuantizationGrid::of(*bounds, options.quantization_bits).float_slack()
             : 0.0;
  struct Found {
    std::size_t non_finite, outside, bad_triangle;
    Aabb box = Aabb::empty();
  };
  std::vector<Found> found(vertex_blocks + triangle_blocks, Found{nv, nv, nf});
  parallel_for(vertex_blocks + triangle_blocks, threads, [&](int item) {
    Found& f = found[item];
    if (item < vertex_blocks) {
      const std::size_t end = std::min(nv, (item + 1) * kBlock);
      for (std::size_t v = item * kBlock; v < end; ++v) {
        const Vec3& p = mesh.vertices[v];
        if (!p.allFinite()) {
          f.non_finite = v;
          return;
        }
        if (bounds) {
          if (f.outside == nv && ((p.array() < bounds->min.array() - tolerance).any() ||
                                  (p.array() > bounds->max.array() + tolerance).any())) {
            f.outside = v;
          }
        } else {
          f.box.merge(p);
        }
      }
    } else {
      const std::size_t block = item - vertex_blocks;
      const std::size_t end = std::min(nf, (block + 1) * kBlock);
      for (std::size_t t = block * kBlock; t < end; ++t) {
        const Triangle& tri = mesh.triangles[t];
        if (tri[0] >= nv || tri[1] >= nv || tri[2] >= nv) {
          f.bad_triangle = t;
          return;
        }
      }
    }
  });
  Found first{nv, nv, nf};
  for (const Found& f : found) {
    first.non_finite = std::min(first.non_finite, f.non_finite);
    first.outside = std::min(first.outside, f.outside);
    first.bad_triangle = std::min(first.bad_triangle, f.bad_triangle);
    first.box.merge(f.box);
  }
  if (first.non_finite < nv) {
    throw InvalidInput("vertices", "vertex " + std::to_string(first.non_finite) +
                                       " is not finite: " + format_point(mesh.vertices[first.non_finite]));
  }
  if (first.bad_triangle < nf) {
    for (std::uint32_t i : mesh.triangles[first.bad_triangle]) {
      if (i >= nv) {
        throw InvalidInput("triangles", "triangle " + std::to_string(first.bad_triangle) + " uses vertex " +
                                            std::to_string(i) + " but the mesh has " + std::to_string(nv) +
                                            " vertices");
      }
    }
  }
  if (bounds) {
    if (first.outside < nv) {
      throw InvalidInput("quantization_bounds", "vertex " + std::to_string(first.outside) + " at " +
                                                    format_point(mesh.vertices[first.outside]) +
                                                    " lies outside quantization_bounds min " +
                                                    format_point(bounds->min) + " max " + format_point(bounds->max) +
                                                    "; use a box that contains every frame (e.g. the job's bounds)");
    }
    return {bounds->min, bounds->size().maxCoeff()};
  }
  const Vec3 lo = nv > 0 ? first.box.min : Vec3::Zero();
  double range = nv > 0 ? first.box.size().maxCoeff() : 0.0;
  if (!(range > 0.0)) range = std::max(1.0, lo.cwiseAbs().maxCoeff()) * 1e-6;  // all vertices coincide
  return {lo, range};
}

// `clamp`: box to clamp values into (vertices within the tolerance outside the quantization box).
int add_float3_attribute(draco::Mesh& out, draco::GeometryAttribute::Type type, const std::vector<Vec3>& values,
                         const std::optional<Aabb>& clamp) {
  auto attribute = std::make_unique<draco::PointAttribute>();
  attribute->Init(type, 3, draco::DT_FLOAT32, false, values.size());
  std::vector<float> data(values.size() * 3);
  for (std::size_t v = 0; v < values.size(); ++v) {
    Vec3 p = values[v];
    if (clamp) p = p.cwiseMax(clamp->min).cwiseMin(clamp->max);
    for (int c = 0; c < 3; ++c) data[3 * v + c] = static_cast<float>(p[c]);
  }
  if (!data.empty()) attribute->buffer()->Write(0, data.data(), data.size() * sizeof(float));
  return out.AddAttribute(std::move(attribute));
}

// Mesh::attributes as Draco GENERIC float32 attributes (not quantized: the values survive bit for bit), each named
// by its attribute metadata entry kAttributeNameKey.
constexpr const char* kAttributeNameKey = "name";

void add_named_attributes(draco::Mesh& out, const Mesh& mesh) {
  check_attributes(mesh);
  for (const Attribute& a : mesh.attributes) {
    auto attribute = std::make_unique<draco::PointAttribute>();
    attribute->Init(draco::GeometryAttribute::GENERIC, static_cast<std::int8_t>(a.components), draco::DT_FLOAT32, false,
                    mesh.vertices.size());
    if (!a.values.empty()) attribute->buffer()->Write(0, a.values.data(), a.values.size() * sizeof(float));
    const int id = out.AddAttribute(std::move(attribute));
    auto metadata = std::make_unique<draco::AttributeMetadata>();
    metadata->AddEntryString(kAttributeNameKey, a.name);
    out.AddAttributeMetadata(id, std::move(metadata));
  }
}

}  // namespace

QuantizationGrid quantization_grid(const Mesh& mesh, const DracoOptions& options) {
  return quantization_grid(mesh, options, 1);
}

QuantizationGrid quantization_grid(const Mesh& mesh, const DracoOptions& options, int threads) {
  const QuantizationBox q = checked_box(mesh, options, threads);
  QuantizationGrid grid;
  for (int c = 0; c < 3; ++c) grid.origin[c] = static_cast<float>(q.origin[c]);
  grid.range = static_cast<float>(q.range);
  grid.bits = options.quantization_bits;
  if (options.quantization_bounds) grid.box = *options.quantization_bounds;
  return grid;
}

double draco_max_error(const Aabb& box, int quantization_bits) {
  const double range = box.size().maxCoeff();
  const double step = range / (std::ldexp(1.0, quantization_bits) - 1.0);
  // Draco quantizes and dequantizes in float32: allow a few float ulps of the coordinates' magnitude.
  const double magnitude = std::max(box.min.cwiseAbs().maxCoeff(), box.max.cwiseAbs().maxCoeff()) + range;
  return 0.5 * step * std::sqrt(3.0) + 8.0 * std::numeric_limits<float>::epsilon() * magnitude;
}

namespace {

// Draco's SetAttributeExplicitQuantization keeps the origin and range as option strings written by std::to_string,
// i.e. rounded to 6 decimals (an origin of -1.7510416 becomes -1.751042, and a range below 5e-7 becomes 0), so the
// frame's grid would not be the job's (docs/ALGORITHMS.md §5 "Frames"). The same options, rewritten with 9
// significant digits, which strtof reads back as the very same floats.
void set_explicit_quantization(draco::Encoder& encoder, int bits, const float origin[3], float range) {
  encoder.SetAttributeExplicitQuantization(draco::GeometryAttribute::POSITION, bits, 3, origin, range);
  const draco::Options* set = encoder.options().FindAttributeOptions(draco::GeometryAttribute::POSITION);
  draco::Options exact = set ? *set : draco::Options();
  char text[128];
  std::snprintf(text, sizeof text, "%.9g %.9g %.9g", static_cast<double>(origin[0]), static_cast<double>(origin[1]),
                static_cast<double>(origin[2]));
  exact.SetString("quantization_origin", text);
  std::snprintf(text, sizeof text, "%.9g", static_cast<double>(range));
  exact.SetString("quantization_range", text);
  encoder.options().SetAttributeOptions(draco::GeometryAttribute::POSITION, exact);
}

}  // namespace

struct DracoEncoder::State {
  draco::Mesh mesh;
  draco::Encoder encoder;
};

DracoEncoder::DracoEncoder(const Mesh& mesh, const DracoOptions& options) : state_(std::make_unique<State>()) {
  const QuantizationBox q = checked_box(mesh, options, 1);
  const bool encode_normals = options.normals && !mesh.normals.empty();

  draco::Mesh& out = state_->mesh;
  if (!mesh.triangles.empty()) {
    out.set_num_points(static_cast<draco::PointIndex::ValueType>(mesh.vertices.size()));
    add_float3_attribute(out, draco::GeometryAttribute::POSITION, mesh.vertices, options.quantization_bounds);
    if (encode_normals) add_float3_attribute(out, draco::GeometryAttribute::NORMAL, mesh.normals, std::nullopt);
    add_named_attributes(out, mesh);
  }
  // else: an empty frame. Draco's decoder rejects a mesh whose attributes have no values, so an empty mesh is
  // written without points or attributes (sequential coder; edgebreaker refuses meshes without faces).
  out.SetNumFaces(mesh.triangles.size());
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    const Triangle& tri = mesh.triangles[t];
    draco::Mesh::Face face;
    for (int c = 0; c < 3; ++c) face[c] = draco::PointIndex(tri[c]);
    out.SetFace(draco::FaceIndex(static_cast<std::uint32_t>(t)), face);
  }

  draco::Encoder& encoder = state_->encoder;
  const float origin[3] = {static_cast<float>(q.origin.x()), static_cast<float>(q.origin.y()),
                           static_cast<float>(q.origin.z())};
  set_explicit_quantization(encoder, options.quantization_bits, origin, static_cast<float>(q.range));
  if (encode_normals) encoder.SetAttributeQuantization(draco::GeometryAttribute::NORMAL, options.normal_bits);
  encoder.SetSpeedOptions(options.speed, options.speed);
  if (mesh.triangles.empty()) encoder.SetEncodingMethod(draco::MESH_SEQUENTIAL_ENCODING);
}

DracoEncoder::~DracoEncoder() = default;

std::string DracoEncoder::encode() {
  draco::EncoderBuffer buffer;
  const draco::Status status = state_->encoder.EncodeMeshToBuffer(state_->mesh, &buffer);
  if (!status.ok()) throw Internal("Draco encoder failed: " + status.error_msg_string());
  return std::string(buffer.data(), buffer.size());
}

std::string encode_draco(const Mesh& mesh, const DracoOptions& options) { return DracoEncoder(mesh, options).encode(); }

namespace {

// Integer or floating-point components. Draco converts DT_BOOL values by loading the stored bytes as `bool`,
// which is undefined behaviour for bytes other than 0 and 1; a position or normal is never boolean anyway.
bool numeric_attribute(const draco::PointAttribute& attribute) {
  const draco::DataType type = attribute.data_type();
  return type >= draco::DT_INT8 && type <= draco::DT_FLOAT64;
}

// Draco's own decoder, unbounded (see decode_draco).
Mesh decode_draco_stream(std::string_view bytes) {
  draco::DecoderBuffer buffer;
  buffer.Init(bytes.data(), bytes.size());
  draco::Decoder decoder;
  auto decoded = decoder.DecodeMeshFromBuffer(&buffer);
  if (!decoded.ok()) {
    throw InvalidInput("frame", "not a Draco triangle mesh (" + decoded.status().error_msg_string() + ")");
  }
  const std::unique_ptr<draco::Mesh> in = std::move(decoded).value();
  Mesh mesh;
  const std::size_t np = in->num_points();
  const draco::PointAttribute* position = in->GetNamedAttribute(draco::GeometryAttribute::POSITION);
  if (np > 0 || in->num_faces() > 0) {
    if (position == nullptr || position->num_components() < 3) {
      throw InvalidInput("frame", "Draco mesh has no 3D POSITION attribute");
    }
    if (!numeric_attribute(*position)) {
      throw InvalidInput("frame", "Draco POSITION attribute is not numeric (data type " +
                                      std::to_string(static_cast<int>(position->data_type())) + ")");
    }
  }
  mesh.vertices.resize(np);
  std::array<float, 3> value{};
  for (std::size_t p = 0; p < np; ++p) {
    if (!position->ConvertValue<float, 3>(position->mapped_index(draco::PointIndex(static_cast<std::uint32_t>(p))),
                                          value.data())) {
      throw InvalidInput("frame", "Draco POSITION attribute is unreadable at point " + std::to_string(p));
    }
    mesh.vertices[p] = Vec3(value[0], value[1], value[2]);
  }
  const draco::PointAttribute* normal = in->GetNamedAttribute(draco::GeometryAttribute::NORMAL);
  if (normal != nullptr && normal->num_components() >= 3 && np > 0) {
    if (!numeric_attribute(*normal)) {
      throw InvalidInput("frame", "Draco NORMAL attribute is not numeric (data type " +
                                      std::to_string(static_cast<int>(normal->data_type())) + ")");
    }
    mesh.normals.resize(np);
    for (std::size_t p = 0; p < np; ++p) {
      if (!normal->ConvertValue<float, 3>(normal->mapped_index(draco::PointIndex(static_cast<std::uint32_t>(p))),
                                          value.data())) {
        throw InvalidInput("frame", "Draco NORMAL attribute is unreadable at point " + std::to_string(p));
      }
      Vec3 n(value[0], value[1], value[2]);
      const double len = n.norm();
      mesh.normals[p] = len > 0.0 ? Vec3(n / len) : n;
    }
  }
  // GENERIC attributes named by metadata (add_named_attributes) of 1 to 4 components: Mesh::attributes.
  for (int id = 0; id < in->num_attributes() && np > 0; ++id) {
    const draco::PointAttribute* generic = in->attribute(id);
    const draco::AttributeMetadata* metadata = in->GetAttributeMetadataByAttributeId(id);
    std::string name;
    if (generic == nullptr || generic->attribute_type() != draco::GeometryAttribute::GENERIC || metadata == nullptr ||
        !metadata->GetEntryString(kAttributeNameKey, &name) || name.empty() || !numeric_attribute(*generic) ||
        generic->num_components() < 1 || generic->num_components() > Attribute::kMaxComponents) {
      continue;
    }
    Attribute attribute{name, generic->num_components(), std::vector<float>(np * generic->num_components())};
    for (std::size_t p = 0; p < np; ++p) {
      if (!generic->ConvertValue<float>(generic->mapped_index(draco::PointIndex(static_cast<std::uint32_t>(p))),
                                        generic->num_components(), &attribute.values[p * generic->num_components()])) {
        throw InvalidInput("frame", "Draco attribute " + name + " is unreadable at point " + std::to_string(p));
      }
    }
    mesh.attributes.push_back(std::move(attribute));
  }
  mesh.triangles.resize(in->num_faces());
  for (std::uint32_t f = 0; f < in->num_faces(); ++f) {
    const draco::Mesh::Face& face = in->face(draco::FaceIndex(f));
    for (int c = 0; c < 3; ++c) {
      const std::uint32_t v = face[c].value();
      if (v >= np) throw InvalidInput("frame", "Draco face " + std::to_string(f) + " references a missing point");
      mesh.triangles[f][c] = v;
    }
  }
  return mesh;
}

constexpr std::size_t kDracoBudgetFloor = std::size_t{64} << 20;
constexpr std::size_t kDracoBytesPerInputByte = 4096;
constexpr std::size_t kDracoBytesPerTriangle = 256;

}  // namespace

Mesh decode_draco(std::string_view bytes, const MeshReadLimits& limits) {
  const std::size_t by_size = kDracoBytesPerInputByte * bytes.size();
  const std::size_t by_limit =
      kDracoBytesPerTriangle * static_cast<std::size_t>(std::max<std::int64_t>(limits.max_triangles, 0));
  const std::size_t budget = kDracoBudgetFloor + std::min(by_size, by_limit);
  {
    AllocationBudget scope(budget);
    try {
      return decode_draco_stream(bytes);
    } catch (const std::bad_alloc&) {
      if (!scope.exhausted()) throw;
    }
  }
  const std::string needs = "decoding this " + std::to_string(bytes.size()) + "-byte Draco stream needs more than " +
                            std::to_string(budget >> 20) + " MiB";
  if (by_limit < by_size) {
    throw ResourceLimit("max_triangles", needs + ", more than a mesh of max_triangles (" +
                                             std::to_string(limits.max_triangles) + ") triangles may take");
  }
  throw InvalidInput("frame", needs + " (" + std::to_string(kDracoBytesPerInputByte) +
                                  " bytes per input byte are allowed): it declares far more elements than it holds");
}

// --- Pieces -------------------------------------------------------------------------------------------------------

namespace {

// Returns the attribute's id.
template <class T>
int add_integer_attribute(draco::Mesh& out, draco::GeometryAttribute::Type type, draco::DataType data_type,
                          int components, const std::vector<T>& values) {
  auto attribute = std::make_unique<draco::PointAttribute>();
  const std::size_t count = values.size() / components;
  attribute->Init(type, components, data_type, false, count);
  if (!values.empty()) attribute->buffer()->Write(0, values.data(), values.size() * sizeof(T));
  return out.AddAttribute(std::move(attribute));
}

bool unsigned_attribute(const draco::PointAttribute& attribute) {
  const draco::DataType type = attribute.data_type();
  return type == draco::DT_UINT8 || type == draco::DT_UINT16 || type == draco::DT_UINT32;
}

}  // namespace

namespace {

// The vertices of an edgebreaker stream as Draco's bitstream 2.2 states them ahead of its connectivity (the
// "DRACO" header, version, mesh and edgebreaker bytes, flags without metadata, the traversal byte, then a varint):
// the points its decoder makes when every attribute is per vertex, as a piece's are. Nullopt for any other stream.
std::optional<std::size_t> edgebreaker_vertices(std::string_view bytes) {
  constexpr unsigned char kHeader[] = {'D', 'R', 'A', 'C', 'O', 2, 2, 1, 1, 0, 0};
  if (bytes.size() < sizeof kHeader + 2 || std::memcmp(bytes.data(), kHeader, sizeof kHeader) != 0) return std::nullopt;
  std::size_t value = 0;
  for (std::size_t at = sizeof kHeader + 1, shift = 0; at < bytes.size() && shift < 35; ++at, shift += 7) {
    const auto byte = static_cast<unsigned char>(bytes[at]);
    value |= static_cast<std::size_t>(byte & 0x7F) << shift;
    if ((byte & 0x80) == 0) return value;
  }
  return std::nullopt;
}

}  // namespace

std::string encode_draco_piece(const QuantizedPiece& piece, int grid_bits, const DracoOptions& options,
                               DracoPieceInfo* info) {
  // A piece without triangles is written without points, as encode_draco writes an empty frame.
  const std::size_t nv = piece.triangles.empty() ? 0 : piece.positions.size();
  draco::Mesh out;
  out.set_num_points(static_cast<draco::PointIndex::ValueType>(nv));
  DracoPieceInfo ids;
  if (nv > 0 && grid_bits <= 16) {
    std::vector<std::uint16_t> values(3 * nv);
    for (std::size_t v = 0; v < nv; ++v) {
      for (int c = 0; c < 3; ++c) values[3 * v + c] = static_cast<std::uint16_t>(piece.positions[v][c]);
    }
    ids.position = add_integer_attribute(out, draco::GeometryAttribute::POSITION, draco::DT_UINT16, 3, values);
  } else if (nv > 0) {
    std::vector<std::uint32_t> values(3 * nv);
    for (std::size_t v = 0; v < nv; ++v) {
      for (int c = 0; c < 3; ++c) values[3 * v + c] = piece.positions[v][c];
    }
    ids.position = add_integer_attribute(out, draco::GeometryAttribute::POSITION, draco::DT_UINT32, 3, values);
  }
  if (nv > 0 && std::any_of(piece.seam_tags.begin(), piece.seam_tags.end(), [](std::uint16_t t) { return t != 0; })) {
    ids.seam = add_integer_attribute(out, draco::GeometryAttribute::GENERIC, draco::DT_UINT16, 1, piece.seam_tags);
  }
  const bool encode_normals = nv > 0 && options.normals && !piece.normals.empty();
  if (encode_normals) {
    ids.normal = add_float3_attribute(out, draco::GeometryAttribute::NORMAL, piece.normals, std::nullopt);
  }
  for (std::size_t a = 0; a < piece.attributes.size() && nv > 0; ++a) {
    const Attribute& attribute = piece.attributes[a];
    if (attribute.components < 1 || attribute.components > Attribute::kMaxComponents ||
        attribute.values.size() != nv * static_cast<std::size_t>(attribute.components)) {
      throw InvalidInput("attributes", "a piece's attribute " + attribute.name + " does not hold 1 to " +
                                           std::to_string(Attribute::kMaxComponents) + " values per vertex");
    }
    const int id = add_integer_attribute(out, draco::GeometryAttribute::GENERIC, draco::DT_FLOAT32,
                                         attribute.components, attribute.values);
    if (a == 0) ids.attributes = id;
  }
  out.SetNumFaces(piece.triangles.size());
  for (std::size_t t = 0; t < piece.triangles.size(); ++t) {
    draco::Mesh::Face face;
    for (int c = 0; c < 3; ++c) face[c] = draco::PointIndex(piece.triangles[t][c]);
    out.SetFace(draco::FaceIndex(static_cast<std::uint32_t>(t)), face);
  }
  draco::Encoder encoder;
  if (encode_normals) encoder.SetAttributeQuantization(draco::GeometryAttribute::NORMAL, options.normal_bits);
  encoder.SetSpeedOptions(options.speed, options.speed);
  if (piece.triangles.empty()) encoder.SetEncodingMethod(draco::MESH_SEQUENTIAL_ENCODING);
  draco::EncoderBuffer buffer;
  draco::Status status = encoder.EncodeMeshToBuffer(out, &buffer);
  if (!status.ok()) throw Internal("Draco encoder failed on a piece: " + status.error_msg_string());
  std::optional<std::size_t> points =
      nv == 0 ? std::optional<std::size_t>(0) : edgebreaker_vertices(std::string_view(buffer.data(), buffer.size()));
  if (info && !points) {  // a bitstream we do not parse: Draco's own count, which walks every vertex's fan again
    encoder.SetTrackEncodedProperties(true);
    buffer.Clear();
    status = encoder.EncodeMeshToBuffer(out, &buffer);
    if (!status.ok()) throw Internal("Draco encoder failed on a piece: " + status.error_msg_string());
    points = encoder.num_encoded_points();
  }
  if (info) {
    *info = ids;
    info->points = *points;
  }
  return std::string(buffer.data(), buffer.size());
}

QuantizedPiece decode_draco_piece(std::string_view bytes, int grid_bits, DracoPieceInfo* info) {
  draco::DecoderBuffer buffer;
  buffer.Init(bytes.data(), bytes.size());
  draco::Decoder decoder;
  auto decoded = decoder.DecodeMeshFromBuffer(&buffer);
  if (!decoded.ok()) {
    throw InvalidInput("frame", "a piece is not a Draco triangle mesh (" + decoded.status().error_msg_string() + ")");
  }
  const std::unique_ptr<draco::Mesh> in = std::move(decoded).value();
  const std::size_t np = in->num_points();
  if (info) {
    *info = DracoPieceInfo{};
    info->points = np;
  }
  QuantizedPiece piece;
  if (np == 0 && in->num_faces() == 0) return piece;
  const draco::PointAttribute* position = in->GetNamedAttribute(draco::GeometryAttribute::POSITION);
  if (position == nullptr || position->num_components() != 3 || !unsigned_attribute(*position)) {
    throw InvalidInput("frame", "a Draco piece has no integer 3D POSITION attribute");
  }
  if (info) info->position = static_cast<int>(position->unique_id());
  const std::uint32_t max_value = (std::uint32_t{1} << grid_bits) - 1u;
  piece.positions.resize(np);
  for (std::size_t p = 0; p < np; ++p) {
    auto& q = piece.positions[p];
    if (!position->ConvertValue<std::uint32_t, 3>(
            position->mapped_index(draco::PointIndex(static_cast<std::uint32_t>(p))), q.data()) ||
        q[0] > max_value || q[1] > max_value || q[2] > max_value) {
      throw InvalidInput("frame",
                         "a Draco piece's POSITION is unreadable or off the grid at point " + std::to_string(p));
    }
  }
  piece.seam_tags.assign(np, 0);
  const draco::PointAttribute* tags = nullptr;
  for (int id = 0; id < in->num_attributes(); ++id) {
    const draco::PointAttribute* generic = in->attribute(id);
    if (generic == nullptr || generic->attribute_type() != draco::GeometryAttribute::GENERIC) continue;
    if (unsigned_attribute(*generic)) {
      if (tags != nullptr || generic->num_components() != 1) {
        throw InvalidInput("frame", "a Draco piece's seam tags are not one unsigned integer per point");
      }
      tags = generic;
      continue;
    }
    if (generic->data_type() != draco::DT_FLOAT32 || generic->num_components() < 1 ||
        generic->num_components() > Attribute::kMaxComponents) {
      throw InvalidInput("frame", "a Draco piece's attribute " + std::to_string(id) + " is not 1 to " +
                                      std::to_string(Attribute::kMaxComponents) + " floats per point");
    }
    if (info && piece.attributes.empty()) info->attributes = static_cast<int>(generic->unique_id());
    const int k = generic->num_components();
    Attribute& attribute = piece.attributes.emplace_back(Attribute{"", k, std::vector<float>(np * k)});
    for (std::size_t p = 0; p < np; ++p) {
      if (!generic->ConvertValue<float>(generic->mapped_index(draco::PointIndex(static_cast<std::uint32_t>(p))), k,
                                        &attribute.values[p * k])) {
        throw InvalidInput("frame", "a Draco piece's attribute " + std::to_string(id) + " is unreadable at point " +
                                        std::to_string(p));
      }
    }
  }
  if (tags != nullptr) {
    if (info) info->seam = static_cast<int>(tags->unique_id());
    for (std::size_t p = 0; p < np; ++p) {
      if (!tags->ConvertValue<std::uint16_t, 1>(tags->mapped_index(draco::PointIndex(static_cast<std::uint32_t>(p))),
                                                &piece.seam_tags[p])) {
        throw InvalidInput("frame", "a Draco piece's seam tag is unreadable at point " + std::to_string(p));
      }
    }
  }
  const draco::PointAttribute* normal = in->GetNamedAttribute(draco::GeometryAttribute::NORMAL);
  if (normal != nullptr) {
    if (normal->num_components() != 3 || !numeric_attribute(*normal)) {
      throw InvalidInput("frame", "a Draco piece's NORMAL attribute is not numeric 3D");
    }
    if (info) info->normal = static_cast<int>(normal->unique_id());
    piece.normals.resize(np);
    std::array<float, 3> value{};
    for (std::size_t p = 0; p < np; ++p) {
      if (!normal->ConvertValue<float, 3>(normal->mapped_index(draco::PointIndex(static_cast<std::uint32_t>(p))),
                                          value.data())) {
        throw InvalidInput("frame", "a Draco piece's NORMAL is unreadable at point " + std::to_string(p));
      }
      const Vec3 n(value[0], value[1], value[2]);
      const double len = n.norm();
      piece.normals[p] = len > 0.0 ? Vec3(n / len) : n;
    }
  }
  piece.triangles.resize(in->num_faces());
  for (std::uint32_t f = 0; f < in->num_faces(); ++f) {
    const draco::Mesh::Face& face = in->face(draco::FaceIndex(f));
    for (int c = 0; c < 3; ++c) {
      const std::uint32_t v = face[c].value();
      if (v >= np) throw InvalidInput("frame", "a Draco piece's face " + std::to_string(f) + " uses a missing point");
      piece.triangles[f][c] = v;
    }
  }
  return piece;
}

}  // namespace surfacer
