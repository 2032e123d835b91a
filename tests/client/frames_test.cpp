// Frame reassembly and verification, output files, stats.csv, job specs from JSON, health statuses.
#include <gtest/gtest.h>
#include <zlib.h>

#include <filesystem>
#include <limits>
#include <sstream>

#include "client/exit_codes.h"
#include "client/frame_assembler.h"
#include "client/frame_writer.h"
#include "client/health.h"
#include "client/job_spec.h"
#include "core/mesh/frame_codec.h"
#include "core/mesh/mesh_io.h"
#include "core/util/crc32.h"
#include "tests/support/files.h"
#include "tests/support/test_meshes.h"
#include "wire/output.h"

namespace surfacer::client {
namespace {

namespace fs = std::filesystem;
using surfacer::testing::fresh_temp_dir;
using surfacer::testing::read_file;
using surfacer::testing::write_file;

// A frame of `bytes` cut into chunks of `chunk_size`, as the server sends it.
struct Events {
  v1::FrameHeader header;
  std::vector<v1::FrameChunk> chunks;
};

Events make_frame(int index, const std::string& bytes, std::size_t chunk_size,
                  v1::MeshEncoding encoding = v1::MESH_ENCODING_DRACO) {
  Events e;
  e.header.set_frame_index(index);
  e.header.set_encoding(encoding);
  e.header.set_total_bytes(bytes.size());
  e.header.set_crc32(crc32_of(bytes));
  e.header.mutable_stats()->set_triangles(12);
  int n = 0;
  for (std::size_t pos = 0; pos < bytes.size(); pos += chunk_size, ++n) {
    v1::FrameChunk c;
    c.set_frame_index(index);
    c.set_chunk_index(n);
    c.set_data(bytes.substr(pos, chunk_size));
    c.set_crc32(crc32_of(c.data()));
    e.chunks.push_back(c);
  }
  if (!e.chunks.empty()) e.chunks.back().set_last(true);
  e.header.set_num_chunks(n);
  return e;
}

std::optional<ReceivedFrame> feed(FrameAssembler& a, const Events& e) {
  std::optional<ReceivedFrame> frame = a.on_header(e.header);
  for (const auto& c : e.chunks) {
    EXPECT_FALSE(frame) << "frame completed before its last chunk";
    frame = a.on_chunk(c);
  }
  return frame;
}

ExitCode error_code_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const CliError& e) {
    return e.code();
  }
  return ExitCode::kSuccess;
}

TEST(Crc32, MatchesZlibCheckValue) {
  EXPECT_EQ(crc32_of("123456789"), 0xCBF43926u);  // the standard CRC-32 check value
  EXPECT_EQ(crc32_of(""), 0u);
}

// A frame's CRC from its chunks' (what a server computes once): the same as over the whole, for every split.
TEST(Crc32, ChunksConcatenateIntoTheWhole) {
  std::string bytes(5000, '\0');
  for (std::size_t i = 0; i < bytes.size(); ++i) bytes[i] = static_cast<char>(i * 31 + i / 7);
  for (std::size_t chunk : {std::size_t{1}, std::size_t{3}, std::size_t{1000}, std::size_t{4096}, bytes.size()}) {
    std::uint32_t crc = 0;
    for (std::size_t at = 0; at < bytes.size(); at += chunk) {
      const std::string_view piece = std::string_view(bytes).substr(at, chunk);
      crc = crc32_concat(crc, crc32_of(piece), piece.size());
    }
    EXPECT_EQ(crc, crc32_of(bytes)) << "chunks of " << chunk;
  }
  EXPECT_EQ(crc32_concat(crc32_of("12345"), crc32_of(""), 0), crc32_of("12345"));
}

TEST(FrameAssembler, ReassemblesChunksInOrder) {
  std::string bytes(2500, '\0');
  for (std::size_t i = 0; i < bytes.size(); ++i) bytes[i] = static_cast<char>(i * 7);
  FrameAssembler a;
  auto frame = feed(a, make_frame(4, bytes, 1000));
  ASSERT_TRUE(frame);
  EXPECT_EQ(frame->index, 4);
  EXPECT_EQ(frame->bytes, bytes);
  EXPECT_EQ(frame->stats.triangles(), 12);
  EXPECT_TRUE(a.idle());
}

