#!/usr/bin/env bash
# Renders the README's pictures into docs/images/ (480x360 PNGs, committed): a few bundled example scenes polygonized
# with the in-process server and pictured by `surfacer preview`, the bundled particle example surfaced, and an
# optimize run's e_d/e_n plot.
# Usage: scripts/make_readme_images.sh   (after a build; BUILD_DIR defaults to build)
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
SURFACER="${BUILD_DIR:-build}/client/surfacer"
[ -x "$SURFACER" ] || { echo "make_readme_images: build $SURFACER first (scripts/setup.sh)" >&2; exit 2; }
OUT=docs/images
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
mkdir -p "$OUT"

for scene in csg_block gyroid_in_sphere blobby smooth_blend; do
  "$SURFACER" --local run isosurface --scene "examples/scenes/$scene.json" --cells 128 -o "$WORK/$scene" \
    --format ply --progress json 2>/dev/null
  "$SURFACER" preview "$WORK/$scene/frame_0000.ply" -o "$WORK/$scene/preview" >/dev/null
  cp "$WORK/$scene/preview/frame_0000.png" "$OUT/$scene.png"
done

"$SURFACER" --local run particles --input examples/particles/drop_in_pool.bin.gz --r-inner 0.006 -o "$WORK/particles" \
  --format ply --preview --progress json 2>/dev/null >/dev/null
cp "$WORK/particles/preview/frame_0000.png" "$OUT/particles_drop_in_pool.png"

"$SURFACER" --local run optimize --scene examples/scenes/csg_block.json --start-cells 48 --iterations 120 \
  --snapshot-every 10 -o "$WORK/optimize" --format ply --preview --progress json 2>/dev/null >/dev/null
cp "$WORK/optimize/preview/iterations.png" "$OUT/optimize_iterations.png"
last=$(ls "$WORK/optimize/preview"/frame_*.png | tail -n 1)
cp "$last" "$OUT/optimize_csg_block.png"
ls -l "$OUT"
