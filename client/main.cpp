#include "client/cli.h"

int main(int argc, char** argv) { return surfacer::client::run_cli(argc, argv); }
