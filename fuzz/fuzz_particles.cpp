// Fuzz target: particle frames, every reader in core/particle_io (from memory; gzip is detected by its magic bytes
// in every format) and the server's decoding of uploaded and inline frames (wire/particle_frames).
// Input: one selector byte, then the file or upload bytes:
//   0 xyz/csv text, 1 PLY, 2 VTK legacy, 3 VTU, 4 raw float32, 5 BGEO, 9 JSON (core::parse_particles; VTK also
//   as a mesh with its surface cells, core::parse_vtk_mesh)
//   6 upload of float32 x y z records, 7 of x y z r records (with_radius), 8 a serialized v1::ParticleFrame with
//   inline positions/radii (wire::summarize_particle_frame + load_particle_frame)
// Expected failures are surfacer::Error; anything else escaping, a crash, UB or a violated property is a bug.
#include <google/protobuf/stubs/logging.h>

#include <cmath>
#include <cstdint>
#include <memory>
#include <string>

#include "core/particles/particle_io.h"
#include "core/util/errors.h"
#include "fuzz/fuzz_input.h"
#include "surfacer/v1/surfacer.pb.h"
#include "wire/particle_frames.h"
#include "wire/uploads.h"

namespace surfacer::fuzz {
namespace {

constexpr std::int64_t kMaxParticles = 1 << 20;

void check_frame(const ParticleFrame& frame) {
  require(frame.radii.empty() || frame.radii.size() == frame.positions.size(), "radii count != particle count");
  for (const Vec3& p : frame.positions) require(p.allFinite(), "reader returned a non-finite position");
}

void decode_server_frame(const v1::ParticleFrame& frame, const wire::UploadLookup& uploads) {
  const wire::ParticleSummary summary = wire::summarize_particle_frame(frame, "frame", uploads, kMaxParticles);
  const wire::ParticleData data = wire::load_particle_frame(frame, "frame", uploads, kMaxParticles);
  require(summary.count > 0 && summary.count <= kMaxParticles, "particle count out of range");
  require(static_cast<std::int64_t>(data.positions.size()) == summary.count, "load and summarize disagree on count");
  require(data.radii.empty() || data.radii.size() == data.positions.size(), "radii count != particle count");
  for (const Vec3& p : data.positions) {
    require(p.allFinite(), "non-finite position accepted");
    require(summary.bounds.contains(p), "a particle lies outside the summary bounds");
  }
  for (double r : data.radii) {
    require(r > 0.0 && std::isfinite(r), "radius <= 0 or non-finite accepted");
    require(r <= summary.max_radius, "a radius exceeds the summary's max_radius");
  }
}

}  // namespace
}  // namespace surfacer::fuzz

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace surfacer;
  if (size == 0) return 0;
  const std::uint8_t selector = data[0] % 10;
  const std::string_view bytes = fuzz::as_view(data + 1, size - 1);
  try {
    if (selector <= 5 || selector == 9) {
      static constexpr ParticleFormat kFormats[] = {ParticleFormat::kXyz, ParticleFormat::kPly, ParticleFormat::kVtk,
                                                    ParticleFormat::kVtu, ParticleFormat::kBin, ParticleFormat::kBgeo};
      const ParticleFormat format = selector == 9 ? ParticleFormat::kJson : kFormats[selector];
      fuzz::check_frame(parse_particles(bytes, format, "fuzz"));
      if (format == ParticleFormat::kVtk || format == ParticleFormat::kVtu) {
        const Mesh mesh = parse_vtk_mesh(bytes, format, "fuzz");
        for (const Triangle& t : mesh.triangles) {
          for (const std::uint32_t v : t) fuzz::require(v < mesh.vertices.size(), "a triangle names a missing vertex");
        }
        fuzz::require(mesh.normals.empty() || mesh.normals.size() == mesh.vertices.size(), "normals count");
      }
    } else if (selector <= 7) {
      wire::MemoryUploads uploads;
      auto blob = std::make_shared<wire::UploadBlob>();
      blob->name = "fuzz.bin";
      blob->bytes = std::string(bytes);
      v1::ParticleFrame frame;
      uploads.put("u-0000000000000001", blob);
      frame.set_upload_id("u-0000000000000001");
      frame.set_with_radius(selector == 7);
      fuzz::decode_server_frame(frame, uploads);
    } else {
      // No "invalid UTF-8" log line per input.
      [[maybe_unused]] static auto* const previous_handler = google::protobuf::SetLogHandler(nullptr);
      v1::ParticleFrame frame;
      if (!frame.ParseFromArray(bytes.data(), static_cast<int>(bytes.size()))) return 0;
      const wire::MemoryUploads uploads;  // empty: an upload_id must be rejected as unknown
      fuzz::decode_server_frame(frame, uploads);
    }
  } catch (const Error& e) {
    fuzz::require(e.what()[0] != '\0', "an Error without a message");
  }
  return 0;
}
