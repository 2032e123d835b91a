#include "server/store.h"

#include <fcntl.h>
#include <google/protobuf/descriptor.h>
#include <sqlite3.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <iterator>
#include <set>
#include <stdexcept>

#include "core/util/crc32.h"
#include "core/util/errors.h"
#include "wire/uploads.h"

namespace surfacer::server {
namespace {

namespace fs = std::filesystem;

// One prepared statement, finalized on scope exit.
class Stmt {
 public:
  Stmt(sqlite3* db, const char* sql) : db_(db) {
    if (sqlite3_prepare_v2(db, sql, -1, &stmt_, nullptr) != SQLITE_OK) {
      throw std::runtime_error(std::string("sqlite prepare: ") + sqlite3_errmsg(db) + " in: " + sql);
    }
  }
  ~Stmt() { sqlite3_finalize(stmt_); }
  Stmt(const Stmt&) = delete;
  Stmt& operator=(const Stmt&) = delete;

  Stmt& bind(int i, const std::string& s) {
    sqlite3_bind_text(stmt_, i, s.data(), static_cast<int>(s.size()), SQLITE_TRANSIENT);
    return *this;
  }
  Stmt& blob(int i, const std::string& s) {
    sqlite3_bind_blob(stmt_, i, s.data(), static_cast<int>(s.size()), SQLITE_TRANSIENT);
    return *this;
  }
  Stmt& bind(int i, std::int64_t v) {
    sqlite3_bind_int64(stmt_, i, v);
    return *this;
  }
  // Steps once: true while rows come back.
  bool step() {
    const int rc = sqlite3_step(stmt_);
    if (rc == SQLITE_ROW) return true;
    if (rc == SQLITE_DONE) return false;
    throw_sqlite(rc);
  }
  void run() {
    while (step()) {
    }
  }
  std::string text(int col) const {
    const auto* p = reinterpret_cast<const char*>(sqlite3_column_blob(stmt_, col));
    return p ? std::string(p, static_cast<std::size_t>(sqlite3_column_bytes(stmt_, col))) : std::string();
  }
  std::int64_t integer(int col) const { return sqlite3_column_int64(stmt_, col); }

  [[noreturn]] void throw_sqlite(int rc) const {
    const std::string message =
        std::string("the job database refused a write (") + sqlite3_errstr(rc) + ": " + sqlite3_errmsg(db_) + ")";
    if (rc == SQLITE_FULL || rc == SQLITE_IOERR || (rc & 0xFF) == SQLITE_IOERR || rc == SQLITE_READONLY ||
        (rc & 0xFF) == SQLITE_READONLY || rc == SQLITE_CANTOPEN) {
      throw ResourceLimit("data_dir", message + "; free disk space in the server's --data-dir");
    }
    throw Internal(message);
  }

 private:
  sqlite3* db_;
  sqlite3_stmt* stmt_ = nullptr;
};

// BEGIN IMMEDIATE ... COMMIT, rolled back unless committed.
class Transaction {
 public:
  explicit Transaction(sqlite3* db) : db_(db) { exec("BEGIN IMMEDIATE"); }
  ~Transaction() {
    if (!done_) sqlite3_exec(db_, "ROLLBACK", nullptr, nullptr, nullptr);
  }
  void commit() {
    exec("COMMIT");
    done_ = true;
  }

