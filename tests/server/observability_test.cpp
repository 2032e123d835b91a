// Observability: the Prometheus endpoint counts what a user watches (jobs by state, queue depth, frames, stage
// latencies, bytes in and out), and the standard health service says NOT_SERVING while the server drains.
#include <arpa/inet.h>
#include <grpcpp/generic/generic_stub.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <future>
#include <regex>
#include <thread>

#include "tests/server/test_client.h"

namespace surfacer::testing {
namespace {

using namespace std::chrono_literals;

std::string http_get(int port, const std::string& path) {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<std::uint16_t>(port));
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
    close(fd);
    return "";
  }
  const std::string request = "GET " + path + " HTTP/1.1\r\nHost: localhost\r\n\r\n";
  (void)!write(fd, request.data(), request.size());
  std::string response;
  char buf[4096];
  ssize_t n;
  while ((n = read(fd, buf, sizeof buf)) > 0) response.append(buf, static_cast<std::size_t>(n));
  close(fd);
  return response;
}

// "SERVING" / "NOT_SERVING" from grpc.health.v1.Health/Check for the whole server.
std::string health(const std::shared_ptr<grpc::Channel>& channel) {
  grpc::GenericStub stub(channel);
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + 5s);
  grpc::ByteBuffer request(nullptr, 0), response;
  std::promise<grpc::Status> done;
  stub.UnaryCall(&context, "/grpc.health.v1.Health/Check", grpc::StubOptions(), &request, &response,
                 [&done](grpc::Status s) { done.set_value(std::move(s)); });
  const auto status = done.get_future().get();
  if (!status.ok()) return "error: " + status.error_message();
  std::vector<grpc::Slice> slices;
  (void)response.Dump(&slices);
  std::string bytes;
  for (const auto& s : slices) bytes.append(reinterpret_cast<const char*>(s.begin()), s.size());
  if (bytes == std::string("\x08\x01", 2)) return "SERVING";
  if (bytes == std::string("\x08\x02", 2)) return "NOT_SERVING";
  return "unexpected";
}

TEST(Observability, MetricsEndpointCountsJobsFramesStagesAndBytes) {
  auto o = LoopbackServer::default_options();
  o.metrics_listen = "127.0.0.1:0";
  LoopbackServer s(o);
  const int port = s.server->metrics_port();
  ASSERT_GT(port, 0);
  std::vector<v1::Scene> scenes(3, scene_from_json(R"({"root": {"sphere": {"radius": 1}}})"));
  std::string id;
  ASSERT_TRUE(submit(*s.stub, isosurface_spec(scenes, 32), &id).ok());
  const auto r = watch_job(*s.stub, id);
  ASSERT_EQ(r.final_job.state(), v1::JOB_STATE_SUCCEEDED);
  std::size_t streamed = 0;
  for (const auto& [k, f] : r.frames) streamed += f.bytes.size();
  // A rejected submit is counted by code.
  v1::JobSpec bad;
  EXPECT_FALSE(submit(*s.stub, bad, &id).ok());

  // The finished counter follows the terminal state a watcher sees by a moment (the job's end hooks run after it is
  // settled): scrape until it is there.
  std::string text;
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  do {
    const std::string response = http_get(port, "/metrics");
    ASSERT_NE(response.find("200 OK"), std::string::npos) << response.substr(0, 200);
    text = response.substr(response.find("\r\n\r\n") + 3);
  } while (metric_sample(text, R"(surfacer_jobs_finished_total{kind="isosurface",state="succeeded"})") != 1 &&
           std::chrono::steady_clock::now() < until);
  EXPECT_EQ(metric_sample(text, R"(surfacer_jobs_submitted_total{kind="isosurface"})"), 1);
  EXPECT_EQ(metric_sample(text, R"(surfacer_frames_total{kind="isosurface"})"), 3);
  EXPECT_EQ(metric_sample(text, R"(surfacer_jobs{state="succeeded"})"), 1);
  EXPECT_EQ(metric_sample(text, R"(surfacer_jobs{state="running"})"), 0);
  EXPECT_EQ(metric_sample(text, "surfacer_queue_depth"), 0);
  EXPECT_EQ(metric_sample(text, R"(surfacer_jobs_finished_total{kind="isosurface",state="succeeded"})"), 1);
  EXPECT_EQ(metric_sample(text, R"(surfacer_jobs_rejected_total{code="INVALID_ARGUMENT"})"), 1);
  EXPECT_EQ(metric_sample(text, "surfacer_stream_bytes_total"), static_cast<double>(streamed));
  EXPECT_EQ(metric_sample(text, "surfacer_frame_bytes_total"), static_cast<double>(streamed));
  EXPECT_EQ(metric_sample(text, "surfacer_serving"), 1);
  // One latency observation per frame and stage, e.g. the polygonizer's.
  const std::regex polygonize(R"re(surfacer_stage_seconds_count\{kind="isosurface",stage="([a-z_]+)"\} 3)re");
  EXPECT_TRUE(std::regex_search(text, polygonize)) << text;
  EXPECT_NE(text.find("# TYPE surfacer_stage_seconds histogram"), std::string::npos);
  EXPECT_EQ(metric_sample(text, R"(surfacer_frame_seconds_count{kind="isosurface"})"), 3);
}

