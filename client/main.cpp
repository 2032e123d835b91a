#include <cstdio>
#include <cstdlib>
#include <iostream>

#include "client/cli.h"

int main(int argc, char** argv) {
  const int code = surfacer::client::run_cli(argc, argv);
  // Every output file is complete by now (written and renamed in place). Leave without running static destructors:
  // gRPC's own threads may still be closing a refused TLS handshake, and tearing OpenSSL and gRPC globals down under
  // them crashed the CLI at exit, rarely, after it had printed its error and chosen its exit code.
  std::cout.flush();
  std::cerr.flush();
  std::fflush(nullptr);
  std::_Exit(code);
}
