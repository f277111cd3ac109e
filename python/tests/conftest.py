"""Shared fixtures: the spinedrr CLI (the independent reference every Python result is checked against),
a phantom built once, and files the CLI writes."""

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
import tifffile

import spinedrr

ROOT = Path(__file__).resolve().parents[2]


def _cli_path() -> Path:
    """$SPINEDRR_BIN, else the newer of the release and debug builds (`cargo test` makes the debug one)."""
    if "SPINEDRR_BIN" in os.environ:
        p = Path(os.environ["SPINEDRR_BIN"])
        p = p if p.is_absolute() else ROOT / p
        found = [p] if p.exists() else []
    else:
        found = [p for p in (ROOT / "target" / b / "spinedrr" for b in ("release", "debug")) if p.exists()]
    if not found:
        raise RuntimeError("the spinedrr CLI is not built: run `cargo build` (or set SPINEDRR_BIN)")
    return max(found, key=lambda p: p.stat().st_mtime)


# The phantom mesh cache the CLI runs share (the Rust integration tests use the same one), never the
# user's own cache.
MESH_CACHE = ROOT / "target" / "tmp" / "phantom-mesh-cache"


class Cli:
    """Runs `spinedrr ARGS…` and fails the test with its stderr when it fails."""

    def __init__(self, exe: Path):
        self.exe = exe

    def __call__(self, *args) -> subprocess.CompletedProcess:
        env = {**os.environ, "SPINEDRR_CACHE_DIR": str(MESH_CACHE)}
        r = subprocess.run([str(self.exe), *map(str, args)], capture_output=True, text=True, env=env)
        if r.returncode != 0:
            raise AssertionError(f"spinedrr {' '.join(map(str, args))} failed:\n{r.stderr}")
        return r

    def render(self, out: Path, *args) -> np.ndarray:
        """`spinedrr render … --out OUT` and the TIFF it wrote."""
        self("render", *args, "--out", out)
        return tifffile.imread(out)


@pytest.fixture(scope="session")
def cli() -> Cli:
    return Cli(_cli_path())


@pytest.fixture(scope="session")
def l3():
    """The L3 phantom as `spinedrr render --phantom L3` builds it."""
    return spinedrr.phantom("L3")


@pytest.fixture(scope="session")
def carm():
    return spinedrr.CArm.default()


@pytest.fixture(scope="session")
def phantom_dir(cli, tmp_path_factory) -> Path:
    """`spinedrr phantom --levels L3` output: meshes, landmarks.json, a 1 mm synthetic CT and its labels."""
    d = tmp_path_factory.mktemp("phantom")
    cli(
        "phantom", "--levels", "L3", "--out", d, "--ct", d / "ct.nii.gz", "--ct-voxel-mm", "1.0",
        "--labels-out", d / "seg.nii.gz",
    )
    return d


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal shape, dtype and every bit (NaN and -0.0 included)."""
    if a.shape != b.shape or a.dtype != b.dtype:
        return False
    width = {4: np.uint32, 8: np.uint64, 1: np.uint8}[a.dtype.itemsize]
    return bool(np.array_equal(np.ascontiguousarray(a).view(width), np.ascontiguousarray(b).view(width)))


def read_json(path: Path):
    return json.loads(Path(path).read_text())
