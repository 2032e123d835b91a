// Wall-clock times of jobs (Job.created/started/finished) and of metrics, read from std::chrono with the clock's
// full resolution (protobuf's TimeUtil::GetCurrentTime() gives whole seconds on some builds).
#pragma once

#include <google/protobuf/timestamp.pb.h>

#include <chrono>
#include <cstdint>

namespace surfacer::server {

inline google::protobuf::Timestamp to_timestamp(std::chrono::system_clock::time_point t) {
  const auto ns = std::chrono::duration_cast<std::chrono::nanoseconds>(t.time_since_epoch()).count();
  // Floor division: nanos stays in [0, 1e9) for times before 1970 too.
  std::int64_t seconds = ns / 1'000'000'000;
  std::int64_t nanos = ns % 1'000'000'000;
  if (nanos < 0) {
    nanos += 1'000'000'000;
    --seconds;
  }
  google::protobuf::Timestamp out;
  out.set_seconds(seconds);
  out.set_nanos(static_cast<std::int32_t>(nanos));
  return out;
}

inline std::chrono::system_clock::time_point from_timestamp(const google::protobuf::Timestamp& t) {
  return std::chrono::system_clock::time_point(std::chrono::duration_cast<std::chrono::system_clock::duration>(
      std::chrono::seconds(t.seconds()) + std::chrono::nanoseconds(t.nanos())));
}

inline google::protobuf::Timestamp now_timestamp() { return to_timestamp(std::chrono::system_clock::now()); }

// Seconds from `t` to now (negative when `t` is in the future).
inline double seconds_since(const google::protobuf::Timestamp& t) {
  return std::chrono::duration<double>(std::chrono::system_clock::now() - from_timestamp(t)).count();
}

}  // namespace surfacer::server
