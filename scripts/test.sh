#!/usr/bin/env bash
# The whole test suite: set-up (idempotent), Rust unit tests, then pytest (incl. hypothesis).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export PATH="$HOME/.cargo/bin:$PATH"
cargo test --release -p motes-core --quiet
.venv/bin/python -m pytest -q tests
