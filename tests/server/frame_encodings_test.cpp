// The frame encodings through real loopback servers: pieced frames (encoded as items on the worker pool) are the
// same bytes whatever the number of workers, and their checks the same figures.
#include <gtest/gtest.h>

#include "core/mesh/frame_codec.h"
#include "core/mesh/mesh_checks.h"
#include "tests/server/test_client.h"
#include "tests/support/mesh_expectations.h"
#include "wire/output.h"

namespace surfacer::testing {
namespace {

std::string frame_bytes(int workers, const v1::JobSpec& spec, v1::FrameStats* stats) {
  server::ServerOptions options = LoopbackServer::default_options();
  options.workers = workers;
  LoopbackServer s(options);
  std::string id;
  EXPECT_TRUE(submit(*s.stub, spec, &id).ok());
  const WatchResult result = watch_job(*s.stub, id);
  EXPECT_EQ(result.integrity_error, "");
  if (result.frames.size() != 1) {
    ADD_FAILURE() << "expected one frame, got " << result.frames.size();
    return "";
  }
  *stats = result.frames.begin()->second.header.stats();
  return result.frames.begin()->second.bytes;
}

TEST(FrameEncodings, PiecedFramesAreTheSameBytesOnAnyNumberOfWorkers) {
  const v1::Scene gyroid = scene_from_json(R"({"root": {"intersection": {"children": [
      {"gyroid": {"period": 1, "thickness": 0.12}}, {"sphere": {"radius": 1.5}}]}}})");
  for (int cells : {48, 160}) {  // one piece, several
    for (v1::MeshEncoding encoding : {v1::MESH_ENCODING_DRACO_PIECES, v1::MESH_ENCODING_MESHOPT}) {
      SCOPED_TRACE(v1::MeshEncoding_Name(encoding) + " at " + std::to_string(cells) + " cells");
      v1::JobSpec spec = isosurface_spec({gyroid}, cells);
      spec.mutable_isosurface()->set_method(v1::POLYGONIZER_CUBES);
      spec.mutable_output()->set_encoding(encoding);
      v1::FrameStats one_stats;
      const std::string one = frame_bytes(1, spec, &one_stats);
      for (int workers : {2, 3}) {
        v1::FrameStats stats;
        EXPECT_EQ(frame_bytes(workers, spec, &stats), one) << workers << " workers";
        EXPECT_EQ(stats.check().SerializeAsString(), one_stats.check().SerializeAsString()) << workers << " workers";
      }
      const Mesh mesh = decode_frame(one, *wire::frame_codec(encoding), 2);
      EXPECT_EQ(static_cast<std::int64_t>(mesh.triangles.size()), one_stats.triangles());
      EXPECT_TRUE(mesh_has(check_mesh(mesh), kClosedManifold));
    }
  }
}

}  // namespace
}  // namespace surfacer::testing
