#include "server/server.h"

#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>

#include <algorithm>
#include <cctype>
#include <condition_variable>
#include <fstream>
#include <set>
#include <sstream>
#include <stdexcept>
#include <thread>

#include "core/util/version.h"
#include "server/auth.h"
#include "server/clock.h"
#include "server/job.h"
#include "server/log.h"
#include "server/memory_budget.h"
#include "server/metrics_http.h"
#include "server/runners/runner.h"
#include "server/scheduler.h"
#include "server/server_metrics.h"
#include "server/service.h"
#include "server/status_map.h"
#include "server/store.h"
#include "server/uploads.h"
#include "server/worker_pool.h"
#include "wire/tls.h"

namespace surfacer::server {
namespace {

std::string read_file(const std::string& path, const char* flag) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(std::string(flag) + " " + path + ": cannot be read");
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// Host part of "host:port", "[v6]:port".
std::string host_of(const std::string& listen) {
  if (!listen.empty() && listen[0] == '[') return listen.substr(1, listen.find(']') - 1);
  const auto colon = listen.rfind(':');
  return colon == std::string::npos ? listen : listen.substr(0, colon);
}

bool is_loopback(const std::string& listen) {
  const std::string host = host_of(listen);
  return host == "localhost" || host == "::1" || host.rfind("127.", 0) == 0 || host.rfind("unix:", 0) == 0 ||
         listen.rfind("unix:", 0) == 0;
}

std::shared_ptr<grpc::ServerCredentials> server_credentials(const ServerOptions& o) {
  if (o.tls_cert_file.empty() != o.tls_key_file.empty()) {
    throw std::runtime_error("--tls-cert and --tls-key go together; give both (PEM files) or neither");
  }
  if (o.tls_cert_file.empty()) {
    if (!o.tls_client_ca_file.empty()) {
      throw std::runtime_error("--tls-client-ca needs --tls-cert and --tls-key (mutual TLS is TLS first)");
    }
    if (!is_loopback(o.listen) && !o.allow_insecure) {
      throw std::runtime_error("refusing plain text on " + o.listen +
                               ": give --tls-cert and --tls-key, listen on a loopback address, or pass "
                               "--allow-insecure (e.g. behind a proxy or mesh that provides TLS)");
    }
    return grpc::InsecureServerCredentials();
  }
  grpc::SslServerCredentialsOptions ssl(o.tls_client_ca_file.empty()
                                            ? GRPC_SSL_DONT_REQUEST_CLIENT_CERTIFICATE
                                            : GRPC_SSL_REQUEST_AND_REQUIRE_CLIENT_CERTIFICATE_AND_VERIFY);
  ssl.pem_key_cert_pairs.push_back({read_file(o.tls_key_file, "--tls-key"), read_file(o.tls_cert_file, "--tls-cert")});
  if (!o.tls_client_ca_file.empty()) ssl.pem_root_certs = read_file(o.tls_client_ca_file, "--tls-client-ca");
  // Checked here, not left to gRPC: it would report a bad pair only as a port it cannot listen on.
  try {
    wire::check_tls_key_pair(ssl.pem_key_cert_pairs[0].cert_chain, ssl.pem_key_cert_pairs[0].private_key,
                             "--tls-cert " + o.tls_cert_file, "--tls-key " + o.tls_key_file);
    if (!o.tls_client_ca_file.empty()) {
      wire::check_tls_certificates(ssl.pem_root_certs, "--tls-client-ca " + o.tls_client_ca_file);
    }
  } catch (const Error& e) {
    throw std::runtime_error(e.what());
  }
  return grpc::SslServerCredentials(ssl);
}

}  // namespace

struct SurfacerServer::Impl {
  explicit Impl(const ServerOptions& options)
      : memory(options.limits.memory_budget_bytes),
        threads(options.workers > 0 ? options.workers
                                    : std::max(1, static_cast<int>(std::thread::hardware_concurrency()))),
        pool(threads),
        store(options.data_dir.empty() ? nullptr : Store::open(options.data_dir)),
        auth(options.tokens_file.empty() ? nullptr : TokenAuth::load(options.tokens_file)),
        uploads(store.get()),
        scheduler(pool, options.max_queued_jobs),
        metrics(registry),
        service(state) {
    state.options = options;
    state.worker_threads = threads;
    state.scheduler = &scheduler;
    state.uploads = &uploads;
    state.store = store.get();
    state.auth = auth.get();
    state.usage = &usage;
    state.hooks = &hooks;
    state.metrics = &metrics;
    state.memory = &memory;
    register_metrics();
  }

