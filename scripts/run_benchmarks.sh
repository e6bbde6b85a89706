#!/usr/bin/env bash
# Re-measure every figure that BENCHMARKS.md, README.md, TESTING.md and docs/ cite, each with the arguments
# the text quotes. The commands are grouped by BENCHMARKS.md's sections, in its order.
#
#     bash scripts/run_benchmarks.sh [LOG_DIR]        (default LOG_DIR: out/bench-logs)
#
# It takes many hours on the project's 2-core machine (roughly a day: the Cornell variants, bench_scale to
# 10^8 grains, the EPT references and the gallery are the longest); that is expected. Run it on an otherwise
# idle machine and never two commands at once: the speed figures are ratios taken side by side inside each
# script. Each command's output (stdout and stderr) goes to LOG_DIR/<name>.log and to the terminal; scripts
# that also write JSON or PNG files put them under out/ (as before; a later run of the same script with
# other arguments overwrites its JSON, the logs keep every run). A command that fails does not stop the
# run: it is named at the end, and the script exits 1.
#
# Not run here:
#   * scripts/bench/image_bits.py: a bitwise A/B of two builds' images (render with each build, then
#     compare); it needs the other build installed beside this one (see its docstring).
#   * render_seconds.py A/B runs of two builds (PYTHONPATH=<other build> ...) and `perf record` profiles;
#     the absolute seconds BENCHMARKS.md quotes are measured below, on this checkout's build.
#   * `duplicates` (BENCHMARKS.md "Code structure"): the workplace's tool, not part of this repository.
set -euo pipefail
cd "$(dirname "$0")/.."
export PATH="$HOME/.cargo/bin:$PATH"
LOG="${1:-out/bench-logs}"
PY=.venv/bin/python
B=scripts/bench
F=scripts/figures
mkdir -p "$LOG" out

failed=()
run() {  # run NAME COMMAND...: one command, its output to $LOG/NAME.log and the terminal
  local name=$1
  shift
  echo "== $name: $*"
  if ! "$@" 2>&1 | tee "$LOG/$name.log"; then
    failed+=("$name")
    echo "!! $name failed (see $LOG/$name.log)"
  fi
}

# --- Single-particle optics (issues 2, 23.1) ------------------------------------------------------------
run mie_accuracy            $PY $F/mie_accuracy.py --out out
run fig6_relmse_runtime     $PY $F/fig6_relmse_runtime.py --out out
run fig4_amplitudes         $PY $F/fig4_amplitudes.py --out out
run r2_variants             $PY $F/r2_variants.py --out out
run hybrid_threshold        $PY $F/hybrid_threshold.py --out out
run fig3_extinction         $PY $F/fig3_extinction.py --out out
run fig22_orders            $PY $F/fig22_orders.py --out out
run singularities           $PY $F/singularities.py --out out
run edge_term               $PY $F/edge_term.py --out out
run bench_amplitudes        $PY $B/bench_amplitudes.py --out out
run bench_goa_call          $PY $B/bench_goa_call.py --out out      # exits 1 if issue 23.1's check fails
run bench_goa_cache         $PY $B/bench_goa_cache.py

# --- Polydisperse ensembles (issues 3, 9.2, 9.3) --------------------------------------------------------
run bench_bulk              $PY $B/bench_bulk.py --out out
run spectral_interpolation  $PY $F/spectral_interpolation.py --out out
run truncation_experiment   $PY $F/truncation_experiment.py --out out
run ensemble_accuracy       $PY $F/ensemble_accuracy.py --out out

# --- Particles in space: grid, traversal, events (issues 4, 10.2, 25) -----------------------------------
run bench_grid              $PY $B/bench_grid.py --out out
run cargo_bench_traverse    cargo bench -p motes-core --bench traverse
run cargo_bench_field_events cargo bench -p motes-core --bench field_events

