// The scheduler: owns the jobs and runs their tasks on the worker pool, round-robin across running jobs, so a long
// sequence does not starve a short job.
#pragma once

#include <chrono>
#include <deque>
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

  // Throws surfacer::Error(kResourceLimit) when max_queued_jobs jobs are already waiting.
  void submit(std::shared_ptr<Job> job);
  // A job restored from the store: runs `tasks` (finished jobs: none; they are only kept for watching).
  void resume(std::shared_ptr<Job> job, std::vector<int> tasks);
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