 private:
  void exec(const char* sql) {
    char* err = nullptr;
    const int rc = sqlite3_exec(db_, sql, nullptr, nullptr, &err);
    if (rc != SQLITE_OK) {
      const std::string message = err ? err : sqlite3_errstr(rc);
      sqlite3_free(err);
      if ((rc & 0xFF) == SQLITE_FULL || (rc & 0xFF) == SQLITE_IOERR) {
        throw ResourceLimit("data_dir", "the job database refused a write (" + message +
                                            "); free disk space in the server's --data-dir");
      }
      throw Internal("job database: " + message);
    }
  }
  sqlite3* db_;
  bool done_ = false;
};

std::int64_t now_unix() {
  return std::chrono::duration_cast<std::chrono::seconds>(std::chrono::system_clock::now().time_since_epoch()).count();
}

[[noreturn]] void throw_io(const std::string& what, const fs::path& path, int err) {
  throw ResourceLimit("data_dir", what + " " + path.string() + " failed: " + std::strerror(err) +
                                      "; free disk space in (or fix the permissions of) the server's --data-dir");
}

void fsync_dir(const fs::path& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd >= 0) {
    ::fsync(fd);
    ::close(fd);
  }
}

}  // namespace

bool Store::valid_id(const std::string& id) {
  if (id.size() != 18 || (id[0] != 'j' && id[0] != 'u') || id[1] != '-') return false;
  for (std::size_t i = 2; i < id.size(); ++i) {
    const char c = id[i];
    if (!((c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'))) return false;
  }
  return true;
}

Store::Store(fs::path dir) : dir_(std::move(dir)) {}

Store::~Store() {
  if (db_) sqlite3_close(db_);
  if (lock_fd_ >= 0) ::close(lock_fd_);  // releases the flock
}

std::unique_ptr<Store> Store::open(const fs::path& dir) {
  std::error_code ec;
  fs::create_directories(dir / "frames", ec);
  if (!ec) fs::create_directories(dir / "uploads", ec);
  if (ec) {
    throw std::runtime_error("data dir " + dir.string() + ": " + ec.message() +
                             "; choose a writable directory with --data-dir");
  }
  auto store = std::unique_ptr<Store>(new Store(fs::absolute(dir)));
  const fs::path lock_path = store->dir_ / "LOCK";
  store->lock_fd_ = ::open(lock_path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (store->lock_fd_ < 0) {
    throw std::runtime_error("data dir " + dir.string() + ": cannot create " + lock_path.string() + ": " +
                             std::strerror(errno) + "; choose a writable directory with --data-dir");
  }
  if (::flock(store->lock_fd_, LOCK_EX | LOCK_NB) != 0) {
    std::string holder(32, '\0');
    const ssize_t n = ::pread(store->lock_fd_, holder.data(), holder.size(), 0);
    holder.resize(n > 0 ? static_cast<std::size_t>(n) : 0);
    while (!holder.empty() && (holder.back() == '\n' || holder.back() == '\0')) holder.pop_back();
    throw std::runtime_error("data dir " + dir.string() + " is in use by another surfacer-server" +
                             (holder.empty() ? "" : " (pid " + holder + ")") + "; give each server its own --data-dir");
  }
  const std::string pid = std::to_string(::getpid()) + "\n";
  if (::ftruncate(store->lock_fd_, 0) == 0) (void)!::pwrite(store->lock_fd_, pid.data(), pid.size(), 0);
  const fs::path db_path = store->dir_ / "surfacer.db";
  if (sqlite3_open_v2(db_path.c_str(), &store->db_, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE | SQLITE_OPEN_FULLMUTEX,
                      nullptr) != SQLITE_OK) {
    const std::string message = store->db_ ? sqlite3_errmsg(store->db_) : "out of memory";
    throw std::runtime_error("cannot open the job database " + db_path.string() + ": " + message);
  }
  sqlite3_busy_timeout(store->db_, 5000);
  try {
    store->exec("PRAGMA journal_mode=WAL");
    store->exec("PRAGMA synchronous=FULL");
    store->exec("PRAGMA foreign_keys=ON");
    store->exec(
        "CREATE TABLE IF NOT EXISTS jobs(id TEXT PRIMARY KEY, owner TEXT NOT NULL, spec BLOB NOT NULL,"
        " snapshot BLOB NOT NULL, state INTEGER NOT NULL, created INTEGER NOT NULL);"
        "CREATE TABLE IF NOT EXISTS frames(job_id TEXT NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,"
        " frame_index INTEGER NOT NULL, header BLOB NOT NULL, bytes INTEGER NOT NULL,"
        " PRIMARY KEY(job_id, frame_index));"
        "CREATE TABLE IF NOT EXISTS tasks_done(job_id TEXT NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,"
        " task INTEGER NOT NULL, PRIMARY KEY(job_id, task));"
        "CREATE TABLE IF NOT EXISTS checkpoints(job_id TEXT NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,"
        " task INTEGER NOT NULL, next_frame INTEGER NOT NULL, bytes INTEGER NOT NULL, crc32 INTEGER NOT NULL,"
        " PRIMARY KEY(job_id, task));"
        "CREATE TABLE IF NOT EXISTS uploads(id TEXT PRIMARY KEY, owner TEXT NOT NULL, name TEXT NOT NULL,"
        " bytes INTEGER NOT NULL, crc32 INTEGER NOT NULL, created INTEGER NOT NULL);");
  } catch (const std::exception& e) {
    throw std::runtime_error("job database " + db_path.string() + ": " + e.what());
  }
  store->remove_orphans();
  return store;
}

void Store::exec(const char* sql) const {
  char* err = nullptr;
  if (sqlite3_exec(db_, sql, nullptr, nullptr, &err) != SQLITE_OK) {
    const std::string message = err ? err : "unknown error";
    sqlite3_free(err);
    throw std::runtime_error(message);
  }
}

fs::path Store::frame_path(const std::string& job_id, int index) const {
  if (!valid_id(job_id) || index < 0) throw Internal("store: bad frame key " + job_id);
  return dir_ / "frames" / job_id / (std::to_string(index) + ".frame");
}

fs::path Store::checkpoint_path(const std::string& job_id, int task, int next_frame) const {
  if (!valid_id(job_id) || task < 0 || next_frame < 0) throw Internal("store: bad checkpoint key " + job_id);
  return dir_ / "frames" / job_id / ("task" + std::to_string(task) + "." + std::to_string(next_frame) + ".checkpoint");
}

fs::path Store::upload_path(const std::string& id) const {
  if (!valid_id(id)) throw Internal("store: bad upload id");
  return dir_ / "uploads" / (id + ".bin");
}

void Store::write_file_atomic(const fs::path& path, const std::string& bytes, const RunControl& control) const {
  std::string tmp_name = path.filename().string();
  tmp_name.append(".tmp");
  tmp_name.insert(tmp_name.begin(), '.');
  const fs::path tmp = path.parent_path() / tmp_name;
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0640);
  if (fd < 0) throw_io("creating", tmp, errno);
  constexpr std::size_t kPiece = std::size_t{4} << 20;  // between cancel checks
  std::size_t done = 0;
  while (done < bytes.size()) {
    if (control.cancelled()) {
      ::close(fd);
      ::unlink(tmp.c_str());
      throw Cancelled();
    }
    const ssize_t n = ::write(fd, bytes.data() + done, std::min(kPiece, bytes.size() - done));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const int err = n < 0 ? errno : ENOSPC;
      ::close(fd);
      ::unlink(tmp.c_str());
      throw_io("writing", tmp, err);
    }
    done += static_cast<std::size_t>(n);
  }
  if (::fsync(fd) != 0 || ::close(fd) != 0) {
    const int err = errno;
    ::unlink(tmp.c_str());
    throw_io("syncing", tmp, err);
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    const int err = errno;
    ::unlink(tmp.c_str());
    throw_io("renaming", tmp, err);
  }
  fsync_dir(path.parent_path());
}

void Store::remove_orphans() {
  std::set<std::string> frame_files, upload_files;
  {
    Stmt s(db_, "SELECT job_id, frame_index FROM frames");
    while (s.step()) frame_files.insert(s.text(0) + "/" + std::to_string(s.integer(1)) + ".frame");
  }
  {
    Stmt s(db_, "SELECT job_id, task, next_frame FROM checkpoints");
    while (s.step()) {
      frame_files.insert(s.text(0) + "/task" + std::to_string(s.integer(1)) + "." + std::to_string(s.integer(2)) +
                         ".checkpoint");
    }
  }
  {
    Stmt s(db_, "SELECT id FROM uploads");
    while (s.step()) upload_files.insert(s.text(0) + ".bin");
  }
  std::error_code ec;
  for (const auto& job_dir : fs::directory_iterator(dir_ / "frames", ec)) {
    for (const auto& f : fs::directory_iterator(job_dir.path(), ec)) {
      const std::string key = job_dir.path().filename().string() + "/" + f.path().filename().string();
      if (!frame_files.count(key)) fs::remove(f.path(), ec);
    }
    if (fs::is_empty(job_dir.path(), ec)) fs::remove(job_dir.path(), ec);
  }
  for (const auto& f : fs::directory_iterator(dir_ / "uploads", ec)) {
    if (!upload_files.count(f.path().filename().string())) fs::remove(f.path(), ec);
  }
}

void Store::put_job(const std::string& id, const std::string& owner, const v1::JobSpec& spec, const v1::Job& snapshot) {
  if (!valid_id(id)) throw Internal("store: bad job id");
  std::lock_guard lock(mutex_);
  Stmt s(db_, "INSERT INTO jobs(id, owner, spec, snapshot, state, created) VALUES(?,?,?,?,?,?)");
  s.bind(1, id).bind(2, owner).blob(3, spec.SerializeAsString()).blob(4, snapshot.SerializeAsString());
  s.bind(5, static_cast<std::int64_t>(snapshot.state())).bind(6, now_unix());
  s.run();
}

void Store::update_job(const v1::Job& snapshot) {
  std::lock_guard lock(mutex_);
  Stmt s(db_, "UPDATE jobs SET snapshot = ?, state = ? WHERE id = ?");
  s.blob(1, snapshot.SerializeAsString()).bind(2, static_cast<std::int64_t>(snapshot.state())).bind(3, snapshot.id());
  s.run();
}

void Store::update_job_spec(const std::string& id, const v1::JobSpec& spec) {
  std::lock_guard lock(mutex_);
  Stmt s(db_, "UPDATE jobs SET spec = ? WHERE id = ?");
  s.blob(1, spec.SerializeAsString()).bind(2, id);
  s.run();
}

void Store::put_frame(const std::string& job_id, const v1::FrameHeader& header, const std::string& bytes,
                      const RunControl& control) {
  const fs::path path = frame_path(job_id, header.frame_index());
  std::error_code ec;
  fs::create_directories(path.parent_path(), ec);
  if (ec) throw_io("creating", path.parent_path(), ec.value());
  write_file_atomic(path, bytes, control);
  try {
    std::lock_guard lock(mutex_);
    Transaction tx(db_);
    Stmt s(db_, "INSERT OR REPLACE INTO frames(job_id, frame_index, header, bytes) VALUES(?,?,?,?)");
    s.bind(1, job_id).bind(2, static_cast<std::int64_t>(header.frame_index()));
    s.blob(3, header.SerializeAsString()).bind(4, static_cast<std::int64_t>(bytes.size()));
    s.run();
    tx.commit();
  } catch (...) {
    fs::remove(path, ec);  // no row: the file must not stay
    throw;
  }
}

std::string Store::read_frame_range(const std::string& job_id, const v1::FrameHeader& header, std::uint64_t offset,
                                    std::size_t length) const {
  const fs::path path = frame_path(job_id, header.frame_index());
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) {
    throw std::runtime_error("frame " + std::to_string(header.frame_index()) + " of job " + job_id +
                             " is no longer stored (removed by retention?)");
  }
  struct stat info {};
  const bool sized = ::fstat(fd, &info) == 0 && static_cast<std::uint64_t>(info.st_size) == header.total_bytes() &&
                     offset + length <= header.total_bytes();
  std::string bytes(sized ? length : 0, '\0');
  std::size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::pread(fd, bytes.data() + done, bytes.size() - done, static_cast<off_t>(offset + done));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    done += static_cast<std::size_t>(n);
  }
  ::close(fd);
  if (!sized || done != length) {
    throw std::runtime_error("frame " + std::to_string(header.frame_index()) + " of job " + job_id +
                             " is damaged on disk (size mismatch)");
  }
  return bytes;
}