TEST(FrameAssembler, InterleavedFramesAndUnspecifiedEncoding) {
  FrameAssembler a;
  Events f1 = make_frame(1, std::string(30, 'a'), 10, v1::MESH_ENCODING_UNSPECIFIED);
  Events f2 = make_frame(2, std::string(20, 'b'), 10, v1::MESH_ENCODING_PLY);
  EXPECT_FALSE(a.on_header(f1.header));
  EXPECT_FALSE(a.on_header(f2.header));
  EXPECT_FALSE(a.on_chunk(f1.chunks[0]));
  EXPECT_FALSE(a.on_chunk(f2.chunks[0]));
  auto done2 = a.on_chunk(f2.chunks[1]);
  ASSERT_TRUE(done2);
  EXPECT_EQ(done2->encoding, v1::MESH_ENCODING_PLY);
  EXPECT_FALSE(a.on_chunk(f1.chunks[1]));
  auto done1 = a.on_chunk(f1.chunks[2]);
  ASSERT_TRUE(done1);
  EXPECT_EQ(done1->encoding, v1::MESH_ENCODING_DRACO);
}

TEST(FrameAssembler, EmptyFrame) {
  FrameAssembler a;
  auto frame = feed(a, make_frame(0, "", 10));
  ASSERT_TRUE(frame);
  EXPECT_TRUE(frame->bytes.empty());
}

TEST(FrameAssembler, EveryMismatchIsAnIntegrityError) {
  const std::string bytes(25, 'x');
  auto expect_integrity = [&](const std::function<void(Events&)>& corrupt, const char* what) {
    Events e = make_frame(0, bytes, 10);
    corrupt(e);
    FrameAssembler a;
    EXPECT_EQ(error_code_of([&] { feed(a, e); }), ExitCode::kIntegrity) << what;
  };
  expect_integrity([](Events& e) { e.chunks[1].set_crc32(e.chunks[1].crc32() ^ 1); }, "chunk crc");
  expect_integrity([](Events& e) { e.chunks[1].mutable_data()->at(0) = 'y'; }, "chunk data");
  expect_integrity([](Events& e) { e.header.set_crc32(e.header.crc32() ^ 1); }, "frame crc");
  expect_integrity([](Events& e) { e.header.set_total_bytes(24); }, "total bytes");
  expect_integrity([](Events& e) { e.header.set_num_chunks(4); }, "num chunks");
  expect_integrity([](Events& e) { e.header.set_num_chunks(2); }, "fewer chunks");
  expect_integrity([](Events& e) { e.chunks[1].set_last(true); }, "early last");
  expect_integrity(
      [](Events& e) {
        e.chunks[2].set_last(false);
        e.header.set_num_chunks(3);
      },
      "missing last");
  expect_integrity([](Events& e) { std::swap(e.chunks[0], e.chunks[1]); }, "order");
  expect_integrity([](Events& e) { e.header.set_encoding(static_cast<v1::MeshEncoding>(9)); }, "encoding");

  FrameAssembler a;
  v1::FrameChunk orphan;
  orphan.set_frame_index(3);
  EXPECT_EQ(error_code_of([&] { a.on_chunk(orphan); }), ExitCode::kIntegrity);
}

// Found by fuzz/fuzz_frame_assembler: the header's total_bytes (up to num_chunks MiB, ~2^51 bytes) was reserved up
// front, so one hostile FrameHeader made the client throw std::bad_alloc (or allocate gigabytes).
TEST(FrameAssembler, HugeAnnouncedFrameReservesNothingUpFront) {
  FrameAssembler a;
  v1::FrameHeader header;
  header.set_frame_index(0);
  header.set_num_chunks(std::numeric_limits<std::int32_t>::max());
  header.set_total_bytes(std::uint64_t{std::numeric_limits<std::int32_t>::max()} * kMaxChunkBytes);
  EXPECT_NO_THROW(EXPECT_FALSE(a.on_header(header)));
  v1::FrameChunk chunk;
  chunk.set_frame_index(0);
  chunk.set_data("abc");
  chunk.set_crc32(crc32_of(chunk.data()));
  chunk.set_last(true);  // but the header announced 2^31-1 chunks
  EXPECT_EQ(error_code_of([&] { a.on_chunk(chunk); }), ExitCode::kIntegrity);
}

TEST(FrameAssembler, ResetDropsPartialFrames) {
  FrameAssembler a;
  Events e = make_frame(0, std::string(25, 'x'), 10);
  a.on_header(e.header);
  a.on_chunk(e.chunks[0]);
  a.reset();
  EXPECT_TRUE(a.idle());
  auto frame = feed(a, e);  // sent again after a reconnect
  ASSERT_TRUE(frame);
}

