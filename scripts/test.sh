#!/usr/bin/env bash
# The whole test suite: set-up (idempotent), the Rust unit tests in an optimised build with the core's
# debug_assert!s and overflow checks on (profile ci-checked in Cargo.toml), then pytest (incl. hypothesis).
# Each stage's seconds go to stderr.
set -euo pipefail
cd "$(dirname "$0")/.."
stage() { echo "test.sh: $1 took $((SECONDS - t0)) s" >&2; t0=$SECONDS; }
t0=$SECONDS
bash scripts/setup.sh
stage "set-up"
export PATH="$HOME/.cargo/bin:$PATH"
cargo test -p motes-core --profile ci-checked --quiet
stage "the Rust unit tests"
.venv/bin/python -m pytest -q --durations=20 tests
stage "pytest"
