#!/usr/bin/env bash
# Issue 46: the GPU check, run on the `device` machine (its python3 is 3.12; nothing can be installed there).
# Packed beforehand here with `bash scripts/device/pack.sh`; then one call of the device tool:
#   command: bash scripts/device/run.sh      carry: [".device", "mitsuba_plugin/motes/_motes.abi3.so"]
#   timeout_s: 540
# Unpacks the trimmed Mitsuba/Dr.Jit wheels, prints the GPU, runs the Dr.Jit walk's tests in cuda_ad_rgb,
# scripts/device/cuda_check.py (the walk: 10^5, 10^6, 10^8 grains against the Rust core on that machine's CPUs)
# and scripts/device/cuda_render.py (dust_box with kernel = drjit against the llvm_ad_rgb references packed here;
# a 10^8-grain cloud against the native kernel in scalar_rgb there) and `motes render dust_box -m cuda_ad_rgb`,
# JSON and kernel histories to $OUT.
# Untested on a GPU (none has been lent yet): if the first call runs out of time, split the steps.
set -uo pipefail
cd "$(dirname "$0")/../.."
OUT=${OUT:-out}
mkdir -p "$OUT" /tmp/motes-site
tar -C /tmp/motes-site -xJf .device/site312.txz
export PYTHONPATH=/tmp/motes-site:$PWD/mitsuba_plugin PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv | tee "$OUT/gpu.txt"
python3 -c 'import mitsuba as mi; mi.set_variant("cuda_ad_rgb"); print("cuda_ad_rgb ok", mi.__version__)' 2>&1 \
  | tee -a "$OUT/gpu.txt"
MOTES_TEST_VARIANT=cuda_ad_rgb timeout 120 python3 -m pytest -q -p no:cacheprovider tests/test_drjit_walk.py 2>&1 \
  | tail -5 | tee "$OUT/tests.txt"
mkdir -p "$OUT/walk" "$OUT/render"
timeout 200 python3 scripts/device/cuda_check.py --out "$OUT/walk" --grains 1e5,1e6,1e8 --rays 1e6 2>&1 | tee "$OUT/walk/check.txt"
timeout 300 python3 scripts/device/cuda_render.py --out "$OUT/render" --count 1e8 --seeds 4 2>&1 | tee "$OUT/render/render.txt"
# `motes render -m cuda_ad_rgb` as a user runs it (kernel = drjit is the default in CUDA variants).
timeout 90 python3 -m motes render dust_box -m cuda_ad_rgb -s 16 -o "$OUT/render/dust_box_cli.exr" 2>&1 | tail -3 \
  | tee "$OUT/render/cli.txt"
