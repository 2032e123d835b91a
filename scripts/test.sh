#!/usr/bin/env bash
# Sets up (installs Debian packages, configures, builds) and runs the whole test suite with CTest.
# Usage: scripts/test.sh [extra ctest args, e.g. -R Service]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
BUILD_DIR="${BUILD_DIR:-build}"
export BUILD_DIR
scripts/setup.sh
# One test process at a time per core; the server tests start their own servers on free loopback ports.
ctest --test-dir "$BUILD_DIR" --output-on-failure -j"$(nproc)" --timeout 600 "$@"
