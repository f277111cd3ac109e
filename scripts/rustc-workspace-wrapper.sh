#!/usr/bin/env bash
# The RUSTC_WORKSPACE_WRAPPER of `make test` (scripts/test.sh): cargo runs it, for the workspace's own crates
# only, as `rustc-workspace-wrapper.sh RUSTC ARGS…`.
#
# 1. Every crate goes through clippy-driver ($SPINEDRR_CLIPPY_DRIVER, rustc plus clippy's lints), so the
#    build that makes the test binaries also lints them (-D warnings through CLIPPY_ARGS).
# 2. The test harnesses — the library's unit-test build, the integration-test crate (`--test`) and the
#    benchmark binary (benches/, which `make test` compiles but does not run) — are compiled without
#    optimisation (`-C opt-level=0`, after cargo's `-C opt-level=2`: rustc takes the last). The library
#    they exercise stays at the dev profile's opt-level 2, and so do the CLI and the Python module.
#    Measured on 2 cores (see README, *The test suite*): the unit-test build 100 → 31 CPU-s and its tests
#    still ~3 s, the integration crate 11 s instead of ~35 s alone, its tests within a few per cent.
#    `cargo test` without this wrapper builds the same tests optimised; both are correct.
set -euo pipefail
driver="${SPINEDRR_CLIPPY_DRIVER:?the clippy-driver to run (scripts/test.sh sets it)}"
for arg in "$@"; do
  case "$arg" in
  --test | benches/*) exec "$driver" "$@" -C opt-level=0 ;;
  esac
done
exec "$driver" "$@"
