// The service's Prometheus metrics (server/metrics.h): what the job store, the scheduler and the RPC handlers
// count. One instance per server, owned by SurfacerServer::Impl; served by --metrics-listen.
#pragma once

#include "core/util/version.h"
#include "server/metrics.h"

namespace surfacer::server {

struct ServerMetrics {
  explicit ServerMetrics(MetricsRegistry& r)
      : jobs_submitted(r.counter("surfacer_jobs_submitted_total", "Jobs accepted by SubmitJob", {"kind"})),
        jobs_rejected(
            r.counter("surfacer_jobs_rejected_total", "SubmitJob calls refused, by gRPC status code", {"code"})),
        jobs_finished(r.counter("surfacer_jobs_finished_total", "Jobs that reached a final state", {"kind", "state"})),
        frames(r.counter("surfacer_frames_total", "Frames finished (rate() gives frames/s)", {"kind"})),
        frame_bytes(r.counter("surfacer_frame_bytes_total", "Bytes of finished frames (encoded meshes)").with()),
        stage_seconds(r.histogram("surfacer_stage_seconds",
                                  "Time per frame stage (sample, polygonize, smooth, encode, "
                                  "...)",
                                  latency_buckets(), {"kind", "stage"})),
        frame_seconds(r.histogram("surfacer_frame_seconds", "Wall time from job start to each finished frame",
                                  latency_buckets(), {"kind"})),
        bytes_in(r.counter("surfacer_upload_bytes_total", "Bytes received by Upload").with()),
        bytes_out(r.counter("surfacer_stream_bytes_total", "Frame bytes sent by WatchJob streams").with()),
        watchers(r.gauge("surfacer_watch_streams", "Open WatchJob streams").with()) {
    // The Prometheus "info" idiom: a constant 1 whose label says which build is running.
    r.gauge("surfacer_build_info", "The version of this server (1)", {"version"}).with({build_version()}).set(1);
  }

  CounterFamily& jobs_submitted;
  CounterFamily& jobs_rejected;
  CounterFamily& jobs_finished;
  CounterFamily& frames;
  Counter& frame_bytes;
  HistogramFamily& stage_seconds;
  HistogramFamily& frame_seconds;
  Counter& bytes_in;
  Counter& bytes_out;
  Gauge& watchers;
};

}  // namespace surfacer::server