  void register_metrics();

  // Brings back what the store holds: uploads, finished jobs (for watching) and unfinished ones (resumed).
  void restore();
  // Fails open sequences whose client went quiet (--upload-idle-timeout; Job::expire_if_idle).
  void expire_idle_sequences();
  void retention();
  // Writes again the job states the store refused (see Job::persist).
  void retry_pending_writes();
  void janitor_loop();

  // First: destroyed last, after the workers and uploads that hold reservations on it.
  MemoryBudget memory;
  int threads;
  WorkerPool pool;
  std::unique_ptr<Store> store;
  std::unique_ptr<TokenAuth> auth;
  Usage usage;
  JobHooks hooks;
  UploadStore uploads;
  Scheduler scheduler;
  MetricsRegistry registry;
  ServerMetrics metrics;
  ServiceState state;
  SurfacerService service;
  std::unique_ptr<grpc::Server> grpc_server;
  std::unique_ptr<grpc::Server> health_server;  // --health-listen: grpc.health.v1 only, plain text
  int port = 0;
  int health_port = 0;

  void set_serving(bool serving) {
    for (auto* server : {grpc_server.get(), health_server.get()}) {
      if (!server) continue;
      if (auto* health = server->GetHealthCheckService()) health->SetServingStatus(serving);
    }
  }
  std::mutex retention_mutex;

