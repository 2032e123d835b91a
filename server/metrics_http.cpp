#include "server/metrics_http.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <compare>
#include <cstring>
#include <stdexcept>
#include <utility>
#include <vector>

#include "core/util/format.h"
#include "server/http_request_head.h"
#include "server/log.h"

namespace surfacer::server {
namespace {

using Clock = std::chrono::steady_clock;

// After the response is sent, the connection is read and discarded for at most this long (until the client
// closes), so that unread request bytes do not turn the close into a reset that could destroy the response.
constexpr std::chrono::milliseconds kLinger{1000};
// poll() never sleeps longer than this, whatever the deadlines.
constexpr std::chrono::milliseconds kMaxPollWait{1000};
constexpr std::string_view kMetricsContentType = "text/plain; version=0.0.4; charset=utf-8";
constexpr std::string_view kTextContentType = "text/plain; charset=utf-8";

std::string errno_text(int error) { return std::strerror(error); }

struct HostPort {
  std::string host;
  std::string port;
};

HostPort parse_address(std::string_view address) {
  const std::string quoted = quote(address);
  const std::string forms = "; use HOST:PORT, e.g. 127.0.0.1:9090, 0.0.0.0:9090, localhost:9090 or [::1]:9090";
  HostPort result;
  std::string_view port;
  if (address.starts_with('[')) {
    const std::size_t close = address.find(']');
    if (close == std::string_view::npos || close + 1 >= address.size() || address[close + 1] != ':') {
      throw std::runtime_error("metrics endpoint address " + quoted + " is malformed" + forms);
    }
    result.host = std::string(address.substr(1, close - 1));
    port = address.substr(close + 2);
  } else {
    const std::size_t colon = address.rfind(':');
    if (colon == std::string_view::npos) {
      throw std::runtime_error("metrics endpoint address " + quoted + " has no port" + forms);
    }
    result.host = std::string(address.substr(0, colon));
    port = address.substr(colon + 1);
    if (result.host.find(':') != std::string::npos) {
      throw std::runtime_error("metrics endpoint address " + quoted +
                               ": put an IPv6 address in brackets, e.g. [::1]:9090");
    }
  }
  if (result.host.empty()) {
    throw std::runtime_error("metrics endpoint address " + quoted +
                             " has no host; use 0.0.0.0 (all interfaces) or 127.0.0.1 (this machine only)");
  }
  if (port.empty() || port.size() > 5 ||
      !std::all_of(port.begin(), port.end(), [](char c) { return c >= '0' && c <= '9'; }) ||
      std::stoi(std::string(port)) > 65535) {
    throw std::runtime_error("metrics endpoint address " + quoted + ": port " + quote(port) +
                             " must be a number from 0 to 65535 (0 picks a free port)");
  }
  result.port = std::string(port);
  return result;
}

std::string format_address(const sockaddr_storage& storage, int& port) {
  char text[INET6_ADDRSTRLEN] = {};
  if (storage.ss_family == AF_INET6) {
    const auto& a = reinterpret_cast<const sockaddr_in6&>(storage);
    inet_ntop(AF_INET6, &a.sin6_addr, text, sizeof text);
    port = ntohs(a.sin6_port);
    std::string out = "[";
    out += text;
    out += "]:";
    out += std::to_string(port);
    return out;
  }
  const auto& a = reinterpret_cast<const sockaddr_in&>(storage);
  inet_ntop(AF_INET, &a.sin_addr, text, sizeof text);
  port = ntohs(a.sin_port);
  return std::string(text) + ":" + std::to_string(port);
}

std::string response(int status, std::string_view reason, std::string_view content_type, std::string_view body,
                     bool head_only, std::string_view extra_headers = {}) {
  std::string out = "HTTP/1.1 ";
  out += std::to_string(status);
  out += ' ';
  out += reason;
  out += "\r\n";
  out += "Content-Type: ";
  out += content_type;
  out += "\r\nContent-Length: " + std::to_string(body.size()) + "\r\n";
  out += extra_headers;
  out += "Connection: close\r\n\r\n";
  if (!head_only) out += body;
  return out;
}

std::string error_response(int status, std::string_view reason, std::string_view detail = {}) {
  std::string body = std::to_string(status) + " " + std::string(reason);
  if (!detail.empty()) {
    body += ": ";
    body += detail;
  }
  body += "\n";
  return response(status, reason, kTextContentType, body, false);
}

// The address a connection comes from, without its port: connections are limited per peer.
using PeerKey = std::string;

PeerKey peer_key(const sockaddr_storage& storage) {
  if (storage.ss_family == AF_INET6) {
    const auto& a = reinterpret_cast<const sockaddr_in6&>(storage);
    return PeerKey(reinterpret_cast<const char*>(&a.sin6_addr), sizeof a.sin6_addr);
  }
  if (storage.ss_family == AF_INET) {
    const auto& a = reinterpret_cast<const sockaddr_in&>(storage);
    return PeerKey(reinterpret_cast<const char*>(&a.sin_addr), sizeof a.sin_addr);
  }
  return {};
}

struct Connection {
  enum class Phase { kReading, kWriting, kLingering };
  int fd = -1;
  Phase phase = Phase::kReading;
  PeerKey peer;
  std::uint64_t serial = 0;     // accept order: smaller is older
  Clock::time_point last_byte;  // when the last byte of the request came, or the accept
  std::string in;
  std::string out;
  std::size_t sent = 0;
  Clock::time_point deadline;
};

// Which open connection (of `peer` only, unless null) gives way to a new one: an answered one (lingering) first,
// then the request being read that has gone longest without a byte (counting from its accept; bytes waiting unread in
// the socket count as now), then one being answered; the oldest of each. A client that has just connected and not yet
// sent its request is as fresh as any, so the stalled ones go before it. nullptr when there is none.
Connection* eviction_victim(std::vector<Connection>& connections, const PeerKey* peer, Clock::time_point now) {
  struct Key {
    int rank;
    Clock::time_point since;
    std::uint64_t serial;
    auto operator<=>(const Key&) const = default;
  };
  const auto key = [now](const Connection& c) {
    switch (c.phase) {
      case Connection::Phase::kLingering:
        return Key{0, {}, c.serial};
      case Connection::Phase::kReading: {
        int pending = 0;
        const bool waiting = ioctl(c.fd, FIONREAD, &pending) == 0 && pending > 0;
        return Key{1, waiting ? now : c.last_byte, c.serial};
      }
      case Connection::Phase::kWriting:
        break;
    }
    return Key{2, {}, c.serial};
  };
  Connection* victim = nullptr;
  Key victim_key{};
  for (Connection& c : connections) {
    if (c.fd < 0 || (peer != nullptr && c.peer != *peer)) continue;
    const Key k = key(c);
    if (victim == nullptr || k < victim_key) {
      victim = &c;
      victim_key = k;
    }
  }
  return victim;
}

}  // namespace

std::unique_ptr<MetricsHttpServer> MetricsHttpServer::start(const MetricsRegistry& registry, std::string_view address,
                                                            MetricsHttpOptions options) {
  if (options.max_request_bytes < 64) {
    throw std::runtime_error("metrics endpoint: max_request_bytes (" + std::to_string(options.max_request_bytes) +
                             ") must be at least 64; the default is 8192");
  }
  if (options.max_connections < 1) {
    throw std::runtime_error("metrics endpoint: max_connections (" + std::to_string(options.max_connections) +
                             ") must be at least 1; the default is 64");
  }
  if (options.max_connections_per_peer < 1) {
    throw std::runtime_error("metrics endpoint: max_connections_per_peer (" +
                             std::to_string(options.max_connections_per_peer) +
                             ") must be at least 1; the default is 8");
  }
  const HostPort host_port = parse_address(address);
  const std::string quoted = quote(address);
  std::unique_ptr<MetricsHttpServer> server(new MetricsHttpServer(registry, std::move(options)));

  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_PASSIVE | AI_NUMERICSERV;
  addrinfo* found = nullptr;
  if (const int rc = getaddrinfo(host_port.host.c_str(), host_port.port.c_str(), &hints, &found); rc != 0) {
    throw std::runtime_error("metrics endpoint: cannot resolve the host of " + quoted + ": " + gai_strerror(rc));
  }
  std::unique_ptr<addrinfo, decltype(&freeaddrinfo)> addresses(found, &freeaddrinfo);
  std::string failure;
  for (const addrinfo* ai = addresses.get(); ai != nullptr && server->listen_fd_ < 0; ai = ai->ai_next) {
    const int fd = socket(ai->ai_family, ai->ai_socktype | SOCK_NONBLOCK | SOCK_CLOEXEC, ai->ai_protocol);
    if (fd < 0) {
      failure = "socket(): " + errno_text(errno);
      continue;
    }
    const int one = 1;
    setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    if (bind(fd, ai->ai_addr, ai->ai_addrlen) != 0) {
      failure = errno_text(errno);
      if (errno == EADDRINUSE) failure += " (another process listens there; choose another port, or 0 for a free one)";
      if (errno == EADDRNOTAVAIL) failure += " (no local interface has this address)";
      if (errno == EACCES) failure += " (ports below 1024 need privileges)";
      close(fd);
      continue;
    }
    // A deep accept queue: a burst of connections (an attacker's) waits there for accept_all() instead of having its
    // SYNs dropped, which would delay the scrapes behind it by the client's 1 s SYN retransmission.
    if (listen(fd, SOMAXCONN) != 0) {
      failure = "listen(): " + errno_text(errno);
      close(fd);
      continue;
    }
    server->listen_fd_ = fd;
  }
  if (server->listen_fd_ < 0) {
    throw std::runtime_error("metrics endpoint: cannot listen on " + quoted + ": " + failure);
  }
  sockaddr_storage bound{};
  socklen_t length = sizeof bound;
  if (getsockname(server->listen_fd_, reinterpret_cast<sockaddr*>(&bound), &length) != 0) {
    throw std::runtime_error("metrics endpoint: getsockname() on " + quoted + ": " + errno_text(errno));
  }
  server->address_ = format_address(bound, server->port_);

  int pipe_fds[2];
  if (pipe2(pipe_fds, O_NONBLOCK | O_CLOEXEC) != 0) {
    throw std::runtime_error("metrics endpoint: pipe2(): " + errno_text(errno));
  }
  server->wake_read_fd_ = pipe_fds[0];
  server->wake_write_fd_ = pipe_fds[1];
  server->thread_ = std::thread([s = server.get()] { s->run(); });
  return server;
}

MetricsHttpServer::MetricsHttpServer(const MetricsRegistry& registry, MetricsHttpOptions options)
    : registry_(registry), options_(std::move(options)) {}

MetricsHttpServer::~MetricsHttpServer() { stop(); }

void MetricsHttpServer::stop() {
  std::lock_guard lock(stop_mutex_);
  stopping_.store(true);
  if (thread_.joinable()) {
    const char byte = 1;
    while (write(wake_write_fd_, &byte, 1) < 0 && errno == EINTR) {
    }
    thread_.join();
  }
  for (int* fd : {&listen_fd_, &wake_read_fd_, &wake_write_fd_}) {
    if (*fd >= 0) close(*fd);
    *fd = -1;
  }
}

std::string MetricsHttpServer::respond(std::string_view head) const {
  const RequestHead request = parse_request_head(head);
  if (request.error_status == 505) return error_response(505, "HTTP Version Not Supported", request.error);
  if (request.error_status != 0) return error_response(400, "Bad Request", request.error);
  const std::string_view method = request.method;
  const std::string_view path = request.path;
  if (path != "/metrics" && path != "/healthz") {
    return error_response(404, "Not Found", "this server has /metrics and /healthz");
  }
  const bool head_only = method == "HEAD";
  if (method != "GET" && !head_only) {
    return response(405, "Method Not Allowed", kTextContentType, "405 Method Not Allowed: use GET or HEAD\n", false,
                    "Allow: GET, HEAD\r\n");
  }
  if (path == "/healthz") {
    if (options_.healthy && !options_.healthy()) {
      return response(503, "Service Unavailable", kTextContentType, "unavailable\n", head_only);
    }
    return response(200, "OK", kTextContentType, "ok\n", head_only);
  }
  std::string body;
  try {
    body = registry_.render();
  } catch (const std::exception& e) {
    log_event(LogLevel::kError, "metrics_render_failed", {{"error", e.what()}});
    return error_response(500, "Internal Server Error", e.what());
  }
  return response(200, "OK", kMetricsContentType, body, head_only);
}

void MetricsHttpServer::run() {
  std::vector<Connection> connections;
  std::vector<pollfd> fds;
  Clock::time_point accept_paused_until{};

  const auto start_writing = [&](Connection& c, std::string out, Clock::time_point now) {
    c.phase = Connection::Phase::kWriting;
    c.out = std::move(out);
    c.sent = 0;
    c.in.clear();
    c.deadline = now + options_.write_timeout;
  };
  const auto close_connection = [](Connection& c) {
    if (c.fd >= 0) close(c.fd);
    c.fd = -1;
  };
  // Reads what has arrived; answers once the head is complete, too large, or cut short.
  const auto on_readable = [&](Connection& c, Clock::time_point now) {
    char buffer[4096];
    bool eof = false;
    while (c.in.size() <= options_.max_request_bytes) {
      const ssize_t n = recv(c.fd, buffer, sizeof buffer, 0);
      if (n > 0) {
        c.in.append(buffer, static_cast<std::size_t>(n));
        c.last_byte = now;
      } else if (n == 0) {
        eof = true;
        break;
      } else if (errno == EINTR) {
        continue;
      } else if (errno == EAGAIN || errno == EWOULDBLOCK) {
        break;
      } else {
        close_connection(c);
        return;
      }
    }
    const std::size_t end = request_head_end(c.in);
    if (end != std::string::npos && end <= options_.max_request_bytes) {
      start_writing(c, respond(std::string_view(c.in).substr(0, end)), now);
    } else if (c.in.size() > options_.max_request_bytes || end != std::string::npos) {
      start_writing(c,
                    error_response(431, "Request Header Fields Too Large",
                                   "the request head exceeds " + std::to_string(options_.max_request_bytes) + " bytes"),
                    now);
    } else if (eof) {
      if (c.in.empty()) {
        close_connection(c);
      } else {
        start_writing(c, error_response(400, "Bad Request", "the request ended before its blank line"), now);
      }
    }
  };
  const auto on_writable = [&](Connection& c, Clock::time_point now) {
    while (c.sent < c.out.size()) {
      const ssize_t n = send(c.fd, c.out.data() + c.sent, c.out.size() - c.sent, MSG_NOSIGNAL);
      if (n > 0) {
        c.sent += static_cast<std::size_t>(n);
      } else if (n < 0 && errno == EINTR) {
        continue;
      } else if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
        return;
      } else {
        close_connection(c);
        return;
      }
    }
    shutdown(c.fd, SHUT_WR);
    c.phase = Connection::Phase::kLingering;
    c.out.clear();
    c.deadline = now + kLinger;
  };
  const auto on_linger_readable = [&](Connection& c) {
    char buffer[4096];
    for (;;) {
      const ssize_t n = recv(c.fd, buffer, sizeof buffer, 0);
      if (n > 0) continue;
      if (n < 0 && errno == EINTR) continue;
      if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) return;
      close_connection(c);  // EOF or error
      return;
    }
  };
  std::uint64_t accepted = 0;
  // Never refuses: a peer at its limit, or a full table, closes the connection that eviction_victim() picks.
  const auto accept_all = [&](Clock::time_point now) {
    for (;;) {
      sockaddr_storage from{};
      socklen_t from_length = sizeof from;
      const int fd =
          accept4(listen_fd_, reinterpret_cast<sockaddr*>(&from), &from_length, SOCK_NONBLOCK | SOCK_CLOEXEC);
      if (fd < 0) {
        if (errno == EINTR || errno == ECONNABORTED) continue;
        if (errno == EMFILE || errno == ENFILE || errno == ENOBUFS || errno == ENOMEM) {
          log_event(LogLevel::kWarn, "metrics_accept_failed", {{"error", errno_text(errno)}});
          accept_paused_until = now + std::chrono::milliseconds(100);
        }
        return;
      }
      Connection c;
      c.fd = fd;
      c.peer = peer_key(from);
      c.serial = accepted++;
      c.deadline = now + options_.read_timeout;
      c.last_byte = now;
      const auto same_peer = std::count_if(connections.begin(), connections.end(),
                                           [&](const Connection& o) { return o.fd >= 0 && o.peer == c.peer; });
      if (same_peer >= options_.max_connections_per_peer) {
        close_connection(*eviction_victim(connections, &c.peer, now));
      }
      std::erase_if(connections, [](const Connection& o) { return o.fd < 0; });
      if (connections.size() >= static_cast<std::size_t>(options_.max_connections)) {
        close_connection(*eviction_victim(connections, nullptr, now));
        std::erase_if(connections, [](const Connection& o) { return o.fd < 0; });
      }
      connections.push_back(std::move(c));
    }
  };

  try {
    while (!stopping_.load()) {
      Clock::time_point now = Clock::now();
      for (Connection& c : connections) {
        if (now < c.deadline) continue;
        if (c.phase == Connection::Phase::kReading) {
          // One attempt to say why, then the connection is closed: an idle client holds no slot beyond read_timeout.
          const std::string timeout = error_response(408, "Request Timeout", "the request head did not arrive in time");
          while (send(c.fd, timeout.data(), timeout.size(), MSG_NOSIGNAL) < 0 && errno == EINTR) {
          }
        }
        close_connection(c);
      }
      std::erase_if(connections, [](const Connection& c) { return c.fd < 0; });

      auto wait = kMaxPollWait;
      fds.clear();
      fds.push_back({wake_read_fd_, POLLIN, 0});
      const bool accepting = now >= accept_paused_until;
      fds.push_back({listen_fd_, static_cast<short>(accepting ? POLLIN : 0), 0});
      if (!accepting) {
        wait = std::min(wait, std::chrono::ceil<std::chrono::milliseconds>(accept_paused_until - now));
      }
      for (const Connection& c : connections) {
        fds.push_back({c.fd, static_cast<short>(c.phase == Connection::Phase::kWriting ? POLLOUT : POLLIN), 0});
        wait = std::min(wait, std::chrono::ceil<std::chrono::milliseconds>(c.deadline - now));
      }
      if (poll(fds.data(), fds.size(), static_cast<int>(std::max<std::int64_t>(wait.count(), 1))) < 0) {
        if (errno == EINTR) continue;
        log_event(LogLevel::kError, "metrics_poll_failed", {{"error", errno_text(errno)}});
        break;
      }
      if (fds[0].revents != 0) {
        char drain[64];
        while (read(wake_read_fd_, drain, sizeof drain) > 0) {
        }
      }
      if (stopping_.load()) break;
      now = Clock::now();
      // connections[i] is fds[i + 2]; accepting happens afterwards, so the indices still match.
      for (std::size_t i = 0; i < connections.size(); ++i) {
        Connection& c = connections[i];
        const short revents = fds[i + 2].revents;
        if (revents == 0) continue;
        if (revents & POLLNVAL) {
          close_connection(c);
          continue;
        }
        switch (c.phase) {
          case Connection::Phase::kReading:
            on_readable(c, now);
            // A complete answer is usually sendable at once.
            if (c.fd >= 0 && c.phase == Connection::Phase::kWriting) on_writable(c, now);
            break;
          case Connection::Phase::kWriting:
            if (revents & (POLLERR | POLLHUP) && !(revents & POLLOUT)) {
              close_connection(c);
            } else {
              on_writable(c, now);
            }
            break;
          case Connection::Phase::kLingering:
            on_linger_readable(c);
            break;
        }
      }
      std::erase_if(connections, [](const Connection& c) { return c.fd < 0; });
      if (fds[1].revents & POLLIN) accept_all(now);
    }
  } catch (const std::exception& e) {
    log_event(LogLevel::kError, "metrics_server_failed", {{"error", e.what()}});
  }
  for (Connection& c : connections) close_connection(c);
}

}  // namespace surfacer::server