# --- Rendering accuracy (issues 5, 9, 10.3, 24, 25) -----------------------------------------------------
run furnace_grid            $PY $F/furnace_grid.py
run prbvolpath_check        $PY $F/prbvolpath_check.py --out out
run grey_extinction         $PY $F/grey_extinction.py --out out
run bench_spotlit           $PY $B/bench_spotlit.py --out out
run continuous_switch       $PY $F/continuous_switch.py
run bench_render_limit      $PY $B/bench_render.py --only limit --out out   # evaluated-mode path (issue 5)
run bench_render_grains     $PY $B/bench_render.py --only grains --out out
# dense clouds: the default against the exact render, many seeds
run dense_accuracy_8        $PY $B/bench_dense.py --rows 4e5x80,1.6e6x80 --reps 1 --seeds 8 --out out
run dense_accuracy_4e6x20   $PY $B/bench_dense.py --surface --reps 1 --rows 4e6x20 --seeds 16 --out out
# the surface-ray rule: its extensions on/off, and the whole rule on/off (also its speed, next section)
run penumbra                $PY $B/bench_penumbra.py --seeds 16 --out out
run penumbra_cornell_3e5    $PY $B/bench_penumbra.py --seeds 16 --scenes cornell --set count=300000 --out out
run penumbra_cornell_3mm    $PY $B/bench_penumbra.py --seeds 16 --scenes cornell --set count=30000 --set radius=3000 --out out
run surface                 $PY $B/bench_surface.py --seeds 16 --scenes dust_box,cornell,bench,staircase --out out
run surface_cornell_3e5     $PY $B/bench_surface.py --seeds 16 --scenes cornell --set count=300000 --out out
run surface_cornell_3mm     $PY $B/bench_surface.py --seeds 16 --scenes cornell --set count=30000 --set radius=3000 --out out
# storage (issue 24): compact, full, procedural, the continuous field's cells
run storage_llvm            $PY $B/bench_storage.py --rows 4e5x80,1e5x300,4e6x20 --seeds 8 --out out
run storage_scalar          $PY $B/bench_storage.py --rows 4e5x80,1e5x300,4e6x20 --seeds 8 --variant scalar_rgb --out out
run centre_cells_furnace_llvm   $PY $B/bench_quantise.py --switch MOTES_CENTRE_CELLS --furnace 1e5x300 --clouds 8 --out out
run centre_cells_furnace_scalar $PY $B/bench_quantise.py --switch MOTES_CENTRE_CELLS --furnace 1e5x300 --clouds 8 --variant scalar_rgb --out out
run storage_defaults        $PY $B/bench_storage_defaults.py
run procedural_llvm         $PY $B/bench_procedural.py
run procedural_scalar       $PY $B/bench_procedural.py --variant scalar_rgb
run procedural_wide_grains  $PY $B/bench_procedural.py --median 1500 --counts 400000 --seeds 6
run field_bias              $PY $B/bench_field_bias.py
# reference image means of the shipped scenes
run scene_means             $PY $B/scene_means.py --scenes cornell,staircase,house,lamp,dust_box --seeds 12 --out out

# --- Rendering speed against homogeneous (issues 10.1, 25) ----------------------------------------------
run native_128              $PY $B/bench_native.py --native-only --out out
run native_256              $PY $B/bench_native.py --native-only --res 256 --spp 64 --out out
run native_both_variants    $PY $B/bench_native.py --out out     # scalar_rgb and the evaluated-mode path too
run gallery_llvm            $PY $B/bench_gallery.py --reps 2 --out out
run gallery_scalar          $PY $B/bench_gallery.py --reps 2 --variant scalar_rgb --out out
# the Cornell box with more or larger grains: both variants, then three more in llvm_ad_rgb
cornell_sets=("count=300000" "radius=2000" "count=30000 radius=3000" "count=300000 radius=2000"
              "count=1000000" "count=1000000 radius=2000" "count=3000000" "count=300000 radius=4000")
