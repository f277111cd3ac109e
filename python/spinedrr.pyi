"""spinedrr: calibration-sensitivity analysis of vertebral DRRs from Python.

Conventions (the CLI's): world frame RAS+ in millimetres; camera frame OpenCV's (origin at the X-ray
source, +z along the central ray toward the detector, +x along detector rows, +y down the detector);
pixel centres at integer coordinates; ``x ~ K [R | t] X`` with ``K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]``.
Images are float32 ``H × W`` arrays (row v, column u), handed to numpy without a copy. Renders, phantom
builds, comparisons and registrations release the GIL. Errors: ``ValueError`` (bad values or file
content), ``OSError`` (files), ``TypeError`` (wrong types or dtypes), with the library's messages.
"""

from os import PathLike
from typing import Any, Literal, Mapping, Sequence, overload

import numpy as np
import numpy.typing as npt

__version__: str
MU_WATER_PER_MM: float

Backend = Literal["raster", "embree", "bvh", "gpu"]
F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]
Bool = npt.NDArray[np.bool_]

class Perturbation:
    """Intrinsic perturbation: ``fx' = (alpha·fx + df)·sx``, ``fy' = (alpha·fy + df)·sy``,
    ``cx' = cx + dcx``, ``cy' = cy + dcy``, ``s' = s + skew`` (px); extrinsics unchanged."""

    def __init__(
        self, df: float = 0.0, alpha: float = 1.0, dcx: float = 0.0, dcy: float = 0.0,
        skew: float = 0.0, sx: float = 1.0, sy: float = 1.0,
    ) -> None: ...
    @staticmethod
    def parse(spec: str) -> Perturbation:
        """The CLI's ``--perturb`` spec, e.g. ``"df=300,dcx=20"``."""
    df: float
    alpha: float
    dcx: float
    dcy: float
    skew: float
    sx: float
    sy: float

class View:
    """One acquisition: ``K`` (3 × 3, px), ``world_to_camera`` (4 × 4, mm), detector ``width × height``."""

    def __init__(self, name: str, K: F64, world_to_camera: F64, width: int, height: int) -> None: ...
    name: str
    K: F64
    world_to_camera: F64
    width: int
    height: int
    source: F64
    def project(self, points: F64) -> F64:
        """``(N, 3)`` float64 world mm → ``(N, 2)`` float64 pixels ``(u, v)``."""
    def perturbed(self, p: Perturbation) -> View: ...

class CArm:
    """A detector and named views (``ap``, ``lat`` by default)."""

    @staticmethod
    def default() -> CArm: ...
    @staticmethod
    def from_file(path: str | PathLike[str]) -> CArm: ...
    @staticmethod
    def from_toml(text: str) -> CArm: ...
    def view(self, name: str) -> View: ...
    view_names: list[str]

class Mesh:
    """Closed triangle mesh: ``vertices`` (N, 3) float64 mm, ``faces`` (M, 3) uint32, ``labels`` (M,) uint8."""

    def __init__(self, vertices: F64, faces: npt.NDArray[np.uint32], labels: npt.NDArray[np.uint8] | None = None, name: str = "mesh") -> None: ...
    name: str
    vertices: F64
    faces: npt.NDArray[np.uint32]
    labels: npt.NDArray[np.uint8]
    def __len__(self) -> int: ...

class Phantom:
    """``scene``: ``[(Mesh, mu_per_mm, object)]`` as ``spinedrr render --phantom`` renders it;
    ``landmarks``: ``{"L3/name": array([x, y, z])}`` world mm."""

    scene: list[tuple[Mesh, float, str]]
    meshes: list[Mesh]
    landmarks: dict[str, F64]

def phantom(levels: str = "L1-L5", soft_tissue: bool = False, discs: bool = True) -> Phantom: ...
def read_mesh(path: str | PathLike[str]) -> Mesh: ...

MeshWithMu = tuple[Mesh, float] | tuple[Mesh, float, str]
Masks = dict[str, Any]  # {"all": Bool, "objects": {name: Bool}, "structures": {name: Bool}}

class Renderer:
    """A thickness-DRR renderer of a fixed scene, built once."""

    def __init__(self, meshes_with_mu: Sequence[MeshWithMu], backend: Backend = "raster") -> None: ...
    backend: str
    adapter: str | None
    """The GPU adapter the renders run on (``backend="gpu"``), else ``None``."""
    objects: list[str]
    open_meshes: list[str]
    @overload
    def render(self, view: View) -> F32: ...
    @overload
    def render(self, view: View, masks: bool = ..., depth: bool = ..., stats: bool = ...) -> F32 | tuple[Any, ...]:
        """Line integral (float32 H × W), or ``(image, masks, depth, stats)`` with what was asked for."""

