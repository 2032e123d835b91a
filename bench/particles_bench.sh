#!/usr/bin/env bash
# Particle surfacing benchmark. Builds bench/particles_bench in its own build directory and runs it on the
# generated data sets (block, sheet, droplets, spray; add block_fine with SETS=...). When OpenVDB's development
# package is installed (Debian: apt-get install libopenvdb-dev; an optional, bench-only dependency), the script also
# compiles bench/openvdb_particles.cpp with g++ and runs ParticlesToLevelSet + LevelSetFilter + VolumeToMesh on the same
# block, printing our time over theirs. Without OpenVDB it says so and skips that part.
#
#   bench/particles_bench.sh [extra particles_bench args]
#   BUILD_DIR=build-bench SETS=block,block_fine REPEAT=3 bench/particles_bench.sh
#
# Numbers depend on the machine's load: the report prints the load average, wall and cpu seconds.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD_DIR="${BUILD_DIR:-$ROOT/build-particles}"
SETS="${SETS:-block,sheet,droplets,spray}"
REPEAT="${REPEAT:-3}"

if [[ ! -f "$BUILD_DIR/build.ninja" && ! -f "$BUILD_DIR/Makefile" ]]; then
  cmake -S "$ROOT" -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
fi
cmake --build "$BUILD_DIR" --target particles_bench -j"$(nproc)"

echo "== Surfacer particle surfacing"
OUT="$("$BUILD_DIR/bench/particles_bench" --sets "$SETS" --repeat "$REPEAT" "$@")"
echo "$OUT"

if [[ -f /usr/include/openvdb/openvdb.h ]]; then
  echo "== OpenVDB (libopenvdb-dev found): ParticlesToLevelSet + LevelSetFilter + VolumeToMesh on the same block"
  VDB_BIN="$BUILD_DIR/bench/openvdb_particles"
  if [[ ! -x "$VDB_BIN" || "$ROOT/bench/openvdb_particles.cpp" -nt "$VDB_BIN" ]]; then
    g++ -std=c++17 -O2 -DNDEBUG "$ROOT/bench/openvdb_particles.cpp" -o "$VDB_BIN" \
      -lopenvdb -ltbb -lImath -lpthread 2>/dev/null ||
      g++ -std=c++17 -O2 -DNDEBUG "$ROOT/bench/openvdb_particles.cpp" -o "$VDB_BIN" -lopenvdb -ltbb -lHalf -lpthread
  fi
  # Same resolution as our block run: r_inner, r_outer and spacing as particles_bench derived them.
  BLOCK_LINE="$(grep -A1 '^block ' <<<"$OUT" | grep -E '^  particles .*r_outer' || true)"
  if [[ -z "$BLOCK_LINE" ]]; then
    echo "(no block set in this run: skipping the OpenVDB comparison)"
    exit 0
  fi
  R_OUTER="$(sed -E 's/.*r_outer ([0-9.e+-]+).*/\1/' <<<"$BLOCK_LINE")"
  SPACING="$(sed -E 's/.*spacing ([0-9.e+-]+).*/\1/' <<<"$BLOCK_LINE")"
  OURS="$(grep -A3 '^block ' <<<"$OUT" | grep -E '^  wall' | sed -E 's/  wall ([0-9.]+) s best.*/\1/')"
  OURS_CPU="$(grep -A3 '^block ' <<<"$OUT" | grep -E '^  wall' | sed -E 's/.*cpu ([0-9.]+) s.*/\1/')"
  "$VDB_BIN" --radius "$R_OUTER" --spacing "$SPACING" --repeat 1 --ours "$OURS" --ours-cpu "$OURS_CPU"
else
  echo "== OpenVDB comparison skipped: /usr/include/openvdb/openvdb.h not found (apt-get install libopenvdb-dev)"
fi
