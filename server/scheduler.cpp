#include "server/scheduler.h"

#include <grpcpp/support/status.h>

#include "core/util/errors.h"
#include "server/log.h"
#include "server/status_map.h"
#include "server/worker_pool.h"

namespace surfacer::server {

Scheduler::Scheduler(WorkerPool& pool, int max_queued_jobs) : pool_(pool), max_queued_jobs_(max_queued_jobs) {}

void Scheduler::submit(std::shared_ptr<Job> job, const std::function<void(int active)>& check_owner) {
  const int tasks = job->runner().task_count();
  {
    std::lock_guard lock(mutex_);
    if (check_owner) {
      int active = 0;
      for (const auto& [id, other] : jobs_) {
        if (other->owner() == job->owner() && !other->terminal()) ++active;
      }
      check_owner(active);
    }
    int queued = 0;
    for (const auto& p : pending_) {
      if (p.job->state() == v1::JOB_STATE_QUEUED) ++queued;
    }
    if (queued >= max_queued_jobs_) {
      throw ResourceLimit("max_queued_jobs", "the job queue is full (" + std::to_string(queued) +
                                                 " jobs waiting); retry later, or start the server with a larger "
                                                 "--max-queued-jobs");
    }
    jobs_.emplace(job->id(), job);
    order_.push_back(job->id());
    std::vector<int> all(tasks);
    for (int i = 0; i < tasks; ++i) all[i] = i;
    pending_.push_back({job, std::move(all), 0});
  }
  log_event(LogLevel::kInfo, "job_submitted",
            {{"job", job->id()},
             {"kind", job->runner().kind()},
             {"tasks", std::to_string(tasks)},
             {"frames", std::to_string(job->runner().frame_count())}});
  for (int i = 0; i < tasks; ++i) pool_.post([this] { run_next_task(); });
}

void Scheduler::resume(std::shared_ptr<Job> job, std::vector<int> tasks) {
  const int n = static_cast<int>(tasks.size());
  {
    std::lock_guard lock(mutex_);
    jobs_.emplace(job->id(), job);
    order_.push_back(job->id());
    if (n > 0) pending_.push_back({job, std::move(tasks), 0});
  }
  if (n > 0) {
    log_event(LogLevel::kInfo, "job_resumed",
              {{"job", job->id()}, {"kind", job->kind()}, {"tasks", std::to_string(n)}});
  }
  for (int i = 0; i < n; ++i) pool_.post([this] { run_next_task(); });
}

void Scheduler::add_tasks(const std::shared_ptr<Job>& job, std::vector<int> tasks) {
  const int n = static_cast<int>(tasks.size());
  if (n == 0) return;
  {
    std::lock_guard lock(mutex_);
    pending_.push_back({job, std::move(tasks), 0});
  }
  for (int i = 0; i < n; ++i) pool_.post([this] { run_next_task(); });
}

void Scheduler::run_next_task() {
  std::shared_ptr<Job> job;
  int task = -1;
  {
    std::lock_guard lock(mutex_);
    // Round-robin: take one task of the job at the front, then move the job to the back.
    while (!pending_.empty()) {
      Pending p = std::move(pending_.front());
      pending_.pop_front();
      if (p.job->terminal() || p.next >= p.tasks.size()) continue;
      job = p.job;
      task = p.tasks[p.next++];
      if (p.next < p.tasks.size()) pending_.push_back(std::move(p));
      break;
    }
  }
  if (!job) return;
  if (!job->task_started()) {
    job->task_skipped();
    return;
  }
  RunControl control;
  control.cancel = &job->cancel_token();
  control.progress = [job = job.get(), task](std::string_view stage, double fraction) {
    job->set_progress(task, stage, fraction);
  };
  try {
    job->runner().run_task(task, *job, control);
    job->task_succeeded(task);
  } catch (...) {
    const grpc::Status status = status_from_exception(std::current_exception());
    job->task_failed(task, status.error_code(), status.error_message());
  }
}

std::shared_ptr<Job> Scheduler::find(const std::string& id) const {
  std::lock_guard lock(mutex_);
  auto it = jobs_.find(id);
  return it == jobs_.end() ? nullptr : it->second;
}

std::vector<std::shared_ptr<Job>> Scheduler::list() const {
  std::lock_guard lock(mutex_);
  std::vector<std::shared_ptr<Job>> out;
  out.reserve(order_.size());
  for (const auto& id : order_) {
    auto it = jobs_.find(id);
    if (it != jobs_.end()) out.push_back(it->second);
  }
  return out;
}

int Scheduler::queued_jobs() const {
  int n = 0;
  for (const auto& job : list()) {
    if (job->state() == v1::JOB_STATE_QUEUED) ++n;
  }
  return n;
}

int Scheduler::active_jobs() const {
  int n = 0;
  for (const auto& job : list()) {
    if (!job->terminal()) ++n;
  }
  return n;
}

void Scheduler::cancel_all(const std::string& reason) {
  for (const auto& job : list()) job->cancel(reason);
}

void Scheduler::suspend_all() {
  for (const auto& job : list()) job->suspend();
}

int Scheduler::active_jobs(const std::string& owner) const {
  int n = 0;
  for (const auto& job : list()) {
    if (job->owner() == owner && !job->terminal()) ++n;
  }
  return n;
}

std::vector<std::shared_ptr<Job>> Scheduler::forget_finished(std::chrono::seconds age) {
  const auto cutoff = std::chrono::steady_clock::now() - age;
  std::vector<std::shared_ptr<Job>> gone;
  std::lock_guard lock(mutex_);
  std::erase_if(order_, [&](const std::string& id) {
    auto it = jobs_.find(id);
    if (it == jobs_.end()) return true;
    if (it->second->terminal() && it->second->finished_at() < cutoff) {
      gone.push_back(it->second);
      jobs_.erase(it);
      return true;
    }
    return false;
  });
  return gone;
}

void Scheduler::forget(const std::string& id) {
  std::lock_guard lock(mutex_);
  jobs_.erase(id);
  std::erase(order_, id);
}

}  // namespace surfacer::server
