#!/usr/bin/env bash
# Sets up, then runs the main jobs on the bundled examples with the embedded (in-process) server: the particle set in
# examples/particles/ is surfaced into out/drop_in_pool/, and every scene in examples/scenes/ is polygonized into
# out/<scene>/ (the default .glb of Draco pieces, a .ply, and a preview PNG of each).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
BUILD_DIR="${BUILD_DIR:-build}"
export BUILD_DIR
scripts/setup.sh
"$BUILD_DIR/client/surfacer" run particles --input examples/particles/drop_in_pool.bin.gz --r-inner 0.006 \
  --format glb,ply --preview -o out/drop_in_pool
for scene in examples/scenes/*.json; do
  name="$(basename "$scene" .json)"
  "$BUILD_DIR/client/surfacer" run isosurface --scene "$scene" --cells 128 --format glb,ply --preview -o "out/$name"
done
echo
echo "Meshes written to $(pwd)/out/<example>/frame_0000.{glb,ply}, pictures in out/<example>/preview/, per-frame stats"
echo "in out/<example>/stats.csv"