void Store::put_task_done(const std::string& job_id, int task) {
  std::lock_guard lock(mutex_);
  Stmt s(db_, "INSERT OR IGNORE INTO tasks_done(job_id, task) VALUES(?,?)");
  s.bind(1, job_id).bind(2, static_cast<std::int64_t>(task));
  s.run();
}

void Store::put_checkpoint(const std::string& job_id, int task, int next_frame, const std::string& state) {
  // A new file per checkpoint (named by its frame), then the row switches to it, then the old file goes: a crash
  // anywhere leaves the row naming a complete file.
  const fs::path path = checkpoint_path(job_id, task, next_frame);
  std::error_code ec;
  fs::create_directories(path.parent_path(), ec);
  if (ec) throw_io("creating", path.parent_path(), ec.value());
  write_file_atomic(path, state);
  std::int64_t previous = -1;
  try {
    std::lock_guard lock(mutex_);
    Transaction tx(db_);
    {
      Stmt q(db_, "SELECT next_frame FROM checkpoints WHERE job_id = ? AND task = ?");
      q.bind(1, job_id).bind(2, static_cast<std::int64_t>(task));
      if (q.step()) previous = q.integer(0);
    }
    Stmt s(db_, "INSERT OR REPLACE INTO checkpoints(job_id, task, next_frame, bytes, crc32) VALUES(?,?,?,?,?)");
    s.bind(1, job_id).bind(2, static_cast<std::int64_t>(task)).bind(3, static_cast<std::int64_t>(next_frame));
    s.bind(4, static_cast<std::int64_t>(state.size()));
    s.bind(5, static_cast<std::int64_t>(crc32_of(state.data(), state.size())));
    s.run();
    tx.commit();
  } catch (...) {
    fs::remove(path, ec);
    throw;
  }
  if (previous >= 0 && previous != next_frame)
    fs::remove(checkpoint_path(job_id, task, static_cast<int>(previous)), ec);
}

