// The table printed at the end of a particles job: one row per frame (particles, triangles, seconds) and a total
// row with the mean seconds per frame.
#pragma once

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

}  // namespace surfacer::client
