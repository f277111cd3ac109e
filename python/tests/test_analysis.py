"""compare and register from Python against `spinedrr compare` (metrics.json) and `spinedrr register`
(R.json); bad inputs."""

import json

import numpy as np
import pytest

import spinedrr
from conftest import read_json


@pytest.mark.parametrize("view_name", ["ap", "lat"])
def test_compare_returns_the_cli_metrics(cli, l3, carm, phantom_dir, tmp_path, view_name):
    ref_tiff, pert_tiff = tmp_path / "ref.tiff", tmp_path / "pert.tiff"
    cli.render(ref_tiff, "--phantom", "L3", "--view", view_name, "--masks")
    cli.render(pert_tiff, "--phantom", "L3", "--view", view_name, "--perturb", "df=500,dcx=8", "--masks")
    cli("compare", "--reference", ref_tiff, "--perturbed", pert_tiff, "--landmarks", phantom_dir / "landmarks.json", "--out", tmp_path / "cmp")
    expected = read_json(tmp_path / "cmp" / "metrics.json")

    view = carm.view(view_name)
    pview = view.perturbed(spinedrr.Perturbation(df=500, dcx=8))
    ref, rmasks = spinedrr.render_mesh(l3.scene, view, masks=True)
    pert, pmasks = spinedrr.render_mesh(l3.scene, pview, masks=True)
    # The CLI pairs OUT_mask_NAME.png files by name, sorted: every object and structure silhouette.
    pairs = {}
    for group in ("objects", "structures"):
        for name in rmasks[group]:
            if name in pmasks[group]:
                pairs[name] = (rmasks[group][name], pmasks[group][name])
    pairs = dict(sorted(pairs.items()))
    got = spinedrr.compare(ref, pert, masks=pairs, landmarks=l3.landmarks, views=(view, pview))

    assert set(got) == {"image", "silhouettes", "landmarks"}
    for key in ("image", "silhouettes", "landmarks"):
        assert got[key] == expected[key], key
    # Not vacuous: the perturbation moved things, and the landmark shifts follow the homography law.
    assert 0 < got["image"]["ncc"] < 1 and len(got["silhouettes"]) == len(pairs) + 1
    assert len(got["landmarks"]) == len(l3.landmarks) == 10
    for lm in got["landmarks"]:
        assert lm["shift_px"] > 1 and abs(lm["shift_px"] - lm["predicted_shift_px"]) < 1e-6


def test_compare_image_only_and_bad_inputs(l3, carm):
    view = carm.view("ap")
    a = spinedrr.render_mesh(l3.scene, view)
    same = spinedrr.compare(a, a)
    assert same["image"]["ncc"] == pytest.approx(1.0) and same["image"]["max_abs_diff"] == 0.0
    assert same["silhouettes"] == [] and same["landmarks"] == []
    with pytest.raises(TypeError, match="reference must have dtype float32, got float64"):
        spinedrr.compare(a.astype(np.float64), a)
    with pytest.raises(ValueError, match="the images differ in size"):
        spinedrr.compare(a, np.ascontiguousarray(a[:512]))
    with pytest.raises(ValueError, match="C-contiguous"):
        spinedrr.compare(a.T, a)
    with pytest.raises(ValueError, match="landmark shifts need both images' views"):
        spinedrr.compare(a, a, landmarks=l3.landmarks)
    with pytest.raises(ValueError, match=r"masks\['body'\]\[1\] must have shape \(1024, 1024\)"):
        spinedrr.compare(a, a, masks={"body": (a > 0, np.zeros((3, 3), dtype=bool))})
    with pytest.raises(TypeError, match=r"masks\['body'\]\[0\] must have dtype bool_"):
        spinedrr.compare(a, a, masks={"body": ((a > 0).astype(np.uint8), a > 0)})
    with pytest.raises(ValueError, match="is not finite"):
        spinedrr.compare(a, a, landmarks={"x": [0, np.nan, 0]}, views=(view, view))


def rotation(axis, deg):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = np.radians(deg)
    return np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * k @ k


@pytest.fixture(scope="module")
def problem(l3, carm):
    """Two-view landmark problem of L3 under a known pose (observations by the library's projection)."""
    names = sorted(l3.landmarks)
    model = np.array([l3.landmarks[n] for n in names])
    r, t = rotation([0.3, -0.5, 0.8], 4.0), np.array([2.0, -3.0, 1.5])
    world = model @ r.T + t
    views = []
    for name in ("ap", "lat"):
        v = carm.view(name)
        uv = v.project(world)
        views.append({
            "name": name, "K": v.K, "world_to_camera": v.world_to_camera, "width": v.width, "height": v.height,
            "observed": {n: uv[i] for i, n in enumerate(names)},
        })
    return {
        "landmarks_3d": {n: model[i] for i, n in enumerate(names)},
        "views": views,
        "truth": {"R": r, "t": t},
    }


def to_json(obj):
    return json.dumps(obj, default=lambda o: o.tolist())


@pytest.mark.parametrize("method", ["direct", "kabsch", "opencv", "opencv-sqpnp"])
@pytest.mark.parametrize("extra", [[], ["--noise-px", "0.5", "--seed", "7", "--init-rot-deg", "5", "--init-trans-mm", "3"]])
def test_register_returns_the_cli_record(cli, problem, tmp_path, method, extra):
    path = tmp_path / "problem.json"
    path.write_text(to_json(problem))
    kwargs, views = {}, []
    if method.startswith("opencv"):  # PnP is single-view
        kwargs, views = {"views": ["ap"]}, ["--view", "ap"]
    cli("register", "--problem", path, "--method", method, *views, *extra, "--out", tmp_path / "R.json")
    expected = read_json(tmp_path / "R.json")
    if extra:
        kwargs.update(noise_px=0.5, seed=7, init_rot_deg=5.0, init_trans_mm=3.0)
    got = spinedrr.register(problem, method=method, **kwargs)
    assert got == expected
    assert got == spinedrr.register(to_json(problem), method=method, **kwargs)
    if not extra:  # exact observations: the truth comes back
        assert got["rot_err_deg"] < 1e-4 and got["trans_err_mm"] < 1e-3


def test_register_one_view_and_bad_inputs(cli, problem, tmp_path):
    path = tmp_path / "problem.json"
    path.write_text(to_json(problem))
    cli("register", "--problem", path, "--view", "lat", "--out", tmp_path / "R.json")
    assert spinedrr.register(problem, views=["lat"]) == read_json(tmp_path / "R.json")
    with pytest.raises(ValueError, match="unknown|method"):
        spinedrr.register(problem, method="icp")
    with pytest.raises(TypeError, match="problem must be a dict"):
        spinedrr.register(42)
    with pytest.raises(ValueError, match="noise_px"):
        spinedrr.register(problem, noise_px=-1.0)
    nan_k = dict(problem, views=[dict(problem["views"][0], K=np.eye(3) * np.nan)])
    with pytest.raises(ValueError, match="problem: Out of range float values are not JSON compliant"):
        spinedrr.register(nan_k)
    k = problem["views"][0]["K"].copy()
    k[2, 2] = 2.0
    with pytest.raises(ValueError, match=r"views\[0\]\.K.*upper triangular"):
        spinedrr.register(dict(problem, views=[dict(problem["views"][0], K=k)]))