Mesh tetrahedron() {
  Mesh m;
  m.vertices = {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, 1)};
  m.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  return m;
}

TEST(FrameWriter, RawPlyAsReceivedAndConvertedToObj) {
  const fs::path dir = fresh_temp_dir("client_writer");
  const std::string ply = write_ply(tetrahedron(), /*double_precision=*/true);
  Events e = make_frame(2, ply, 1 << 20, v1::MESH_ENCODING_PLY);
  FrameAssembler a;
  auto frame = feed(a, e);
  ASSERT_TRUE(frame);

  FrameWriter writer(FrameOutputOptions{dir / "sub", {FileFormat::kPly, FileFormat::kObj}});
  auto files = writer.write(*frame);
  ASSERT_EQ(files.size(), 2u);
  EXPECT_EQ(read_file(dir / "sub" / "frame_0002.ply"), ply);  // lossless: byte for byte
  Mesh obj = read_mesh(dir / "sub" / "frame_0002.obj");
  EXPECT_EQ(obj.triangles.size(), 4u);
  const std::string csv = read_file(dir / "sub" / "stats.csv");
  EXPECT_EQ(csv.rfind("frame,vertices,triangles,closed,manifold,euler,components,min_valence,min_angle,area,volume", 0),
            0u);
  for (const auto& entry : fs::directory_iterator(dir / "sub")) {
    EXPECT_EQ(entry.path().string().find(".tmp"), std::string::npos) << entry.path();
  }
  fs::remove_all(dir);
}

// An output directory that takes no files is refused when the writer is made, before any job runs (/proc takes none,
// whoever runs the test), and the check leaves nothing behind in one that does.
TEST(FrameWriter, ADirectoryThatTakesNoFilesIsAUsageErrorAtOnce) {
  try {
    FrameWriter writer(FrameOutputOptions{"/proc", {}});
    ADD_FAILURE() << "/proc was taken as an output directory";
  } catch (const CliError& e) {
    EXPECT_EQ(e.code(), ExitCode::kUsage);
    EXPECT_NE(std::string(e.what()).find("cannot write in the output directory /proc"), std::string::npos) << e.what();
  }
  const fs::path dir = fresh_temp_dir("frame_writer_probe");
  { FrameWriter writer(FrameOutputOptions{dir, {}}); }
  EXPECT_TRUE(fs::is_empty(dir));
  fs::remove_all(dir);
}

// With no format asked for, each frame is written in the file that takes its bytes on every core: Draco pieces as a
// .glb holding their streams (what to_gltf makes of them), or, on a grid of more bits than glTF holds, as a .drc; one
// Draco mesh as the .drc it is; meshopt and raw frames as .ply.
TEST(FrameWriter, DefaultFormatFollowsEncoding) {
  const fs::path dir = fresh_temp_dir("client_writer_default");
  const Mesh sphere = testing::icosphere(4);
  auto frame_of = [&](FrameCodec codec, int bits) {
    FrameCodecOptions options;
    options.codec = codec;
    options.draco.quantization_bits = bits;
    options.max_piece_triangles = 1024;  // several pieces
    ReceivedFrame frame;
    frame.index = 0;
    frame.encoding = wire::mesh_encoding(codec);
    frame.bytes = encode_frame(sphere, options, 2);
    return frame;
  };
  auto only_file = [&] {
    std::vector<fs::path> files;
    for (const auto& entry : fs::directory_iterator(dir)) {
      if (entry.path().filename() != "stats.csv") files.push_back(entry.path());
    }
    EXPECT_EQ(files.size(), 1u);
    return files.empty() ? fs::path() : files.front();
  };
  for (const int bits : {8, 14, 16, 17, 20}) {
    SCOPED_TRACE(std::to_string(bits) + " bits");
    for (const FrameCodec codec :
         {FrameCodec::kDraco, FrameCodec::kDracoPieces, FrameCodec::kMeshopt, FrameCodec::kPly}) {
      SCOPED_TRACE(frame_codec_name(codec));
      fs::remove_all(dir);
      FrameWriter writer(FrameOutputOptions{dir, {}});
      const ReceivedFrame frame = frame_of(codec, bits);
      const std::vector<fs::path> written = writer.write(frame);
      const fs::path file = only_file();
      ASSERT_EQ(written, std::vector<fs::path>{file});
      const Mesh decoded = decode_frame(frame.bytes, codec, 2);
      if (codec == FrameCodec::kDracoPieces && bits <= kMaxGltfQuantizationBits) {
        EXPECT_EQ(file.filename(), "frame_0000.glb");
        EXPECT_EQ(read_file(file), to_gltf(frame.bytes, codec, nullptr, 2));  // the pieces as they came
      } else if (codec == FrameCodec::kDraco || codec == FrameCodec::kDracoPieces) {
        EXPECT_EQ(file.filename(), "frame_0000.drc");
        if (codec == FrameCodec::kDraco) {
          EXPECT_EQ(read_file(file), frame.bytes);
        }
      } else {
        EXPECT_EQ(file.filename(), "frame_0000.ply");
      }
      // Whatever the file, it holds the frame's mesh.
      const Mesh back = read_mesh(file);
      EXPECT_EQ(back.triangles.size(), decoded.triangles.size());
      EXPECT_EQ(back.vertices.size(), decoded.vertices.size());
    }
  }
  // Bytes that are not what their encoding says are an integrity error, with or without a format asked for.
  ReceivedFrame bad;
  bad.index = 0;
  bad.bytes = "not really draco";
  for (const FrameCodec codec : {FrameCodec::kDraco, FrameCodec::kDracoPieces}) {
    bad.encoding = wire::mesh_encoding(codec);
    FrameWriter ply_writer(FrameOutputOptions{dir, {FileFormat::kPly}});
    EXPECT_EQ(error_code_of([&] { ply_writer.write(bad); }), ExitCode::kIntegrity);
  }
  bad.encoding = wire::mesh_encoding(FrameCodec::kDracoPieces);  // its directory says which file takes it
  FrameWriter default_writer(FrameOutputOptions{dir, {}});
  EXPECT_EQ(error_code_of([&] { default_writer.write(bad); }), ExitCode::kIntegrity);
  fs::remove_all(dir);
}

