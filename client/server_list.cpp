#include "client/server_list.h"

#include <arpa/inet.h>
#include <netdb.h>
#include <sys/socket.h>

#include <algorithm>
#include <cctype>

#include "client/exit_codes.h"
#include "core/util/format.h"

namespace surfacer::client {
namespace {

constexpr const char* kDnsPrefix = "dns:///";

// Splits "host:port" / "[v6]:port"; false without a port.
bool split_host_port(const std::string& text, std::string* host, std::string* port) {
  std::size_t colon = std::string::npos;
  if (!text.empty() && text.front() == '[') {
    const std::size_t close = text.find(']');
    if (close == std::string::npos || close + 1 >= text.size() || text[close + 1] != ':') return false;
    *host = text.substr(1, close - 1);
    colon = close + 1;
  } else {
    colon = text.rfind(':');
    if (colon == std::string::npos || text.find(':') != colon) return false;  // none, or a bare IPv6 address
    *host = text.substr(0, colon);
  }
  *port = text.substr(colon + 1);
  return !host->empty() && !port->empty() &&
         std::all_of(port->begin(), port->end(), [](unsigned char c) { return std::isdigit(c); });
}

}  // namespace

bool is_server_list(const std::string& server) { return server.find(',') != std::string::npos; }

void check_server_ports(const std::string& server) {
  const std::string addresses = is_dns_name(server) ? server.substr(std::string(kDnsPrefix).size()) : server;
  std::size_t pos = 0;
  while (pos <= addresses.size()) {
    const std::size_t comma = addresses.find(',', pos);
    const std::string entry(trim(addresses.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos)));
    std::string host;
    std::string port;
    if (split_host_port(entry, &host, &port)) {
      const bool in_range = port.size() <= 5 && std::stoi(port) >= 1 && std::stoi(port) <= 65535;
      if (!in_range) {
        throw CliError(ExitCode::kUsage, "--server \"" + server + "\": port " + port +
                                             " is not a TCP port (1 to 65535), e.g. --server localhost:50051");
      }
    }
    if (comma == std::string::npos) break;
    pos = comma + 1;
  }
}

bool is_dns_name(const std::string& server) { return server.rfind(kDnsPrefix, 0) == 0; }

std::vector<std::string> parse_server_list(const std::string& server) {
  std::vector<std::string> targets;
  std::size_t pos = 0;
  while (true) {
    const std::size_t comma = server.find(',', pos);
    const std::string entry(trim(server.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos)));
    std::string host;
    std::string port;
    if (entry.empty()) {
      throw CliError(ExitCode::kUsage, "--server \"" + server +
                                           "\" has an empty entry; a list is HOST:PORT,HOST:PORT,..., e.g. "
                                           "--server a:50051,b:50051");
    }
    if (!split_host_port(entry, &host, &port)) {
      throw CliError(ExitCode::kUsage, "--server \"" + server + "\": entry \"" + entry +
                                           "\" needs HOST:PORT (IPv6 as [ADDRESS]:PORT), e.g. --server "
                                           "a:50051,b:50051");
    }
    if (std::find(targets.begin(), targets.end(), entry) == targets.end()) targets.push_back(entry);
    if (comma == std::string::npos) break;
    pos = comma + 1;
  }
  return targets;
}

std::string dns_host(const std::string& server) {
  std::string host;
  std::string port;
  if (!is_dns_name(server) || !split_host_port(server.substr(std::string(kDnsPrefix).size()), &host, &port)) return "";
  return host;
}

std::vector<std::string> resolve_dns_name(const std::string& server) {
  std::string host;
  std::string port;
  if (!is_dns_name(server) || !split_host_port(server.substr(std::string(kDnsPrefix).size()), &host, &port)) {
    throw CliError(ExitCode::kUsage, "--server \"" + server +
                                         "\" needs a port: dns:///NAME:PORT, e.g. "
                                         "dns:///surfacer.default.svc.cluster.local:50051");
  }
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  addrinfo* found = nullptr;
  const int rc = ::getaddrinfo(host.c_str(), port.c_str(), &hints, &found);
  if (rc != 0) {
    throw CliError(ExitCode::kUnreachable,
                   "cannot resolve " + host + " (from --server " + server + "): " + ::gai_strerror(rc));
  }
  std::vector<std::string> targets;
  for (const addrinfo* a = found; a != nullptr; a = a->ai_next) {
    char text[INET6_ADDRSTRLEN] = {};
    std::string target;
    if (a->ai_family == AF_INET) {
      ::inet_ntop(AF_INET, &reinterpret_cast<const sockaddr_in*>(a->ai_addr)->sin_addr, text, sizeof text);
      target = std::string(text) + ":" + port;
    } else if (a->ai_family == AF_INET6) {
      ::inet_ntop(AF_INET6, &reinterpret_cast<const sockaddr_in6*>(a->ai_addr)->sin6_addr, text, sizeof text);
      target.append(1, '[').append(text).append("]:").append(port);
    } else {
      continue;
    }
    if (std::find(targets.begin(), targets.end(), target) == targets.end()) targets.push_back(target);
  }
  ::freeaddrinfo(found);
  if (targets.empty()) {
    throw CliError(ExitCode::kUnreachable,
                   "cannot resolve " + host + " (from --server " + server + "): no IPv4 or IPv6 address");
  }
  return targets;
}

}  // namespace surfacer::client
