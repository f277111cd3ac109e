#!/usr/bin/env bash
# Installs the `spinedrr` extension module that `cargo test --workspace` (scripts/test.sh) compiled into
# the virtual environment $1, from the build folder $2 (target/debug): the cdylib as
# `spinedrr<EXT_SUFFIX>` with its type stubs beside it, replacing any installed `spinedrr` (a wheel
# from `make python` included). The module must have been built with PYO3_BUILD_EXTENSION_MODULE=1
# (no libpython linked), as maturin builds it.
set -euo pipefail
venv="$1"
build="$2"
lib="$build/libspinedrr_py.so"
if [ ! -f "$lib" ]; then
  echo "install-dev.sh: $lib is missing (build the workspace first: cargo test --workspace --no-run)" >&2
  exit 1
fi
py="$venv/bin/python"
"$py" -m pip uninstall --quiet --yes spinedrr >/dev/null 2>&1 || true
site=$("$py" -c 'import sysconfig; print(sysconfig.get_paths()["platlib"])')
suffix=$("$py" -c 'import sysconfig; print(sysconfig.get_config_var("EXT_SUFFIX"))')
rm -rf "$site/spinedrr" "$site"/spinedrr.*.so "$site/spinedrr.pyi"
# A copy, not a link: a later build must not change the module under a running interpreter.
cp "$lib" "$site/spinedrr$suffix"
cp "$(dirname "$0")/spinedrr.pyi" "$site/spinedrr.pyi"
"$py" -c 'import spinedrr' || { echo "install-dev.sh: the installed module does not import" >&2; exit 1; }