TEST(FrameWriter, UnwritableDirectoryIsAUsageError) {
  const fs::path dir = fresh_temp_dir("client_writer_file");
  write_file(dir / "plain_file", "x");
  EXPECT_EQ(error_code_of([&] {
              FrameWriter w(FrameOutputOptions{dir / "plain_file" / "out", {}});
            }),
            ExitCode::kUsage);
  fs::remove_all(dir);
}

TEST(StatsCsv, OneRowPerFrameSortedWithStageColumns) {
  std::map<int, v1::FrameStats> stats;
  for (int i : {1, 0}) {
    v1::FrameStats s;
    s.set_vertices(10 + i);
    s.set_triangles(20 + i);
    s.mutable_check()->set_closed(true);
    s.mutable_check()->set_edge_manifold(true);
    s.mutable_check()->set_vertex_manifold(i == 0);
    s.mutable_check()->set_euler_characteristic(2);
    s.mutable_check()->set_components(1);
    auto* t = s.add_timings();
    t->set_stage("polygonize");
    t->set_seconds(0.5);
    if (i == 1) {
      auto* t2 = s.add_timings();
      t2->set_stage("encode");
      t2->set_seconds(0.25);
    }
    stats[i] = s;
  }
  const std::string csv = stats_csv(stats);
  std::istringstream lines(csv);
  std::string header, row0, row1, extra;
  std::getline(lines, header);
  std::getline(lines, row0);
  std::getline(lines, row1);
  EXPECT_FALSE(std::getline(lines, extra));
  EXPECT_EQ(header,
            "frame,vertices,triangles,closed,manifold,euler,components,min_valence,min_angle,area,volume,"
            "polygonize_s,encode_s,total_s");
  EXPECT_EQ(row0.rfind("0,10,20,1,1,2,1,", 0), 0u) << row0;
  EXPECT_EQ(row1.rfind("1,11,21,1,0,2,1,", 0), 0u) << row1;
  EXPECT_NE(row0.find(",0.500000,,0.500000"), std::string::npos) << row0;
  EXPECT_NE(row1.find(",0.500000,0.250000,0.750000"), std::string::npos) << row1;
}

