#!/usr/bin/env bash
# Re-measure every number in BENCHMARKS.md: runs each figure/benchmark script in full mode, one after
# the other (never in parallel: timings are side by side within each script), logs to out/<name>.log.
set -euo pipefail
cd "$(dirname "$0")/.."
mkdir -p out
# figures/<name> and bench/<name>: the folder is dropped from the log's name (out/<name>.log)
for s in figures/mie_accuracy figures/fig3_extinction figures/fig4_amplitudes figures/fig6_relmse_runtime figures/r2_variants figures/fig22_orders figures/hybrid_threshold figures/singularities figures/edge_term bench/bench_amplitudes bench/bench_goa_call bench/bench_bulk bench/bench_goa_cache figures/truncation_experiment figures/spectral_interpolation bench/bench_grid bench/bench_render figures/prbvolpath_check figures/grey_extinction figures/furnace_grid bench/bench_ept bench/bench_spotlit bench/bench_native figures/continuous_switch bench/ept_time_to_error bench/bench_dense bench/bench_storage bench/bench_scale bench/bench_procedural bench/bench_field_bias bench/bench_cluster; do
  echo "== scripts/$s.py"
  .venv/bin/python "scripts/$s.py" --out out "$@" | tee "out/$(basename "$s").log"
done
# The gallery (docs/gallery, docs/gallery.md) and Table 1, at full quality.
bash scripts/paper/run_all.sh --full
.venv/bin/python scripts/paper/table1.py | tee out/table1.log
