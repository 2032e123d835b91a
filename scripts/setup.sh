#!/usr/bin/env bash
# Installs (with apt-get) every Debian 12 package the build, tests and benches need, then configures and builds.
# Usage: scripts/setup.sh [--no-build]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

PACKAGES=(
  build-essential cmake ninja-build ccache pkg-config python3 python3-yaml openssl
  libgrpc++-dev protobuf-compiler-grpc libprotobuf-dev protobuf-compiler
  grpc-proto  # grpc/health/v1/health.proto, generated into the client's health stub (proto/CMakeLists.txt)
  libeigen3-dev libopenmesh-dev libdraco-dev draco libmeshoptimizer-dev
  libgtest-dev libgmock-dev libbenchmark-dev libcli11-dev zlib1g-dev libsqlite3-dev libssl-dev
  clang-14 libclang-rt-14-dev  # libFuzzer targets (scripts/fuzz.sh)
  libopenvdb-dev libboost-dev  # the client's .vdb writer and the OpenVDB reference of bench/particles_bench (its
                               # headers include Boost's, which libopenvdb-dev does not depend on)
  python3-openvdb  # pyopenvdb reads our .vdb files back in tests/python/test_readers.py
  pybind11-dev python3-dev python3-numpy python3-pytest  # the Python package (python/) and its tests
  libstb-dev  # PNG previews and plots (core/render/, header-only)
  liblz4-dev liblzma-dev  # LZ4 and LZMA blocks of VTK XML particle files (core/particles/particle_io_vtk.cpp)
  python3-vtk9 python3-meshio  # the real VTK and meshio in tests: VTK's own XML writers for the particle readers
                               # (tests/core/vtk_writer_files_test.py), reading our .vtk/.vtu (tests/python/test_readers.py)
)
missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing ${missing[*]}"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -q
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"
fi

[ "${1:-}" = "--no-build" ] && exit 0
BUILD_DIR="${BUILD_DIR:-build}"
cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release
cmake --build "$BUILD_DIR" -j"$(nproc)"
