#!/usr/bin/env bash
# Sets up, then runs the main job on a bundled example with the embedded (in-process) server:
# every scene in examples/scenes/ is polygonized and its frames written to out/<scene>/ (Draco .drc and .ply).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
BUILD_DIR="${BUILD_DIR:-build}"
export BUILD_DIR
scripts/setup.sh
for scene in examples/scenes/*.json; do
  name="$(basename "$scene" .json)"
  "$BUILD_DIR/client/surfacer" run isosurface --scene "$scene" --cells 128 --format drc,ply -o "out/$name"
done
echo
echo "Meshes written to $(pwd)/out/<scene>/frame_0000.{drc,ply}, with per-frame stats in out/<scene>/stats.csv"
