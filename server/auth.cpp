#include "server/auth.h"

#include <fstream>
#include <sstream>
#include <stdexcept>

namespace surfacer::server {
namespace {

bool constant_time_equal(std::string_view a, std::string_view b) {
  unsigned char diff = a.size() == b.size() ? 0 : 1;
  const std::size_t n = a.size();
  for (std::size_t i = 0; i < n; ++i) {
    diff |= static_cast<unsigned char>(a[i] ^ (i < b.size() ? b[i] : 0));
  }
  return diff == 0;
}

std::int64_t parse_count(const std::string& value, const std::string& where) {
  std::size_t pos = 0;
  long long v = -1;
  try {
    v = std::stoll(value, &pos);
  } catch (...) {
    pos = 0;
  }
  if (pos != value.size() || v < 0) throw std::runtime_error(where + ": '" + value + "' is not a count >= 0");
  return v;
}

}  // namespace

std::unique_ptr<TokenAuth> TokenAuth::load(const std::filesystem::path& file) {
  std::ifstream in(file);
  if (!in) throw std::runtime_error("--tokens-file " + file.string() + ": cannot be read");
  std::stringstream text;
  text << in.rdbuf();
  return parse(text.str(), file.string());
}

std::unique_ptr<TokenAuth> TokenAuth::parse(const std::string& text, const std::string& origin) {
  auto auth = std::make_unique<TokenAuth>();
  std::map<std::string, std::shared_ptr<const Tenant>> tenants;
  std::istringstream lines(text);
  std::string line;
  int number = 0;
  while (std::getline(lines, line)) {
    ++number;
    if (const auto hash = line.find('#'); hash != std::string::npos) line.resize(hash);
    std::istringstream words(line);
    std::string token, tenant_name, word;
    if (!(words >> token)) continue;
    const std::string where = origin + ":" + std::to_string(number);
    if (!(words >> tenant_name)) throw std::runtime_error(where + ": expected `TOKEN TENANT [running=N] [bytes=N]`");
    if (token.size() < 16) {
      throw std::runtime_error(where +
                               ": token shorter than 16 characters; use a long random token (e.g. "
                               "`openssl rand -hex 32`)");
    }
    Tenant tenant{tenant_name};
    while (words >> word) {
      const auto eq = word.find('=');
      const std::string key = word.substr(0, eq);
      const std::string value = eq == std::string::npos ? "" : word.substr(eq + 1);
      if (key == "running") {
        tenant.max_running_jobs = static_cast<int>(parse_count(value, where + " running"));
      } else if (key == "bytes") {
        tenant.max_stored_bytes = parse_count(value, where + " bytes");
      } else {
        throw std::runtime_error(where + ": unknown quota '" + word + "' (known: running=N, bytes=N)");
      }
    }
    for (const auto& e : auth->entries_) {
      if (e.token == token) throw std::runtime_error(where + ": token repeated");
    }
    auto it = tenants.find(tenant_name);
    if (it == tenants.end()) it = tenants.emplace(tenant_name, std::make_shared<const Tenant>(tenant)).first;
    auth->entries_.push_back({token, it->second});
  }
  if (auth->entries_.empty()) throw std::runtime_error(origin + ": no tokens (lines `TOKEN TENANT ...`)");
  return auth;
}

const Tenant* TokenAuth::authenticate(std::string_view authorization) const {
  constexpr std::string_view kBearer = "Bearer ";
  if (authorization.size() <= kBearer.size() || authorization.substr(0, kBearer.size()) != kBearer) return nullptr;
  const std::string_view token = authorization.substr(kBearer.size());
  const Tenant* found = nullptr;
  for (const auto& e : entries_) {  // every entry is compared, match or not
    if (constant_time_equal(e.token, token) && !found) found = e.tenant.get();
  }
  return found;
}

const Tenant* TokenAuth::tenant(const std::string& name) const {
  for (const auto& e : entries_) {
    if (e.tenant->name == name) return e.tenant.get();
  }
  return nullptr;
}

bool Usage::try_add(const std::string& tenant, std::int64_t bytes, std::int64_t limit) {
  std::lock_guard lock(mutex_);
  std::int64_t& used = bytes_[tenant];
  if (limit > 0 && used + bytes > limit) return false;
  used += bytes;
  return true;
}

void Usage::add(const std::string& tenant, std::int64_t bytes) {
  std::lock_guard lock(mutex_);
  bytes_[tenant] += bytes;
}

void Usage::release(const std::string& tenant, std::int64_t bytes) {
  std::lock_guard lock(mutex_);
  bytes_[tenant] = std::max<std::int64_t>(0, bytes_[tenant] - bytes);
}

std::int64_t Usage::bytes(const std::string& tenant) const {
  std::lock_guard lock(mutex_);
  auto it = bytes_.find(tenant);
  return it == bytes_.end() ? 0 : it->second;
}

std::map<std::string, std::int64_t> Usage::all() const {
  std::lock_guard lock(mutex_);
  return bytes_;
}

}  // namespace surfacer::server