  std::mutex mutex;
  std::condition_variable cv;
  bool shutting_down = false;
  bool done = false;
  std::thread janitor;
  // Last: destroyed first, so its scrapes never see a half-destroyed server.
  std::unique_ptr<MetricsHttpServer> metrics_http;
};

void SurfacerServer::Impl::register_metrics() {
  hooks.on_frame = [this](const Job& job, const v1::FrameHeader& header) {
    metrics.frames.with({job.kind()}).inc();
    metrics.frame_bytes.inc(static_cast<double>(header.total_bytes()));
    for (const auto& t : header.stats().timings())
      metrics.stage_seconds.with({job.kind(), t.stage()}).observe(t.seconds());
    const v1::Job snap = job.snapshot();
    if (snap.has_started()) {
      metrics.frame_seconds.with({job.kind()}).observe(std::max(0.0, seconds_since(snap.started())));
    }
  };
  hooks.on_finished = [this](const Job& job, v1::JobState s) {
    std::string state = v1::JobState_Name(s);
    if (state.rfind("JOB_STATE_", 0) == 0) state = state.substr(10);
    for (auto& c : state) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    metrics.jobs_finished.with({job.kind(), state}).inc();
  };
  registry.gauge_callback_family("surfacer_jobs", "Jobs known to this server, by state", {"state"}, [this] {
    std::map<std::string, double> counts = {
        {"queued", 0}, {"running", 0}, {"succeeded", 0}, {"failed", 0}, {"cancelled", 0}};
    for (const auto& job : scheduler.list()) {
      switch (job->state()) {
        case v1::JOB_STATE_QUEUED:
          counts["queued"] += 1;
          break;
        case v1::JOB_STATE_RUNNING:
          counts["running"] += 1;
          break;
        case v1::JOB_STATE_SUCCEEDED:
          counts["succeeded"] += 1;
          break;
        case v1::JOB_STATE_FAILED:
          counts["failed"] += 1;
          break;
        case v1::JOB_STATE_CANCELLED:
          counts["cancelled"] += 1;
          break;
        default:
          break;
      }
    }
    std::vector<LabelledValue> out;
    for (const auto& [k, v] : counts) out.push_back({{k}, v});
    return out;
  });
  registry.gauge_callback("surfacer_queue_depth", "Jobs waiting for a worker",
                          [this] { return static_cast<double>(scheduler.queued_jobs()); });
  registry.gauge_callback("surfacer_workers", "Worker threads", [this] { return static_cast<double>(threads); });
  registry.gauge_callback("surfacer_serving", "1 while accepting jobs, 0 while draining or stopped",
                          [this] { return state.accepting.load() ? 1.0 : 0.0; });
  registry.gauge_callback("surfacer_memory_budget_bytes", "The memory budget (--memory-budget)",
                          [this] { return static_cast<double>(memory.limit()); });
  registry.gauge_callback("surfacer_memory_budget_used_bytes",
                          "Bytes of the memory budget held by running jobs' meshes, by uploads being received or "
                          "kept in memory and by WatchJob streams",
                          [this] { return static_cast<double>(memory.used()); });
  registry.gauge_callback("surfacer_stored_bytes", "Bytes of frames and uploads held (store or memory)", [this] {
    double total = static_cast<double>(uploads.total_bytes());
    for (const auto& job : scheduler.list()) total += static_cast<double>(job->stored_bytes());
    return total;
  });
}

void SurfacerServer::Impl::restore() {
  if (!store) return;
  uploads.restore();
  for (const UploadInfo& u : uploads.list()) usage.add(u.owner, u.bytes);
  int resumed = 0, kept = 0;
  for (StoredJob& stored : store->load_jobs()) {
    const Tenant* tenant = nullptr;
    if (auth) tenant = auth->tenant(stored.owner);
    const bool finished = stored.snapshot.state() == v1::JOB_STATE_SUCCEEDED ||
                          stored.snapshot.state() == v1::JOB_STATE_FAILED ||
                          stored.snapshot.state() == v1::JOB_STATE_CANCELLED;
    JobInit init;
    init.id = stored.id;
    init.name = stored.spec.name();
    init.owner = stored.owner;
    init.kind = stored.snapshot.kind();
    init.store = store.get();
    init.usage = &usage;
    init.max_stored_bytes = tenant ? tenant->max_stored_bytes : 0;
    init.upload_ids = stored.upload_ids;
    init.hooks = &hooks;
    init.spec = stored.spec;
    grpc::Status failure;
    if (!finished) {
      try {
        JobContext context{state.options.limits, uploads, threads, &memory};
        init.runner = make_job_runner(stored.spec, context);
      } catch (...) {
        failure = status_from_exception(std::current_exception());
      }
    }
    auto job = std::make_shared<Job>(std::move(init));
    std::vector<int> tasks = job->restore(stored);
    if (!failure.ok()) {
      job->fail_restore(failure.error_code(), failure.error_message());
      tasks.clear();
    }
    if (job->terminal()) {
      ++kept;
    } else {
      ++resumed;
    }
    scheduler.resume(job, std::move(tasks));
  }
  log_event(LogLevel::kInfo, "store_opened",
            {{"data_dir", store->dir().string()},
             {"jobs_resumed", std::to_string(resumed)},
             {"jobs_finished", std::to_string(kept)},
             {"uploads", std::to_string(uploads.list().size())}});
}

void SurfacerServer::Impl::retention() {
  std::lock_guard guard(retention_mutex);
  const ServerOptions& o = state.options;
  auto drop_job = [&](const std::shared_ptr<Job>& job) {
    const std::int64_t bytes = job->stored_bytes();
    usage.release(job->owner(), bytes);
    if (store) store->delete_job(job->id());
    log_event(LogLevel::kInfo, "retention_job", {{"job", job->id()}, {"bytes", std::to_string(bytes)}});
  };
  for (const auto& job : scheduler.forget_finished(o.keep_finished)) drop_job(job);

  // Uploads that no unfinished job uses, oldest first.
  auto unused_uploads = [&] {
    std::set<std::string> used;
    for (const auto& job : scheduler.list()) {
      if (job->terminal()) continue;
      const std::vector<std::string> ids = job->upload_ids();
      used.insert(ids.begin(), ids.end());
    }
    std::vector<UploadInfo> out;
    for (auto& u : uploads.list()) {
      if (!used.count(u.id)) out.push_back(std::move(u));
    }
    std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return a.created < b.created; });
    return out;
  };
  auto drop_upload = [&](const UploadInfo& u) {
    usage.release(u.owner, uploads.remove(u.id));
    log_event(LogLevel::kInfo, "retention_upload", {{"upload", u.id}, {"bytes", std::to_string(u.bytes)}});
  };
  const auto cutoff = std::chrono::system_clock::now() - o.keep_finished;
  for (const auto& u : unused_uploads()) {
    if (u.created < cutoff) drop_upload(u);
  }
  if (o.retain_bytes <= 0) return;
  auto total = [&] {
    std::int64_t t = uploads.total_bytes();
    for (const auto& job : scheduler.list()) t += job->stored_bytes();
    return t;
  };
  std::int64_t bytes = total();
  if (bytes <= o.retain_bytes) return;
  std::vector<std::shared_ptr<Job>> finished;
  for (const auto& job : scheduler.list()) {
    if (job->terminal()) finished.push_back(job);
  }
  std::sort(finished.begin(), finished.end(),
            [](const auto& a, const auto& b) { return a->finished_at() < b->finished_at(); });
  for (const auto& job : finished) {
    if (bytes <= o.retain_bytes) break;
    bytes -= job->stored_bytes();
    scheduler.forget(job->id());
    drop_job(job);
  }
  for (const auto& u : unused_uploads()) {
    if (bytes <= o.retain_bytes) break;
    bytes -= u.bytes;
    drop_upload(u);
  }
}