for s in "${cornell_sets[@]}"; do
  set_args=()
  for kv in $s; do set_args+=(--set "$kv"); done
  tag=${s// /_}
  run "cornell_${tag}_llvm"   $PY $B/bench_gallery.py --scenes cornell --reps 3 "${set_args[@]}" --out out
  run "cornell_${tag}_scalar" $PY $B/bench_gallery.py --scenes cornell --reps 3 "${set_args[@]}" --variant scalar_rgb --out out
done
run cornell_count=1000000_radius=3000_llvm $PY $B/bench_gallery.py --scenes cornell --reps 3 --set count=1000000 --set radius=3000 --out out
run cornell_count=300000_radius=6000_llvm  $PY $B/bench_gallery.py --scenes cornell --reps 3 --set count=300000 --set radius=6000 --out out
run cornell_count=3000000_radius=2000_llvm $PY $B/bench_gallery.py --scenes cornell --reps 3 --set count=3000000 --set radius=2000 --out out
# dense clouds of visible grains: the issue's rows, then its room at higher counts and larger grains
run dense_rows_llvm         $PY $B/bench_dense.py --surface --reps 2 --seeds 2 --out out
run dense_rows_scalar       $PY $B/bench_dense.py --surface --reps 2 --seeds 2 --variant scalar_rgb --out out
run dense_more_grains       $PY $B/bench_dense.py --rows 6.4e6x80,1.6e6x200,2e5x400,2.56e7x80,4e6x200 --speed-only --reps 2 --out out
# absolute seconds per render (this checkout's build)
run seconds_1e6_2mm_llvm    $PY $B/render_seconds.py --scene cornell --set count=1000000 --set radius=2000 --renders 5
run seconds_1e6_2mm_scalar  $PY $B/render_seconds.py --scene cornell --set count=1000000 --set radius=2000 --renders 5 --variant scalar_rgb
run seconds_3e5_4mm_llvm    $PY $B/render_seconds.py --scene cornell --set count=300000 --set radius=4000 --renders 5
# each speed-up switched off in the same process (bench_surface's time ratio: the surface runs above)
run skips_llvm              $PY $B/bench_skips.py --set count=300000 --set radius=2000
run skips_scalar            $PY $B/bench_skips.py --set count=300000 --set radius=2000 --variant scalar_rgb
run uniform_majorant        $PY $B/bench_quantise.py --switch MOTES_UNIFORM_MAJORANT --scenes cornell,staircase,house,lamp,1.6e6 --reps 8 --out out
run beams                   $PY $B/bench_quantise.py --switch MOTES_BEAM --scenes haze --res 256 --spp 64 --reps 3 --out out
run centre_cells_llvm       $PY $B/bench_quantise.py --switch MOTES_CENTRE_CELLS --reps 4 --out out
run centre_cells_scalar     $PY $B/bench_quantise.py --switch MOTES_CENTRE_CELLS --reps 4 --variant scalar_rgb --out out

# --- Memory and scale (issues 10.4, 24) -----------------------------------------------------------------
run main_job                .venv/bin/motes render scenes_xml/dust_box.xml -o out/dust_box.exr --png   # README
run native_memory           $PY $B/bench_native.py --configs default --memory --out out
run scale_continuous        $PY $B/bench_scale.py --counts 1e6,1e7,1e8 --out out
run scale_discrete          $PY $B/bench_scale.py --discrete --counts 1e6,1e7,1e8 --out out
run scale_discrete_npz      $PY $B/bench_scale.py --discrete --source file --counts 1e7,1e8 --out out
run scale_discrete_ply      $PY $B/bench_scale.py --discrete --source ply --counts 1e7,1e8 --out out
run scale_procedural        $PY $B/bench_scale.py --storage procedural --counts 1e6,1e7,1e8 --out out
run scale_nave              $PY $B/bench_scale.py --storage procedural --scene nave --counts 1e10,1e11,1e12 --out out
run scale_nave_1e8          $PY $B/bench_scale.py --storage procedural --scene nave --counts 1e8 --res 32 --spp 1 --out out
run scale_nave_1e8_cache    $PY $B/bench_scale.py --storage procedural --scene nave --counts 1e8 --res 32 --spp 1 --cache-mb 16000 --out out
# (bytes per particle of bench_storage and bench_quantise --switch MOTES_CENTRE_CELLS: the runs above)
run resident                $PY $B/bench_resident.py               # bytes a medium reports vs resident memory

# --- Against explicit path tracing (issues 9.0, 10.5) ---------------------------------------------------
run ept                     $PY $B/bench_ept.py --out out
run ept_dense               $PY $B/bench_ept.py --dense --out out
run ept_time_to_error       $PY $B/ept_time_to_error.py --out out
run ept_time_to_error_10k   $PY $B/ept_time_to_error.py --scenes cornell --count 10000 --out out/ept10k
run ept_time_to_error_ds4   $PY $B/ept_time_to_error.py --scenes cornell --downsample 4 --out out/ept_ds4

# --- The gallery and the paper's Table 1 (issue 26) -----------------------------------------------------
# Preview quality, as docs/gallery.md quotes it: renders docs/gallery/ and rewrites docs/gallery.md (each
# figure's log also in out/<figure>.log).
run gallery_figures         bash scripts/paper/run_all.sh
run house_sky_seeds         $PY $B/house_sky_seeds.py --seeds 32
run table1                  $PY scripts/paper/table1.py      # also writes docs/gallery/table1.json

# --- Animations and the Dask cluster (issue 27) ---------------------------------------------------------
run bench_cluster           $PY $B/bench_cluster.py

# --- A drop-in medium (issue 43) -----------------------------------------------------------------------
run dropin                  $PY $B/bench_dropin.py
run dropin_rotated          $PY $B/bench_dropin.py --rotated-study --spp 256
run dropin_heterogeneous    $PY $B/bench_dropin.py --heterogeneous
run dropin_heterogeneous_llvm $PY $B/bench_dropin.py --heterogeneous --variant llvm_ad_rgb
run lod_sidelit             $PY $B/bench_lod.py --scenes sidelit,sidelit3mm --configs default,exact
run lod_shipped             $PY $B/bench_lod.py --scenes cornell,lamp,dust_box,footprint,bench,house,limit,staircase --configs default,exact
run lod_clouds              $PY $B/bench_lod.py --scenes sidelit-h5 --variants scalar_rgb --clouds 16 --res 24 --spp 64 --seeds 4
run camera_lod              $PY $B/bench_camera_lod.py --off
run load_1e8                $PY $B/bench_load.py --count 1e8 --configs gen-discrete-compact,npz-discrete-compact

# --- Polarisation (issue 45) ----------------------------------------------------------------------------
run mueller_goa_vs_mie      $PY scripts/figures/mueller_goa_vs_mie.py
run polarisation_checks     $PY scripts/figures/polarisation_checks.py
run polarized_cost          $PY $B/bench_polarized.py --scene dust_box --res 96 --spp 16
run sky_polarisation        $PY scripts/paper/sky_polarisation.py --spp 128 --res 160

# --- The Dr.Jit kernel (issue 46) ------------------------------------------------------------------------
run drjit_kernel            $PY $B/bench_drjit_kernel.py --res 32 --spp 16 --seeds 4
run drjit_exclusion_tag     $PY $B/bench_drjit_kernel.py --scenes sidelit --res 32 --spp 64 --seeds 12 --max-depth 2 --exclusion tag
run drjit_exclusion_ball    $PY $B/bench_drjit_kernel.py --scenes sidelit --res 32 --spp 64 --seeds 12 --max-depth 2 --exclusion ball

# --- Code structure (issues 12, 42) ---------------------------------------------------------------------
run function_lengths        python3 scripts/function_lengths.py   # exits 1 while a function is over 80 lines
run layers_and_sizes        python3 scripts/check_layers.py --sizes
run cargo_doc               cargo doc --no-deps -p motes-core      # the warnings, if any, are in its log

# --- TESTING.md -----------------------------------------------------------------------------------------
run malformed_table         $PY tests/test_malformed.py            # the table of TESTING.md
run ctrl_c_seconds          $PY tests/test_ctrl_c.py
run fresh_venv              bash scripts/fresh_venv_check.sh       # needs pip to reach its packages

if ((${#failed[@]})); then
  echo "!! failed: ${failed[*]}"
  exit 1
fi
echo "all commands ran; logs in $LOG"
