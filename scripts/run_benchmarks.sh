#!/usr/bin/env bash
# Re-measure every number in BENCHMARKS.md: runs each figure/benchmark script in full mode, one after
# the other (never in parallel: timings are side by side within each script), logs to out/<name>.log.
set -euo pipefail
cd "$(dirname "$0")/.."
mkdir -p out
for s in mie_accuracy fig3_extinction fig4_amplitudes fig6_relmse_runtime r2_variants fig22_orders hybrid_threshold singularities edge_term bench_amplitudes bench_bulk truncation_experiment spectral_interpolation bench_grid bench_render prbvolpath_check grey_extinction furnace_grid bench_ept bench_spotlit bench_native continuous_switch ept_time_to_error; do
  echo "== scripts/$s.py"
  .venv/bin/python "scripts/$s.py" --out out "$@" | tee "out/$s.log"
done
