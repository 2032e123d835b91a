// The durable job store: SQLite (job specs, snapshots, frame headers, finished tasks, upload records) plus a data
// directory holding the bytes (uploads/<id>.bin, frames/<job>/<index>.frame). Every file is written to a temporary
// name, fsync'ed and renamed before its row is committed, so a crash (kill -9 included) or a failed write (disk
// full) leaves either the old state or the new one, never a row without its bytes. Files without a row (a crash
// between rename and commit) are removed when the store opens.
//
// Only ids the server generated ("j-" / "u-" + 16 hex digits) ever become file names: nothing a client sends
// can name a path, so nothing is read or written outside the data directory.
#pragma once

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "core/util/run_control.h"
#include "surfacer/v1/surfacer.pb.h"

struct sqlite3;

namespace surfacer::wire {
struct UploadBlob;
}

namespace surfacer::server {

using wire::UploadBlob;

// A job as found in the store when the server starts.
struct StoredJob {
  std::string id;
  std::string owner;
  v1::JobSpec spec;
  v1::Job snapshot;                     // last persisted state (terminal ones are final)
  std::vector<v1::FrameHeader> frames;  // in completion order
  std::vector<int> tasks_done;
  struct Checkpoint {
    int task = 0;
    int next_frame = 0;
    std::string state;
  };
  std::vector<Checkpoint> checkpoints;  // the latest of each evolving task
  std::vector<std::string> upload_ids;  // uploads the spec refers to
};

struct StoredUpload {
  std::string id;
  std::string owner;
  std::string name;
  std::int64_t bytes = 0;
  std::int64_t created_unix = 0;
};

class Store {
 public:
  // Opens (creating if needed) `dir`/surfacer.db and the data folders; removes leftovers of interrupted writes.
  // Throws std::runtime_error naming the path when the directory or the database cannot be used, or when another
  // server holds the directory (each server needs its own; two would resume the same jobs).
  static std::unique_ptr<Store> open(const std::filesystem::path& dir);
  ~Store();

  const std::filesystem::path& dir() const { return dir_; }

  // --- Jobs -------------------------------------------------------------------------------------------------
  // Every write throws surfacer::ResourceLimit("data_dir", ...) when the disk refuses it (full, quota, I/O error);
  // the store is unchanged then.
  void put_job(const std::string& id, const std::string& owner, const v1::JobSpec& spec, const v1::Job& snapshot);
  void update_job(const v1::Job& snapshot);
  // Replaces a job's spec (an open sequence's, as frames join it).
  void update_job_spec(const std::string& id, const v1::JobSpec& spec);
  // Writes the frame's bytes and records its header, atomically. The bytes go out in pieces of a few MiB and
  // `control` is checked between them: a cancel leaves nothing stored and throws Cancelled.
  void put_frame(const std::string& job_id, const v1::FrameHeader& header, const std::string& bytes,
                 const RunControl& control = {});
  // Reads `length` bytes at `offset` of a stored frame (one chunk of a WatchJob stream, so a stream holds a chunk,
  // never the whole frame), checking the file's size against the header; the caller checks the CRC-32s. Throws
  // std::runtime_error when the frame is gone (retention), has the wrong size, or the range lies outside it.
  std::string read_frame_range(const std::string& job_id, const v1::FrameHeader& header, std::uint64_t offset,
                               std::size_t length) const;
  void put_task_done(const std::string& job_id, int task);
  // Replaces the task's resumable state (FrameSink::checkpoint), atomically.
  void put_checkpoint(const std::string& job_id, int task, int next_frame, const std::string& state);
  void delete_job(const std::string& id);
  std::vector<StoredJob> load_jobs() const;

  // --- Uploads ----------------------------------------------------------------------------------------------
  void put_upload(const std::string& id, const std::string& owner, const UploadBlob& blob);
  // nullptr when no such upload is stored.
  std::shared_ptr<UploadBlob> load_upload(const std::string& id, std::string* owner = nullptr) const;
  void delete_upload(const std::string& id);
  std::vector<StoredUpload> list_uploads() const;

  // After a write the disk refused: moves the WAL's pages into the database file and truncates the WAL, which gives
  // back its space (best effort; nothing changes when it cannot).
  void reclaim();

  // --- Accounting -------------------------------------------------------------------------------------------
  std::int64_t total_bytes() const;
  // Bytes stored per owner (uploads + frames).
  std::map<std::string, std::int64_t> bytes_by_owner() const;
  std::int64_t job_bytes(const std::string& id) const;

  // The ids of the uploads a spec refers to (every `*upload_id` string field, found by reflection).
  static std::vector<std::string> referenced_uploads(const google::protobuf::Message& spec);
  // The same, with each one's field path from `prefix` ("spec.particles.frames[3].upload_id").
  static std::vector<std::pair<std::string, std::string>> referenced_upload_fields(
      const google::protobuf::Message& message, const std::string& prefix);
  // "j-0123456789abcdef" / "u-..." as generated by the server.
  static bool valid_id(const std::string& id);

 private:
  explicit Store(std::filesystem::path dir);
  void exec(const char* sql) const;
  void write_file_atomic(const std::filesystem::path& path, const std::string& bytes,
                         const RunControl& control = {}) const;
  std::filesystem::path frame_path(const std::string& job_id, int index) const;
  std::filesystem::path checkpoint_path(const std::string& job_id, int task, int next_frame) const;
  std::filesystem::path upload_path(const std::string& id) const;
  void remove_orphans();

  std::filesystem::path dir_;
  int lock_fd_ = -1;  // flock'ed DIR/LOCK: one server per data directory
  sqlite3* db_ = nullptr;
  mutable std::mutex mutex_;
};

}  // namespace surfacer::server