void Store::delete_job(const std::string& id) {
  if (!valid_id(id)) return;
  {
    std::lock_guard lock(mutex_);
    Transaction tx(db_);
    Stmt(db_, "DELETE FROM frames WHERE job_id = ?").bind(1, id).run();
    Stmt(db_, "DELETE FROM tasks_done WHERE job_id = ?").bind(1, id).run();
    Stmt(db_, "DELETE FROM checkpoints WHERE job_id = ?").bind(1, id).run();
    Stmt(db_, "DELETE FROM jobs WHERE id = ?").bind(1, id).run();
    tx.commit();
  }
  std::error_code ec;
  fs::remove_all(dir_ / "frames" / id, ec);
}

std::vector<StoredJob> Store::load_jobs() const {
  std::lock_guard lock(mutex_);
  std::vector<StoredJob> jobs;
  std::map<std::string, std::size_t> at;
  {
    Stmt s(db_, "SELECT id, owner, spec, snapshot FROM jobs ORDER BY created, rowid");
    while (s.step()) {
      StoredJob job;
      job.id = s.text(0);
      job.owner = s.text(1);
      if (!job.spec.ParseFromString(s.text(2)) || !job.snapshot.ParseFromString(s.text(3))) continue;
      job.upload_ids = referenced_uploads(job.spec);
      at[job.id] = jobs.size();
      jobs.push_back(std::move(job));
    }
  }
  {
    Stmt s(db_, "SELECT job_id, header FROM frames ORDER BY rowid");
    while (s.step()) {
      auto it = at.find(s.text(0));
      v1::FrameHeader header;
      if (it != at.end() && header.ParseFromString(s.text(1))) jobs[it->second].frames.push_back(std::move(header));
    }
  }
  {
    Stmt s(db_, "SELECT job_id, task FROM tasks_done");
    while (s.step()) {
      auto it = at.find(s.text(0));
      if (it != at.end()) jobs[it->second].tasks_done.push_back(static_cast<int>(s.integer(1)));
    }
  }
  {
    Stmt s(db_, "SELECT job_id, task, next_frame, bytes, crc32 FROM checkpoints");
    while (s.step()) {
      auto it = at.find(s.text(0));
      if (it == at.end()) continue;
      StoredJob::Checkpoint c;
      c.task = static_cast<int>(s.integer(1));
      c.next_frame = static_cast<int>(s.integer(2));
      // A checkpoint that does not read back whole is ignored: the task then starts over.
      std::ifstream in(checkpoint_path(it->first, c.task, c.next_frame), std::ios::binary);
      c.state.assign(std::istreambuf_iterator<char>(in), {});
      if (static_cast<std::int64_t>(c.state.size()) != s.integer(3) ||
          crc32_of(c.state.data(), c.state.size()) != static_cast<std::uint32_t>(s.integer(4))) {
        continue;
      }
      jobs[it->second].checkpoints.push_back(std::move(c));
    }
  }
  return jobs;
}

