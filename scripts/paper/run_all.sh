#!/usr/bin/env bash
# Render every gallery figure (preview quality unless arguments say otherwise, e.g. --full) into
# docs/gallery/, then rewrite docs/gallery.md from their numbers. One script after the other (timings).
set -euo pipefail
cd "$(dirname "$0")/../.."
mkdir -p out
for s in fig10_lamp fig12_13_cornell fig14_limit fig16_footprint fig17_bench fig18_staircase fig19_house sky_polarisation; do
  echo "== scripts/paper/$s.py"
  .venv/bin/python "scripts/paper/$s.py" "$@" | tee "out/$s.log" || echo "!! $s: a check did not hold (see out/$s.log)"
done
.venv/bin/python scripts/paper/gallery_md.py
