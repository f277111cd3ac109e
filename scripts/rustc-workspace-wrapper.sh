#!/usr/bin/env bash
# The RUSTC_WORKSPACE_WRAPPER of `make test` (scripts/test.sh): cargo runs it, for the workspace's own crates
# only, as `rustc-workspace-wrapper.sh RUSTC ARGS…`, in the one `cargo build --workspace --all-targets`.
#
# 1. The crates go through clippy-driver ($SPINEDRR_CLIPPY_DRIVER, rustc plus clippy's lints), so the build
#    that makes the test binaries also lints them (-D warnings through CLIPPY_ARGS).
# 2. The test harnesses — the unit-test builds and the integration-test crate (`--test`) — and the
#    benchmark binary (benches/, which `make test` compiles but does not run) are compiled without
#    optimisation (`-C opt-level=0` after cargo's `-C opt-level=2`: rustc takes the last). The core
#    library they exercise (spinedrr-core) stays at the dev profile's opt-level 2, and so does the Python
#    module; the study crate and the CLI are at opt-level 0 through the profile itself (Cargo.toml).
# 3. The libraries themselves (src/lib.rs, core/src/lib.rs, not as tests) are compiled by plain rustc with
#    `-D warnings`: each one's unit-test build compiles every line of it again (there is no
#    `cfg(not(test))` code) through clippy,
#    so clippy's lints would only be computed twice; rustc's own warnings, which differ between the two
#    builds (dead code), are still errors.
# Measured on 2 cores (README, *The test suite*). `cargo test` or `cargo clippy` without this wrapper build
# and lint the same code the usual way.
set -euo pipefail
driver="${SPINEDRR_CLIPPY_DRIVER:?the clippy-driver to run (scripts/test.sh sets it)}"
rustc="$1"
crate="" harness=0 lib=0
prev=""
for arg in "$@"; do
  case "$arg" in
  --test | benches/*) harness=1 ;;
  src/lib.rs | core/src/lib.rs) lib=1 ;;
  esac
  [ "$prev" = --crate-name ] && crate="$arg"
  prev="$arg"
done
if [ $harness = 1 ]; then
  exec "$driver" "$@" -C opt-level=0
fi
if { [ "$crate" = spinedrr ] || [ "$crate" = spinedrr_core ]; } && [ $lib = 1 ]; then
  shift
  exec "$rustc" "$@" -D warnings
fi
exec "$driver" "$@"