void Store::put_upload(const std::string& id, const std::string& owner, const UploadBlob& blob) {
  const fs::path path = upload_path(id);
  write_file_atomic(path, blob.bytes);
  try {
    std::lock_guard lock(mutex_);
    Stmt s(db_, "INSERT INTO uploads(id, owner, name, bytes, crc32, created) VALUES(?,?,?,?,?,?)");
    s.bind(1, id).bind(2, owner).bind(3, blob.name).bind(4, static_cast<std::int64_t>(blob.bytes.size()));
    s.bind(5, static_cast<std::int64_t>(blob.crc32)).bind(6, now_unix());
    s.run();
  } catch (...) {
    std::error_code ec;
    fs::remove(path, ec);
    throw;
  }
}

std::shared_ptr<UploadBlob> Store::load_upload(const std::string& id, std::string* owner) const {
  if (!valid_id(id)) return nullptr;
  auto blob = std::make_shared<UploadBlob>();
  std::int64_t size = 0;
  {
    std::lock_guard lock(mutex_);
    Stmt s(db_, "SELECT owner, name, bytes, crc32 FROM uploads WHERE id = ?");
    s.bind(1, id);
    if (!s.step()) return nullptr;
    if (owner) *owner = s.text(0);
    blob->name = s.text(1);
    size = s.integer(2);
    blob->crc32 = static_cast<std::uint32_t>(s.integer(3));
  }
  const fs::path path = upload_path(id);
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return nullptr;
  blob->bytes.resize(static_cast<std::size_t>(size));
  std::size_t done = 0;
  while (done < blob->bytes.size()) {
    const ssize_t n = ::read(fd, blob->bytes.data() + done, blob->bytes.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    done += static_cast<std::size_t>(n);
  }
  ::close(fd);
  if (done != blob->bytes.size() || crc32_of(blob->bytes.data(), blob->bytes.size()) != blob->crc32) return nullptr;
  return blob;
}

void Store::delete_upload(const std::string& id) {
  if (!valid_id(id)) return;
  {
    std::lock_guard lock(mutex_);
    Stmt(db_, "DELETE FROM uploads WHERE id = ?").bind(1, id).run();
  }
  std::error_code ec;
  fs::remove(upload_path(id), ec);
}

std::vector<StoredUpload> Store::list_uploads() const {
  std::lock_guard lock(mutex_);
  std::vector<StoredUpload> out;
  Stmt s(db_, "SELECT id, owner, name, bytes, created FROM uploads ORDER BY created, rowid");
  while (s.step()) out.push_back({s.text(0), s.text(1), s.text(2), s.integer(3), s.integer(4)});
  return out;
}

void Store::reclaim() {
  std::lock_guard lock(mutex_);
  sqlite3_wal_checkpoint_v2(db_, nullptr, SQLITE_CHECKPOINT_TRUNCATE, nullptr, nullptr);
}

std::int64_t Store::total_bytes() const {
  std::lock_guard lock(mutex_);
  Stmt s(db_, "SELECT (SELECT COALESCE(SUM(bytes),0) FROM frames) + (SELECT COALESCE(SUM(bytes),0) FROM uploads)");
  return s.step() ? s.integer(0) : 0;
}

std::map<std::string, std::int64_t> Store::bytes_by_owner() const {
  std::lock_guard lock(mutex_);
  std::map<std::string, std::int64_t> out;
  Stmt f(db_, "SELECT jobs.owner, SUM(frames.bytes) FROM frames JOIN jobs ON jobs.id = frames.job_id GROUP BY 1");
  while (f.step()) out[f.text(0)] += f.integer(1);
  Stmt u(db_, "SELECT owner, SUM(bytes) FROM uploads GROUP BY 1");
  while (u.step()) out[u.text(0)] += u.integer(1);
  return out;
}

std::int64_t Store::job_bytes(const std::string& id) const {
  std::lock_guard lock(mutex_);
  Stmt s(db_, "SELECT COALESCE(SUM(bytes),0) FROM frames WHERE job_id = ?");
  s.bind(1, id);
  return s.step() ? s.integer(0) : 0;
}

std::vector<std::string> Store::referenced_uploads(const google::protobuf::Message& message) {
  std::vector<std::string> out;
  for (auto& [path, id] : referenced_upload_fields(message, "")) out.push_back(std::move(id));
  return out;
}

std::vector<std::pair<std::string, std::string>> Store::referenced_upload_fields(
    const google::protobuf::Message& message, const std::string& prefix) {
  std::vector<std::pair<std::string, std::string>> out;
  const auto* descriptor = message.GetDescriptor();
  const auto* reflection = message.GetReflection();
  using FD = google::protobuf::FieldDescriptor;
  auto append = [&](std::vector<std::pair<std::string, std::string>> sub) {
    out.insert(out.end(), std::make_move_iterator(sub.begin()), std::make_move_iterator(sub.end()));
  };
  for (int i = 0; i < descriptor->field_count(); ++i) {
    const FD* field = descriptor->field(i);
    const std::string path = prefix.empty() ? field->name() : prefix + "." + field->name();
    const bool is_upload = field->type() == FD::TYPE_STRING && field->name().size() >= 9 &&
                           field->name().compare(field->name().size() - 9, 9, "upload_id") == 0;
    if (field->is_repeated()) {
      const int n = reflection->FieldSize(message, field);
      for (int k = 0; k < n; ++k) {
        const std::string item = path + "[" + std::to_string(k) + "]";
        if (field->type() == FD::TYPE_MESSAGE) {
          append(referenced_upload_fields(reflection->GetRepeatedMessage(message, field, k), item));
        } else if (is_upload) {
          out.emplace_back(item, reflection->GetRepeatedString(message, field, k));
        }
      }
    } else if (field->type() == FD::TYPE_MESSAGE) {
      if (reflection->HasField(message, field))
        append(referenced_upload_fields(reflection->GetMessage(message, field), path));
    } else if (is_upload) {
      std::string v = reflection->GetString(message, field);
      if (!v.empty()) out.emplace_back(path, std::move(v));
    }
  }
  return out;
}

}  // namespace surfacer::server
