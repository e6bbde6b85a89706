#!/usr/bin/env bash
# Idempotent set-up on Debian 12: system packages, a virtual environment in .venv, and the Rust
# extension built in release mode. Safe to run again; it only installs what is missing.
set -euo pipefail
cd "$(dirname "$0")/.."

SUDO=""
[ "$(id -u)" = 0 ] || SUDO="sudo"
# libllvm19: Mitsuba's LLVM variants (Dr.Jit 1.5) need it; python3-venv for .venv; gcc for cc crates;
# g++ for the native render path (motes/native: a C++ Mitsuba plugin built against the installed wheel).
need=""
for pkg in libllvm19 python3-venv python3-dev gcc g++; do
  dpkg -s "$pkg" >/dev/null 2>&1 || need="$need $pkg"
done
if [ -n "$need" ]; then
  $SUDO apt-get update -qq
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $need
fi

if ! command -v cargo >/dev/null 2>&1; then
  if [ -x "$HOME/.cargo/bin/cargo" ]; then
    export PATH="$HOME/.cargo/bin:$PATH"
  else
    echo "setup: no Rust toolchain found; installing it with rustup (needs network access)" >&2
    command -v curl >/dev/null 2>&1 || { $SUDO apt-get update -qq; $SUDO apt-get install -y -qq curl; }
    curl --proto '=https' --tlsv1.2 -sSf https://sh.rustup.rs | sh -s -- -y --profile minimal
    export PATH="$HOME/.cargo/bin:$PATH"
  fi
fi

[ -x .venv/bin/python ] || python3 -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
# Editable install: maturin builds the extension in release mode into mitsuba_plugin/motes/.
.venv/bin/python -m pip install -q -e '.[dev,cluster]'
# Compile the native render path now (cached per Mitsuba/Dr.Jit version) rather than at the first render.
.venv/bin/python -c "import motes, motes.native as n; print('motes', motes.__version__, 'ready; native plugins in', n.build())"
