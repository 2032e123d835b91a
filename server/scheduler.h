// The scheduler: owns the jobs and runs their tasks on the worker pool, round-robin across running jobs, so a long
// sequence does not starve a short job.
#pragma once

#include <chrono>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "server/job.h"

namespace surfacer::server {

class WorkerPool;

// Owns the jobs and runs their tasks on the pool, round-robin across running jobs.
class Scheduler {
 public:
  Scheduler(WorkerPool& pool, int max_queued_jobs);

  // Throws surfacer::Error(kResourceLimit) when max_queued_jobs jobs are already waiting. `check_owner` (when set) is
  // called with the number of the job's owner's unfinished jobs under the same lock that adds the job, so a quota it
  // enforces by throwing holds however many submits race (the job is not added then).
  void submit(std::shared_ptr<Job> job, const std::function<void(int active)>& check_owner = {});
  // A job restored from the store: runs `tasks` (finished jobs: none; they are only kept for watching).
  void resume(std::shared_ptr<Job> job, std::vector<int> tasks);
  // Tasks that joined a running job (an open sequence's new frames), queued behind the other jobs' tasks.
  void add_tasks(const std::shared_ptr<Job>& job, std::vector<int> tasks);
  std::shared_ptr<Job> find(const std::string& id) const;
  std::vector<std::shared_ptr<Job>> list() const;
  int queued_jobs() const;
  // Jobs not yet finished.
  int active_jobs() const;
  void cancel_all(const std::string& reason);
  // Suspends every unfinished job (see Job::suspend).
  void suspend_all();
  // Jobs of `owner` not yet finished.
  int active_jobs(const std::string& owner) const;
  // Forgets finished jobs older than `age`; returns them.
  std::vector<std::shared_ptr<Job>> forget_finished(std::chrono::seconds age);
  // Forgets one finished job.
  void forget(const std::string& id);

 private:
  void run_next_task();

  WorkerPool& pool_;
  const int max_queued_jobs_;
  mutable std::mutex mutex_;
  std::map<std::string, std::shared_ptr<Job>> jobs_;
  std::vector<std::string> order_;  // submission order, for list()
  struct Pending {
    std::shared_ptr<Job> job;
    std::vector<int> tasks;
    std::size_t next = 0;
  };
  std::deque<Pending> pending_;  // jobs with tasks not yet started, round-robin
};

}  // namespace surfacer::server
