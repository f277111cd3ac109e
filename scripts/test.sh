#!/usr/bin/env bash
# `make test`: every check a change must pass, in one compile of the tree, with the wall time of each phase
# printed at the end beside the pass/fail totals.
#
# Phases:
#   deps    scripts/install-deps.sh (system packages, only those missing)
#   static  cargo fmt --check, the import-cycle check
#   build   ONE `cargo build --all-targets` of the workspace (test binaries, benches, examples, the CLI, the
#           Python cdylib) through clippy-driver (scripts/rustc-workspace-wrapper.sh as the workspace
#           wrapper), so clippy's lints (-D warnings) are emitted by the same compile that produces the test
#           binaries, the CLI and the Python module (no separate `cargo clippy` check build, no release build
#           of the module); the test harnesses and the study crate (study, report, CLI) compile
#           unoptimised, the core library (spinedrr-core) and the Python module at opt-level 2; the Python
#           virtual environment is made meanwhile
#   rust    the library's unit tests and the one integration-test binary (tests/it/)
#   python  the module the build phase compiled, installed into the venv, and pytest over python/tests,
#           run beside the Rust tests (both phases' times count from their common start)
#
# The last line is a plain "N passed, N failed" total over the Rust and the Python tests.
set -euo pipefail
cd "$(dirname "$0")/.."

PYENV=target/pyenv
mkdir -p target
phases=()
now_ms() { echo $(($(date +%s%N) / 1000000)); }
seconds() { printf '%d.%d' $(($1 / 1000)) $(($1 % 1000 / 100)); }
phase() { # phase NAME COMMAND… : runs COMMAND, records its wall time under NAME, returns its status
  local name="$1" t0 rc=0
  shift
  t0=$(now_ms)
  "$@" || rc=$?
  phases+=("$name $(seconds $(($(now_ms) - t0)))")
  return $rc
}

# clippy-driver is rustc plus clippy's lints: run by the workspace wrapper (RUSTC_WORKSPACE_WRAPPER) it lints
# the workspace's own crates (not the dependencies) during the ordinary build, which is what `cargo clippy`
# does in a check build. CLIPPY_ARGS is how cargo-clippy hands `-- -D warnings` to the driver. The wrapper
# also compiles the test harnesses themselves without optimisation (scripts/rustc-workspace-wrapper.sh).
clippy_driver="$(rustc --print sysroot)/bin/clippy-driver"
[ -x "$clippy_driver" ] || clippy_driver="$(command -v clippy-driver || true)"
if [ -z "$clippy_driver" ]; then
  echo "make test needs clippy (rustup component add clippy)" >&2
  exit 1
fi
export SPINEDRR_CLIPPY_DRIVER="$clippy_driver"
export RUSTC_WORKSPACE_WRAPPER="$PWD/scripts/rustc-workspace-wrapper.sh"
export CLIPPY_ARGS="-D__CLIPPY_HACKERY__warnings__CLIPPY_HACKERY__"
# The Python module is compiled by the same build as an extension module (no libpython linked: what maturin
# sets) for the system python3 the venv is made from, so it is installed as built (`python/install-dev.sh`).
export PYO3_PYTHON=python3
export PYO3_BUILD_EXTENSION_MODULE=1

static_checks() {
  cargo fmt --all -- --check
  python3 scripts/check_import_cycles.py src
  python3 scripts/check_import_cycles.py core/src
}

build() {
  # The venv (pip, network) is made while cargo compiles.
  bash python/make-venv.sh "$PYENV" > target/venv.log 2>&1 &
  local venv=$!
  local rc=0
  # --timings leaves target/cargo-timings/cargo-timing.html: which crate compiled when, and for how long.
  cargo build --workspace --all-targets --timings || rc=$?
  wait "$venv" || { cat target/venv.log >&2; return 1; }
  return $rc
}

rust_tests() {
  set -o pipefail
  # The Slurm tests mostly wait on the scheduler (measured beside the other tests, session 32: 221 s of wall
  # for 61 CPU-s in their process, their jobs' work running under slurmd) and, last in libtest's
  # alphabetical order, they were the run's tail with one core idle; they run in a second process of the
  # test binary from the start instead, and their output follows the rest.
  local rc=0 slurm_rc=0
  # `--workspace` as below: the same feature resolution, so the same binary (without it, cargo resolves the
  # root package's features alone and compiles a second library and test binary meanwhile).
  cargo test --workspace --test it -- study_slurm --test-threads 2 > target/test-slurm.log 2>&1 &
  local slurm=$!
  # Four test threads on two cores: several tests mostly wait (subprocesses, locks), and the in-process ones
  # share one rayon pool (measured: 484 s against 514 s with two).
  cargo test --workspace --lib --bins --tests -- --test-threads 4 --skip study_slurm 2>&1 |
    tee target/test.log || rc=$?
  wait "$slurm" || slurm_rc=$?
  tee -a target/test.log < target/test-slurm.log
  [ "$rc" -ne 0 ] && return "$rc"
  return "$slurm_rc"
}

python_tests() {
  set -o pipefail
  bash python/install-dev.sh "$PYENV" target/debug
  SPINEDRR_BIN=target/debug/spinedrr "$PYENV/bin/python" -m pytest -p no:cacheprovider python/tests 2>&1 |
    tee target/pytest.log
}

t_start=$(now_ms)
rm -f target/test.log target/test-slurm.log target/pytest.log target/python.out target/python.status
status=0
phase deps bash scripts/install-deps.sh || status=$?
[ $status -ne 0 ] || phase static static_checks || status=$?
[ $status -ne 0 ] || phase build build || status=$?
if [ $status -eq 0 ]; then
  # The Python tests run beside the Rust tests (they mostly wait on the CLI's subprocesses, and fill the
  # cores the Rust tests' tail leaves idle); each phase's time is its own wall time from the common start.
  # Both always run, so both totals count; the Python output follows the Rust output.
  t_tests=$(now_ms)
  (
    rc=0
    python_tests > target/python.out 2>&1 || rc=$?
    echo "$rc $(($(now_ms) - t_tests))" > target/python.status
  ) &
  python_pid=$!
  rust_tests || status=$?
  phases+=("rust $(seconds $(($(now_ms) - t_tests)))")
  wait "$python_pid" || true
  cat target/python.out
  read -r py_rc py_ms < target/python.status || { py_rc=1; py_ms=0; }
  phases+=("python $(seconds "$py_ms")")
  [ "$py_rc" -eq 0 ] || status=$py_rc
fi

rust_counts=$(awk '/^test result:/ {p += $4; f += $6} END {print p + 0, f + 0}' target/test.log 2>/dev/null ||
  echo 0 0)
py_counts="0 0"
[ -f target/pytest.log ] &&
  py_counts=$(awk '/ in [0-9.]+s/ && /(passed|failed|error)/ { for (i = 2; i <= NF; i++) {
      if ($i ~ /^passed/) p += $(i-1); if ($i ~ /^(failed|error)/) f += $(i-1) } } END {print p + 0, f + 0}' \
    target/pytest.log)
echo
echo "wall time per phase (s):"
for p in "${phases[@]}"; do printf '  %-7s %7s\n' ${p}; done
printf '  %-7s %7s\n' total "$(seconds $(($(now_ms) - t_start)))"
echo "Rust: ${rust_counts% *} passed, ${rust_counts#* } failed; Python: ${py_counts% *} passed, ${py_counts#* } failed"
printf '%s\n%s\n' "$rust_counts" "$py_counts" | awk '{p += $1; f += $2} END {printf "%d passed, %d failed\n", p, f}'
exit $status