void SurfacerServer::Impl::expire_idle_sequences() {
  const std::chrono::milliseconds timeout = state.options.upload_idle_timeout;
  const auto cutoff = std::chrono::steady_clock::now() - timeout;
  for (const auto& job : scheduler.list()) {
    if (!job->open()) continue;
    if (job->expire_if_idle(cutoff, state.upload_activity.last(job->owner()), timeout)) {
      log_event(LogLevel::kWarn, "sequence_idle", {{"job", job->id()}, {"note", "--upload-idle-timeout"}});
    }
  }
}

void SurfacerServer::Impl::retry_pending_writes() {
  if (!store) return;
  std::vector<std::shared_ptr<Job>> pending;
  for (const auto& job : scheduler.list()) {
    if (job->persist_pending()) pending.push_back(job);
  }
  if (pending.empty()) return;
  store->reclaim();
  for (const auto& job : pending) job->retry_persist();
}

void SurfacerServer::Impl::janitor_loop() {
  constexpr auto kRetryInterval = std::chrono::seconds(1);
  auto next_retention = std::chrono::steady_clock::now() + state.options.retention_interval;
  std::unique_lock lock(mutex);
  while (!shutting_down) {
    cv.wait_for(lock, std::min<std::chrono::steady_clock::duration>(kRetryInterval, state.options.retention_interval),
                [&] { return shutting_down; });
    if (shutting_down) break;
    lock.unlock();
    try {
      expire_idle_sequences();
      retry_pending_writes();
      if (std::chrono::steady_clock::now() >= next_retention) {
        next_retention = std::chrono::steady_clock::now() + state.options.retention_interval;
        retention();
      }
    } catch (const std::exception& e) {
      log_event(LogLevel::kError, "retention_failed", {{"error", e.what()}});
    }
    lock.lock();
  }
}

std::unique_ptr<SurfacerServer> SurfacerServer::start(const ServerOptions& options) {
  auto credentials = options.listen.empty() ? nullptr : server_credentials(options);
  auto impl = std::make_unique<Impl>(options);
  impl->restore();
  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  if (!options.listen.empty()) builder.AddListeningPort(options.listen, credentials, &impl->port);
  builder.RegisterService(&impl->service);
  impl->grpc_server = builder.BuildAndStart();
  if (!impl->grpc_server || (!options.listen.empty() && impl->port == 0)) {
    throw std::runtime_error("cannot listen on " + options.listen +
                             " (address in use or not valid?); choose another with --listen");
  }
  if (!options.health_listen.empty()) {
    grpc::ServerBuilder health_builder;
    health_builder.AddListeningPort(options.health_listen, grpc::InsecureServerCredentials(), &impl->health_port);
    impl->health_server = health_builder.BuildAndStart();
    if (!impl->health_server || impl->health_port == 0) {
      impl->grpc_server->Shutdown();
      throw std::runtime_error("cannot listen on " + options.health_listen + " (--health-listen)");
    }
  }
  impl->set_serving(true);
  if (!options.metrics_listen.empty())
    impl->metrics_http = MetricsHttpServer::start(impl->registry, options.metrics_listen);
  impl->janitor = std::thread([p = impl.get()] { p->janitor_loop(); });
  log_event(LogLevel::kInfo, "server_started",
            {{"listen", options.listen.empty() ? "in-process" : options.listen},
             {"port", std::to_string(impl->port)},
             {"workers", std::to_string(impl->threads)},
             {"tls", options.tls_cert_file.empty() ? "off" : (options.tls_client_ca_file.empty() ? "on" : "mutual")},
             {"auth", impl->auth ? std::to_string(impl->auth->size()) + " tokens" : "off"},
             {"data_dir", options.data_dir.empty() ? "memory-only" : options.data_dir},
             {"metrics_port", impl->metrics_http ? std::to_string(impl->metrics_http->port()) : "off"},
             {"health_port", impl->health_port != 0 ? std::to_string(impl->health_port) : "off"},
             {"version", std::string(build_version())}});
  return std::unique_ptr<SurfacerServer>(new SurfacerServer(std::move(impl)));
}