TEST(Observability, JobTimesAndFrameSecondsHaveSubSecondResolution) {
  LoopbackServer s;
  std::vector<v1::Scene> scenes(2, scene_from_json(R"({"root": {"sphere": {"radius": 1}}})"));
  std::string id;
  ASSERT_TRUE(submit(*s.stub, isosurface_spec(scenes, 48), &id).ok());
  const v1::Job job = watch_job(*s.stub, id).final_job;
  ASSERT_EQ(job.state(), v1::JOB_STATE_SUCCEEDED);
  // Whole seconds would leave every nanos field 0 (the odds of that by chance are nil).
  EXPECT_TRUE(job.created().nanos() != 0 || job.started().nanos() != 0 || job.finished().nanos() != 0)
      << job.DebugString();
  auto seconds = [](const google::protobuf::Timestamp& t) {
    return static_cast<double>(t.seconds()) + 1e-9 * t.nanos();
  };
  const double run = seconds(job.finished()) - seconds(job.started());
  EXPECT_GT(run, 0.0);
  EXPECT_LT(run, 60.0);
  EXPECT_LE(seconds(job.created()), seconds(job.started()));
  // Two frames of a job that ran for a fraction of a second: their sum is a fraction of a second, not 0.
  const std::string text = s.server->metrics_text();
  EXPECT_EQ(metric_sample(text, R"(surfacer_frame_seconds_count{kind="isosurface"})"), 2);
  const double sum = metric_sample(text, R"(surfacer_frame_seconds_sum{kind="isosurface"})");
  EXPECT_GT(sum, 0.0) << text;
  EXPECT_LT(sum, 2 * run + 1.0);
}

TEST(Observability, HealthIsNotServingWhileDraining) {
  auto o = LoopbackServer::default_options();
  o.health_listen = "127.0.0.1:0";
  LoopbackServer s(o);
  ASSERT_GT(s.server->health_port(), 0);
  auto probe =
      grpc::CreateChannel("127.0.0.1:" + std::to_string(s.server->health_port()), grpc::InsecureChannelCredentials());
  EXPECT_EQ(health(s.channel), "SERVING");
  EXPECT_EQ(health(probe), "SERVING");
  std::string id;
  ASSERT_TRUE(
      submit(*s.stub, isosurface_spec({scene_from_json(R"({"root": {"sphere": {"radius": 1}}})")}, 400), &id).ok());
  std::thread drain([&] { s.server->shutdown(server::ShutdownMode::kDrain, 20s); });
  std::string during;
  for (int i = 0; i < 200; ++i) {
    during = health(s.channel);
    if (during != "SERVING") break;
    std::this_thread::sleep_for(5ms);
  }
  EXPECT_EQ(during, "NOT_SERVING");
  EXPECT_EQ(health(probe), "NOT_SERVING") << "the probe port follows the main port";
  drain.join();
}

}  // namespace
}  // namespace surfacer::testing
