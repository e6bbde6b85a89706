#!/usr/bin/env bash
# Issue 46: what a GPU check needs on the `device` machine, packed here (that machine reaches nothing outside
# it, runs its own python3 (3.12) and takes at most 64 MiB with the working tree).
#
#   bash scripts/device/pack.sh            # writes .device/ (ignored by git): about 34 MB
#
# * .device/site312.txz: Mitsuba, Dr.Jit and nanobind (headers) for CPython 3.12 at the versions installed here,
#   trimmed to the scalar_rgb, llvm_ad_rgb and cuda_ad_rgb variants (no stubs or other variants: 205 MB
#   unpacked as shipped, ~35 MB packed with xz);
# * .device/reference/: dust_box rendered here with kernel = drjit in llvm_ad_rgb, the images the GPU's are
#   compared with (scripts/device/cuda_render.py --reference; the device has no libLLVM).
# The extension (mitsuba_plugin/motes/_motes.abi3.so, abi3: it loads on 3.12) travels as a carried path.
# Then, with the `device` tool (one call; carry .device and mitsuba_plugin/motes/_motes.abi3.so):
#   bash scripts/device/run.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=${PY:-$PWD/.venv/bin/python}
grep -qx '/.device/' .git/info/exclude 2>/dev/null || echo '/.device/' >>"$(git rev-parse --git-path info/exclude)"
mkdir -p .device/wheels
MI=$($PY -c 'import mitsuba; print(mitsuba.__version__)')
DR=$($PY -c 'import drjit; print(drjit.__version__)')
NB=$($PY -c 'import nanobind; print(nanobind.__version__)')
$PY -m pip download --quiet --no-deps --only-binary=:all: --python-version 3.12 \
    --platform manylinux_2_28_x86_64 -d .device/wheels "mitsuba==$MI" "drjit==$DR" "nanobind==$NB"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
for w in .device/wheels/*.whl; do (cd "$work" && $PY -m zipfile -e "$OLDPWD/$w" .); done
rm -f "$work"/mitsuba/*spectral* "$work"/mitsuba/*mono* "$work"/mitsuba/*polarized*
# (The headers stay: the native kernel of scalar_rgb, the CPU reference there, is compiled against them.)
rm -rf "$work"/mitsuba/cmake "$work"/mitsuba/mitsuba_stubs "$work"/mitsuba/pkgconfig "$work"/drjit/cmake \
       "$work"/*.dist-info
chmod -R u+rwX,go+rX "$work"
tar -C "$work" -cJf .device/site312.txz mitsuba drjit nanobind
rm -rf .device/wheels
$PY scripts/device/cuda_render.py --reference .device/reference
du -sh .device