SurfacerServer::SurfacerServer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

SurfacerServer::~SurfacerServer() { shutdown(ShutdownMode::kCancel, std::chrono::milliseconds(0)); }

int SurfacerServer::port() const { return impl_->port; }

int SurfacerServer::health_port() const { return impl_->health_port; }

int SurfacerServer::metrics_port() const { return impl_->metrics_http ? impl_->metrics_http->port() : 0; }

std::string SurfacerServer::metrics_text() const { return impl_->registry.render(); }

void SurfacerServer::run_retention() { impl_->retention(); }

std::shared_ptr<grpc::Channel> SurfacerServer::in_process_channel() {
  return impl_->grpc_server->InProcessChannel(grpc::ChannelArguments());
}

void SurfacerServer::shutdown(ShutdownMode mode, std::chrono::milliseconds deadline) {
  {
    std::unique_lock lock(impl_->mutex);
    if (impl_->shutting_down) {
      impl_->cv.wait(lock, [&] { return impl_->done; });
      return;
    }
    impl_->shutting_down = true;
  }
  impl_->cv.notify_all();
  if (impl_->janitor.joinable()) impl_->janitor.join();
  Impl& s = *impl_;
  s.state.accepting.store(false);
  s.set_serving(false);
  log_event(LogLevel::kInfo, "server_stopping",
            {{"mode", mode == ShutdownMode::kDrain ? "drain" : "cancel"},
             {"active_jobs", std::to_string(s.scheduler.active_jobs())}});
  const auto until = std::chrono::steady_clock::now() + deadline;
  if (mode == ShutdownMode::kDrain) {
    while (s.scheduler.active_jobs() > 0 && std::chrono::steady_clock::now() < until) {
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
  }
  if (s.store) {
    // Durable: what is left stays in the store as it is, and the next server on this data dir resumes it (a
    // redeploy loses no work). Running tasks stop at their cancel token; the pool joins them below.
    s.scheduler.suspend_all();
  } else {
    s.scheduler.cancel_all("server shutting down");
    // Running frames see the cancel token within a fraction of a second.
    const auto cancel_until = std::chrono::steady_clock::now() + std::chrono::seconds(5);
    while (s.scheduler.active_jobs() > 0 && std::chrono::steady_clock::now() < cancel_until) {
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
  }
  // Watch streams of finished jobs end by themselves; give them a moment, then cancel what is left.
  s.grpc_server->Shutdown(std::chrono::system_clock::now() + std::chrono::seconds(2));
  if (s.health_server) s.health_server->Shutdown(std::chrono::system_clock::now());
  s.pool.stop();
  // A state the disk refused so far gets a last try; one still refused is lost with this process (the README says
  // what a client then sees).
  s.retry_pending_writes();
  for (const auto& job : s.scheduler.list()) {
    if (job->persist_pending()) {
      log_event(
          LogLevel::kError, "store_write_lost",
          {{"job", job->id()}, {"state", v1::JobState_Name(job->state())}, {"data_dir", s.state.options.data_dir}});
    }
  }
  if (s.metrics_http) s.metrics_http->stop();
  log_event(LogLevel::kInfo, "server_stopped");
  {
    std::lock_guard lock(s.mutex);
    s.done = true;
  }
  s.cv.notify_all();
}

void SurfacerServer::cancel_jobs(const std::string& reason) { impl_->scheduler.cancel_all(reason); }

void SurfacerServer::wait() {
  std::unique_lock lock(impl_->mutex);
  impl_->cv.wait(lock, [&] { return impl_->done; });
}

}  // namespace surfacer::server
