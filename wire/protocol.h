// Constants of the protocol itself (proto/surfacer/v1/surfacer.proto), shared by both sides. GetServerInfo reports
// them with the server's own limits.
#pragma once

#include <cstddef>

namespace surfacer::wire {

// The largest message either side accepts: gRPC's default receive limit, which neither side raises. Bulk data goes
// in chunks and uploads; a JobSpec larger than this (say a million inline scenes) is refused by the client before
// it is sent, since the server could only answer with gRPC's own "larger than max".
inline constexpr std::size_t kMaxMessageBytes = std::size_t{4} << 20;

// The largest payload of one UploadChunk or FrameChunk: every message stays far under kMaxMessageBytes.
inline constexpr std::size_t kMaxChunkBytes = std::size_t{1} << 20;

// Free text a request carries (JobSpec.name, Scene.name, UploadChunk.name): at most this many bytes, so that
// every reply that echoes it (SubmitJob, GetJob, WatchJob, a ListJobs page) stays far under 4 MiB.
inline constexpr std::size_t kMaxNameBytes = 1024;
// Ids a request carries (job_id, upload_id, page_token); the server's own are 18 characters.
inline constexpr std::size_t kMaxIdBytes = 64;

// Scene nodes nested deeper than this (unions, intersections, differences, transforms) are refused, by the server
// and by the CLI alike. Each level is two protobuf messages (Node, then Csg or Transform) and two JSON objects,
// so this stays well inside both parsers' recursion limits (100 in protobuf 3.21, for binary and JSON).
inline constexpr int kMaxSceneDepth = 32;

// A job's error message (JobError.message) is cut to this many bytes.
inline constexpr std::size_t kMaxErrorBytes = 2048;

// ListJobs: jobs per page when the request does not say, and at most.
inline constexpr int kDefaultListPageSize = 100;
inline constexpr int kMaxListPageSize = 1000;
// A full page (each Job: its name, its error and under 512 bytes more) stays under gRPC's 4 MiB.
static_assert(kMaxListPageSize * (kMaxNameBytes + kMaxErrorBytes + 512) < (std::size_t{4} << 20));

}  // namespace surfacer::wire