@overload
def render_mesh(meshes_with_mu: Sequence[MeshWithMu], view: View, backend: Backend = "raster") -> F32: ...
@overload
def render_mesh(
    meshes_with_mu: Sequence[MeshWithMu], view: View, backend: Backend = "raster", masks: bool = ...,
    depth: bool = ..., stats: bool = ...,
) -> F32 | tuple[Any, ...]:
    """Line integral ``Σ μ·L`` (float32 H × W); with ``masks``/``depth``/``stats`` a tuple
    ``(image, masks, depth, stats)`` of what was asked for."""

class CtRenderer:
    """A CT volume DRR renderer of a fixed CT, built once: ``render_ct``'s arguments but the view. HU → μ
    and the Siddon walk's running sums are computed once; each ``render`` equals ``render_ct`` bit for bit.
    ``backend="gpu"`` renders with compute shaders on the machine's GPU adapter (to ~1e-5 relative)."""

    def __init__(
        self, hu: npt.NDArray[Any], affine: F64, mask: Bool | None = None,
        method: Literal["siddon", "trilinear"] = "siddon", mu_water: float = ..., step_mm: float | None = None,
        placement: Literal["volume-centre", "label-centre", "auto", "keep"] = "volume-centre",
        backend: Literal["cpu", "gpu"] = "cpu",
    ) -> None: ...
    @property
    def adapter(self) -> str | None:
        """The GPU adapter that renders (``backend="gpu"``), or ``None`` on the CPU."""
    def render(self, view: View) -> F32:
        """Line integrals of μ along the rays of ``view`` (float32 H × W)."""

def render_ct(
    hu: npt.NDArray[Any], affine: F64, view: View, mask: Bool | None = None,
    method: Literal["siddon", "trilinear"] = "siddon", mu_water: float = ..., step_mm: float | None = None,
    placement: Literal["volume-centre", "label-centre", "auto", "keep"] = "volume-centre",
) -> F32:
    """CT DRR of a nibabel-style (i, j, k) HU array with its 4 × 4 index → world affine, placed where the
    views aim (``placement``, as ``spinedrr render --placement``)."""

def material_mu_rho(name: str, energies_kev: Sequence[float], energy_absorption: bool = False) -> F64:
    """μ/ρ (cm²/g; μ_en/ρ with ``energy_absorption``) of a built-in material at each energy (1–200 keV), from
    the embedded NIST SRD 126 element tables."""

def spectrum(spec: str, filters: str = "", detector: str = "csi:0.6") -> dict[str, Any]:
    """The sidecar's ``spectral`` record of ``--spectrum SPEC --filter FILTERS --detector DETECTOR``:
    ``energies_kev``, ``fluence``, ``mean_energy_kev``, ``hvl_al_mm``, ``detector_weights``, …"""

def render_spectral(
    view: View, spectrum: str, meshes: Sequence[tuple[Mesh, float | str] | tuple[Mesh, float | str, str]] | None = None,
    phantom: str | None = None, soft_tissue: bool = False, screws: bool = False, filters: str = "",
    detector: str = "csi:0.6",
    backend: Backend = "raster",
    ct: npt.NDArray[Any] | None = None, affine: F64 | None = None, mask: Bool | None = None,
    placement: Literal["volume-centre", "label-centre", "auto", "keep"] = "volume-centre",
    implants: Sequence[tuple[Mesh, str] | tuple[Mesh, str, F64]] | None = None,
    screws_at: Mapping[str, Sequence[float]] | None = None,
) -> tuple[F32, dict[str, Any]]:
    """``(−ln(I/I0) float32 H × W, spectral record)`` as ``spinedrr render --spectrum …`` writes them. The
    anatomy is one of ``meshes`` (μ or ``"MATERIAL[@DENSITY]"``), ``phantom="L1-L5"`` or ``ct`` (HU array
    with its ``affine``, ``mask``, ``placement``); ``implants`` (material meshes, optionally with a 4 × 4
    pose) and ``screws_at`` (a plan's ``PREFIXpedicle_entry``/``PREFIXpedicle_tip`` points) displace what
    they occupy. ``backend="gpu"`` renders the material channels of meshes or a CT on the GPU (the energy
    sum on the host) and refuses implants."""

def intensity(line_integral: F32, i0: float) -> F32:
    """``I0 · exp(−L)`` of a line-integral image, as ``spinedrr render --intensity I0`` writes it."""

def compare(
    reference: F32, perturbed: F32, masks: Mapping[str, tuple[Bool, Bool]] | None = None,
    landmarks: Mapping[str, Sequence[float] | F64] | None = None, views: tuple[View, View] | None = None,
) -> dict[str, Any]:
    """``{"image": …, "silhouettes": […], "landmarks": […]}`` as in ``spinedrr compare``'s metrics.json."""

def register(
    problem: Mapping[str, Any] | str, method: str = "direct", views: Sequence[str] | None = None,
    noise_px: float = 0.0, seed: int = 0, init_rot_deg: float | None = None, init_trans_mm: float | None = None,
    max_iterations: int = 100,
) -> dict[str, Any]:
    """The ``R.json`` record of ``spinedrr register``."""
