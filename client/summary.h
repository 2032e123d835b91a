// What the CLI prints at the end of a run: the particles table, elapsed time, a job's error.
#pragma once

#include <chrono>
#include <cstdint>
#include <map>
#include <string>

#include "surfacer/v1/surfacer.pb.h"

namespace surfacer::client {

// `stats`: the frames written, by index. Particles per frame come from the frame's metrics["particles"] (set by the
// server), else from `uploaded` (what this client uploaded for that frame), else "-". Seconds are the frame's stage
// timings summed (time on the server). `wall_seconds` > 0 adds the elapsed time of the whole command.
std::string particles_summary_table(const std::map<int, v1::FrameStats>& stats,
                                    const std::map<int, std::int64_t>& uploaded, double wall_seconds);

// "12.3 s" since `start`.
std::string elapsed_text(std::chrono::steady_clock::time_point start);
// "CODE: message" of a job's error; "" when it has none.
std::string job_error_text(const v1::Job& job);

}  // namespace surfacer::client
