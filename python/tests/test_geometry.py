"""Geometry: projection against OpenCV's cv2.projectPoints, views and perturbations against the CLI."""

import math

import cv2
import numpy as np
import pytest

import spinedrr


def cv_project(view: spinedrr.View, points: np.ndarray) -> np.ndarray:
    m = view.world_to_camera
    rvec, _ = cv2.Rodrigues(m[:3, :3])
    uv, _ = cv2.projectPoints(points, rvec, m[:3, 3], view.K, None)
    return uv.reshape(-1, 2)


def points(n=200, seed=3):
    rng = np.random.default_rng(seed)
    return rng.uniform(-80.0, 80.0, size=(n, 3))


@pytest.mark.parametrize("name", ["ap", "lat"])
@pytest.mark.parametrize(
    "perturbation",
    [spinedrr.Perturbation(), spinedrr.Perturbation(df=500), spinedrr.Perturbation(alpha=1.05, dcx=20, dcy=-10, sx=1.01, sy=0.99)],
)
def test_project_equals_opencv(carm, name, perturbation):
    # cv2.projectPoints ignores K[0, 1] (skew), so these perturbations keep s = 0.
    view = carm.view(name).perturbed(perturbation)
    x = points()
    ours = view.project(x)
    assert ours.shape == (len(x), 2) and ours.dtype == np.float64
    assert np.max(np.abs(ours - cv_project(view, x))) < 1e-9


def test_skewed_projection_is_the_pinhole_equation(carm):
    view = carm.view("lat").perturbed(spinedrr.Perturbation(skew=2.5, dcx=7))
    x = points()
    cam = x @ view.world_to_camera[:3, :3].T + view.world_to_camera[:3, 3]
    h = cam @ view.K.T
    assert np.max(np.abs(view.project(x) - h[:, :2] / h[:, 2:])) < 1e-9


def test_perturbation_is_the_cli_spec(carm):
    kw = spinedrr.Perturbation(df=300, dcx=20, dcy=-10, skew=1.5, alpha=1.05, sx=1.01, sy=0.99)
    spec = spinedrr.Perturbation.parse("df=300,dcx=20,dcy=-10,skew=1.5,alpha=1.05,sx=1.01,sy=0.99")
    v = carm.view("ap")
    assert np.array_equal(v.perturbed(kw).K, v.perturbed(spec).K)
    fx = v.K[0, 0]
    assert v.perturbed(kw).K[0, 0] == (1.05 * fx + 300) * 1.01
    assert (kw.df, kw.alpha, kw.dcx, kw.dcy, kw.skew, kw.sx, kw.sy) == (300, 1.05, 20, -10, 1.5, 1.01, 0.99)


def test_geometry_file_round_trip(cli, tmp_path, carm):
    toml = cli("geometry").stdout
    path = tmp_path / "geometry.toml"
    path.write_text(toml)
    loaded = spinedrr.CArm.from_file(path)
    assert loaded.view_names == carm.view_names == ["ap", "lat"]
    for name in loaded.view_names:
        a, b = loaded.view(name), carm.view(name)
        assert np.array_equal(a.K, b.K) and np.array_equal(a.world_to_camera, b.world_to_camera)
        assert (a.width, a.height) == (b.width, b.height)
    # The source is the camera centre: it projects nowhere, and -R^T t is where world_to_camera sends 0.
    ap = carm.view("ap")
    r, t = ap.world_to_camera[:3, :3], ap.world_to_camera[:3, 3]
    assert np.allclose(r @ ap.source + t, 0.0, atol=1e-9)


def test_view_from_matrices(carm):
    ap = carm.view("ap")
    v = spinedrr.View("mine", ap.K, ap.world_to_camera, ap.width, ap.height)
    assert v.name == "mine"
    x = points(20)
    assert np.array_equal(v.project(x), ap.project(x))


def test_unknown_view_names_the_views(carm):
    with pytest.raises(ValueError, match=r"unknown view 'oblique' \(this geometry has: ap, lat\)"):
        carm.view("oblique")


def test_bad_geometry_inputs(carm, tmp_path):
    ap = carm.view("ap")
    k = ap.K.copy()
    k[0, 0] = math.nan
    with pytest.raises(ValueError, match="intrinsics.fx: must be finite"):
        spinedrr.View("x", k, ap.world_to_camera, 1024, 1024)
    with pytest.raises(ValueError, match=r"K must have shape \(3, 3\)"):
        spinedrr.View("x", ap.K[:2], ap.world_to_camera, 1024, 1024)
    with pytest.raises(TypeError, match="K must have dtype float64, got int64"):
        spinedrr.View("x", ap.K.astype(np.int64), ap.world_to_camera, 1024, 1024)
    with pytest.raises(ValueError, match="C-contiguous"):
        spinedrr.View("x", np.asfortranarray(ap.K), ap.world_to_camera, 1024, 1024)
    with pytest.raises(TypeError, match="must be a numpy array, got list"):
        spinedrr.View("x", ap.K.tolist(), ap.world_to_camera, 1024, 1024)
    with pytest.raises(ValueError, match="points must have shape"):
        ap.project(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="C-contiguous"):
        ap.project(np.zeros((3, 6))[:, ::2])
    with pytest.raises(ValueError, match="perturbation alpha: must be positive"):
        spinedrr.Perturbation(alpha=-1)
    with pytest.raises(ValueError, match="perturbation df: must be finite"):
        spinedrr.Perturbation(df=math.nan)
    with pytest.raises(ValueError, match="unknown key 'f'"):
        spinedrr.Perturbation.parse("f=3")
    with pytest.raises(ValueError, match="focal lengths must be positive"):
        ap.perturbed(spinedrr.Perturbation(df=-1e6))
    with pytest.raises(OSError, match="no-such.toml"):
        spinedrr.CArm.from_file(tmp_path / "no-such.toml")