TEST(JobSpec, BuildsIsosurfaceFromSceneFiles) {
  const fs::path dir = fresh_temp_dir("client_spec");
  write_file(dir / "ball.json", R"({"name": "ball", "root": {"sphere": {"radius": 0.5}}})");
  JobOptions options;
  options.scenes = {dir / "ball.json", dir / "ball.json"};
  v1::IsosurfaceJob* iso = options.spec.mutable_isosurface();
  iso->mutable_bounds()->mutable_min()->set_x(-1);
  iso->mutable_bounds()->mutable_min()->set_y(-1);
  iso->mutable_bounds()->mutable_min()->set_z(-1);
  iso->mutable_bounds()->mutable_max()->set_x(1);
  iso->mutable_bounds()->mutable_max()->set_y(1);
  iso->mutable_bounds()->mutable_max()->set_z(1);
  iso->set_method(v1::POLYGONIZER_CUBES);
  options.spec.mutable_output()->set_encoding(v1::MESH_ENCODING_PLY);
  options.spec.mutable_output()->set_normals(true);
  v1::JobSpec spec = prepare_job(options).spec;
  ASSERT_TRUE(spec.has_isosurface());
  EXPECT_EQ(spec.isosurface().scenes_size(), 2);
  EXPECT_DOUBLE_EQ(spec.isosurface().scenes(0).root().sphere().radius(), 0.5);
  // No --cells: the CLI sends no resolution, so the server applies its own default.
  EXPECT_EQ(spec.isosurface().resolution_case(), v1::IsosurfaceJob::RESOLUTION_NOT_SET);
  EXPECT_DOUBLE_EQ(spec.isosurface().bounds().max().z(), 1.0);
  EXPECT_EQ(spec.isosurface().method(), v1::POLYGONIZER_CUBES);
  EXPECT_EQ(spec.output().encoding(), v1::MESH_ENCODING_PLY);
  EXPECT_TRUE(spec.output().normals());
  EXPECT_EQ(spec.name(), "ball (+1 more)");

  options.spec.mutable_isosurface()->set_cell_size(0.1);
  options.name = "named";
  options.spec.mutable_output()->clear_encoding();
  options.spec.mutable_output()->set_quantization_bits(11);
  spec = prepare_job(options).spec;
  EXPECT_DOUBLE_EQ(spec.isosurface().cell_size(), 0.1);
  EXPECT_EQ(spec.name(), "named");
  EXPECT_EQ(spec.output().quantization_bits(), 11);
  fs::remove_all(dir);
}

TEST(JobSpec, WholeSpecFromJsonWithOverrides) {
  const fs::path dir = fresh_temp_dir("client_spec_json");
  write_file(dir / "job.json", R"({"name": "from file", "output": {"quantizationBits": 9},
             "isosurface": {"scenes": [{"root": {"torus": {"majorRadius": 1, "minorRadius": 0.25}}}], "cells": 40}})");
  JobOptions options;
  options.spec_file = dir / "job.json";
  v1::JobSpec spec = prepare_job(options).spec;
  EXPECT_EQ(spec.name(), "from file");
  EXPECT_EQ(spec.isosurface().cells(), 40);
  EXPECT_EQ(spec.output().quantization_bits(), 9);
  options.spec.mutable_output()->set_encoding(v1::MESH_ENCODING_PLY);
  EXPECT_EQ(prepare_job(options).spec.output().encoding(), v1::MESH_ENCODING_PLY);
  fs::remove_all(dir);
}

TEST(JobSpec, MalformedOrMissingFilesNameTheFile) {
  const fs::path dir = fresh_temp_dir("client_spec_bad");
  write_file(dir / "broken.json", R"({"root": {"sphere": {"radius": }}})");
  write_file(dir / "typo.json", R"({"root": {"sphere": {"radios": 1}}})");
  for (const char* name : {"broken.json", "typo.json", "missing.json"}) {
    try {
      read_scene_file(dir / name);
      ADD_FAILURE() << name << " parsed";
    } catch (const CliError& e) {
      EXPECT_EQ(e.code(), ExitCode::kUsage);
      EXPECT_NE(std::string(e.what()).find(name), std::string::npos) << e.what();
    }
  }
  fs::remove_all(dir);
}

TEST(Health, NamesServingStatusesAndKeepsUnknownNumbersUnknown) {
  EXPECT_EQ(health_status_from(0), HealthStatus::kUnknown);
  EXPECT_EQ(health_status_from(1), HealthStatus::kServing);
  EXPECT_EQ(health_status_from(2), HealthStatus::kNotServing);
  EXPECT_EQ(health_status_from(3), HealthStatus::kServiceUnknown);
  EXPECT_EQ(health_status_from(4), HealthStatus::kUnknown);  // a newer server's value
  EXPECT_EQ(health_status_from(-1), HealthStatus::kUnknown);
  EXPECT_EQ(health_status_name(HealthStatus::kServing), "SERVING");
  EXPECT_EQ(health_status_name(HealthStatus::kServiceUnknown), "SERVICE_UNKNOWN");
}

}  // namespace
}  // namespace surfacer::client
