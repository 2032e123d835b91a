// The servers of `--server`: one HOST:PORT (or any gRPC target), a comma-separated list "a:1,b:2,c:3", or a
// "dns:///NAME:PORT" name whose every address is a server. A list, or a name with several addresses, makes `run`
// split frame sequences across the servers (client/scale_out.h).
#pragma once

#include <string>
#include <vector>

namespace surfacer::client {

// True for a comma-separated list.
bool is_server_list(const std::string& server);
// True for "dns:///NAME:PORT" (the system resolver, not a "dns://AUTHORITY/..." target).
bool is_dns_name(const std::string& server);
// Refuses a HOST:PORT whose port is not 1..65535 (gRPC would otherwise connect to the port modulo 65536), in a single
// address, each entry of a list, or a dns:/// name. Throws CliError(kUsage) naming --server. Other forms (unix:PATH)
// pass unchecked.
void check_server_ports(const std::string& server);

// The entries of a comma-separated list, trimmed, each HOST:PORT ("[v6]:PORT" for IPv6), duplicates removed in
// order. Throws CliError(kUsage) naming --server for an empty entry or one without a port.
std::vector<std::string> parse_server_list(const std::string& server);

// Every address "dns:///NAME:PORT" resolves to (getaddrinfo), as "IP:PORT" / "[IPv6]:PORT", in the resolver's
// order without duplicates. Throws CliError(kUsage) when the port is missing, CliError(kUnreachable) when the name
// does not resolve.
std::vector<std::string> resolve_dns_name(const std::string& server);

// The host part of "dns:///NAME:PORT" ("NAME"), for TLS name checks against resolved addresses.
std::string dns_host(const std::string& server);

}  // namespace surfacer::client
