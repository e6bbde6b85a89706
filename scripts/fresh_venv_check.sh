#!/usr/bin/env bash
# Issue 11 acceptance: a fresh venv, `pip install .` (no extras), then `motes render <shipped scene> -s 16`
# from a folder outside the checkout works with no other step. Prints the render's last line and exits 0.
#     bash scripts/fresh_venv_check.sh        (~1 min with a warm pip cache; needs the README's apt packages)
set -euo pipefail
src="$(cd "$(dirname "$0")/.." && pwd)"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
git clone -q "$src" "$work/clone"
python3 -m venv "$work/venv"
"$work/venv/bin/pip" install -q "$work/clone"
cd "$work"
"$work/venv/bin/motes" --help > /dev/null
"$work/venv/bin/motes" render dust_box -s 16 -o "$work/out/dust_box.exr" --png 2>&1 | tail -1
test -s "$work/out/dust_box.exr" && test -s "$work/out/dust_box.png"
echo "fresh venv: OK"
