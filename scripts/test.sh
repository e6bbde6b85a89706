#!/usr/bin/env bash
# The whole test suite: set-up (idempotent), the Rust unit tests in a release build and again in a debug
# build (profile ci-debug in Cargo.toml: the core's debug_assert!s and overflow checks), then pytest (incl.
# hypothesis).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export PATH="$HOME/.cargo/bin:$PATH"
cargo test --release -p motes-core --quiet
cargo test -p motes-core --profile ci-debug --quiet
.venv/bin/python -m pytest -q tests
