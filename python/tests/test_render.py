"""Thickness DRRs from Python against the CLI's TIFFs, bit for bit; masks and depth against its files;
bad inputs; four Python threads rendering at once."""

import threading
import time
import warnings

import numpy as np
import pytest
import tifffile
from PIL import Image

import spinedrr
from conftest import read_json, same_bits


@pytest.mark.parametrize(
    "view_name, spec",
    [("ap", "none"), ("lat", "df=500"), ("ap", "dcx=20,dcy=-10,skew=1.5"), ("lat", "alpha=1.05,sx=1.01,sy=0.99")],
)
def test_phantom_render_equals_cli_tiff(cli, l3, carm, tmp_path, view_name, spec):
    expected = cli.render(tmp_path / "cli.tiff", "--phantom", "L3", "--view", view_name, "--perturb", spec)
    view = carm.view(view_name).perturbed(spinedrr.Perturbation.parse(spec))
    image, stats = spinedrr.render_mesh(l3.scene, view, stats=True)
    assert image.dtype == np.float32 and image.shape == (1024, 1024)
    assert image.max() > 1.0  # the vertebra is in the picture
    assert same_bits(image, expected)
    cli_stats = read_json(tmp_path / "cli.json")["details"]["stats"]
    assert stats.pop("render_ms") > 0 and cli_stats.pop("render_ms") > 0
    assert stats == cli_stats and stats["rays_traced"] > 0


def test_intensity_equals_cli_intensity_tiff(cli, l3, carm, tmp_path):
    expected = cli.render(tmp_path / "cli.tiff", "--phantom", "L3", "--view", "lat", "--intensity", "10000")
    line_integral = spinedrr.render_mesh(l3.scene, carm.view("lat"))
    image = spinedrr.intensity(line_integral, 1e4)
    assert same_bits(image, expected)
    # Beer–Lambert, independently: air pixels carry I0, the vertebra attenuates.
    assert image.max() == np.float32(1e4) and image.min() < 1e4 * np.exp(-1.0)
    with pytest.raises(ValueError, match="I0"):
        spinedrr.intensity(line_integral, -1.0)


@pytest.mark.parametrize("backend", ["raster", "embree", "bvh", "gpu"])
def test_mesh_files_render_equals_cli_with_masks_and_depth(cli, phantom_dir, carm, tmp_path, backend):
    cortical, cancellous = phantom_dir / "L3_cortical.stl", phantom_dir / "L3_cancellous.stl"
    out = tmp_path / "cli.tiff"
    expected = cli.render(
        out, "--mesh", f"{cortical}:0.04", "--mesh", f"{cancellous}:-0.02", "--view", "lat",
        "--perturb", "df=300", "--backend", backend, "--masks", "--depth",
    )
    meshes = [(spinedrr.read_mesh(cortical), 0.04, "L3_cortical"), (spinedrr.read_mesh(cancellous), -0.02, "L3_cancellous")]
    view = carm.view("lat").perturbed(spinedrr.Perturbation(df=300))
    image, masks, depth = spinedrr.render_mesh(meshes, view, backend=backend, masks=True, depth=True)
    assert same_bits(image, expected)
    assert same_bits(depth, tifffile.imread(tmp_path / "cli_depth.tiff"))

    def png(suffix):
        return np.asarray(Image.open(tmp_path / f"cli_mask{suffix}.png")) > 0

    assert np.array_equal(masks["all"], png(""))
    assert sorted(masks["objects"]) == ["L3_cancellous", "L3_cortical"]
    for name, m in masks["objects"].items():
        assert m.dtype == np.bool_ and np.array_equal(m, png(f"_{name}"))
    assert "body" in masks["structures"]
    for name, m in masks["structures"].items():
        assert np.array_equal(m, png(f"_{name}"))


def test_renderer_reuses_its_scene(l3, carm):
    r = spinedrr.Renderer(l3.scene)
    assert r.backend == "raster" and r.objects == ["L3"] and r.open_meshes == []
    view = carm.view("ap")
    assert same_bits(r.render(view), spinedrr.render_mesh(l3.scene, view))
    image, masks = r.render(view, masks=True)
    assert same_bits(image, r.render(view))
    # The silhouette is where the line integral is positive (the phantom has no μ = 0 shell).
    assert np.array_equal(masks["all"], image != 0)
    image2, depth = r.render(view, depth=True)
    assert same_bits(image2, image) and depth.dtype == np.float32
    # Depth is the camera z of the first surface: inside the silhouette, between source and detector.
    inside = depth[masks["all"]]
    assert np.all(depth[~masks["all"]] == 0) and inside.min() > 0 and inside.max() < 1000 + 50


def test_a_gpu_renderer_equals_the_raster(l3, carm):
    """``backend="gpu"`` (lavapipe in CI): path lengths within 1e-4 mm (μ ≤ 0.06 mm⁻¹: 6e-6 of line
    integral), the same silhouettes, and the adapter named."""
    cpu, gpu = spinedrr.Renderer(l3.scene), spinedrr.Renderer(l3.scene, backend="gpu")
    assert gpu.backend == "gpu" and gpu.adapter and cpu.adapter is None
    for name in ("ap", "lat"):
        view = carm.view(name).perturbed(spinedrr.Perturbation(df=200, dcx=3))
        (a, ma), (b, mb) = cpu.render(view, masks=True), gpu.render(view, masks=True)
        assert a.max() > 1 and np.abs(a.astype(np.float64) - b).max() <= 6e-6
        assert np.array_equal(ma["all"], mb["all"])
        assert ma["structures"].keys() == mb["structures"].keys()
        for k in ma["structures"]:
            assert np.array_equal(ma["structures"][k], mb["structures"][k])


def test_output_is_handed_over_without_a_copy(l3, carm):
    image = spinedrr.render_mesh(l3.scene, carm.view("ap"))
    assert not image.flags["OWNDATA"] and image.base is not None  # numpy wraps the Rust buffer
    assert image.flags["C_CONTIGUOUS"] and image.flags["WRITEABLE"]


def test_mesh_arrays_round_trip(l3):
    m = l3.meshes[0]
    again = spinedrr.Mesh(m.vertices, m.faces, m.labels, name=m.name)
    assert np.array_equal(again.vertices, m.vertices) and np.array_equal(again.faces, m.faces)
    assert np.array_equal(again.labels, m.labels) and len(again) == len(m)
    assert m.vertices.dtype == np.float64 and m.faces.dtype == np.uint32 and m.labels.dtype == np.uint8


CUBE_V = np.array([[x, y, z] for x in (-10.0, 10.0) for y in (-10.0, 10.0) for z in (-10.0, 10.0)])
CUBE_F = np.array(
    [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
     [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], dtype=np.uint32)


def test_a_cube_is_as_thick_as_its_side(carm):
    # Analytic: a 20 mm cube at the isocentre, μ = 1, seen through its centre is 20 mm thick.
    cube = spinedrr.Mesh(CUBE_V, CUBE_F, name="cube")
    view = carm.view("ap")
    centre = view.project(np.zeros((1, 3)))[0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a closed mesh renders without a warning
        image = spinedrr.render_mesh([(cube, 1.0)], view)
    u, w = int(round(centre[0] + 0.5)), int(round(centre[1] + 0.5))
    assert abs(image[w, u] - 20.0) < 0.2  # the ray through a pixel near the centre is nearly axial


def test_an_open_mesh_is_rendered_with_a_warning(carm):
    box = spinedrr.Mesh(CUBE_V, np.ascontiguousarray(CUBE_F[2:]), name="lidless")
    with pytest.warns(RuntimeWarning, match="mesh 'lidless' is not closed"):
        spinedrr.Renderer([(box, 1.0)])
    with pytest.warns(RuntimeWarning, match="mesh 'lidless' is not closed"):
        spinedrr.render_mesh([(box, 1.0)], carm.view("ap"))


def test_bad_render_inputs(l3, carm):
    view = carm.view("ap")
    m = l3.meshes[0]
    with pytest.raises(TypeError, match="vertices must have dtype float64, got float32"):
        spinedrr.Mesh(m.vertices.astype(np.float32), m.faces)
    with pytest.raises(ValueError, match="C-contiguous"):
        spinedrr.Mesh(np.asfortranarray(m.vertices), m.faces)
    with pytest.raises(ValueError, match=r"vertices must have shape \(N, 3\), got \[.*, 2\]"):
        spinedrr.Mesh(m.vertices[:, :2].copy(), m.faces)
    with pytest.raises(TypeError, match="faces must have dtype uint32, got int64"):
        spinedrr.Mesh(m.vertices, m.faces.astype(np.int64))
    bad = m.faces.copy()
    bad[0, 0] = len(m.vertices)
    with pytest.raises(ValueError, match="mesh 'mesh'"):
        spinedrr.Mesh(m.vertices, bad)
    with pytest.raises(ValueError, match=r"labels must have shape"):
        spinedrr.Mesh(m.vertices, m.faces, np.zeros(3, dtype=np.uint8))
    with pytest.raises(TypeError, match=r"meshes_with_mu\[0\] must be a \(Mesh, mu\)"):
        spinedrr.render_mesh([m], view)
    with pytest.raises(ValueError, match="unknown backend 'optix'"):
        spinedrr.render_mesh(l3.scene, view, backend="optix")
    with pytest.raises(ValueError, match="no meshes to render"):
        spinedrr.render_mesh([], view)
    with pytest.raises(ValueError, match="must be finite"):
        spinedrr.render_mesh([(m, float("nan"))], view)
    with pytest.raises(OSError, match="missing.stl"):
        spinedrr.read_mesh("missing.stl")


def test_four_threads_render_what_serial_calls_render(l3, carm):
    renderer = spinedrr.Renderer(l3.scene)
    views = [
        carm.view("ap"),
        carm.view("lat"),
        carm.view("ap").perturbed(spinedrr.Perturbation(df=500)),
        carm.view("lat").perturbed(spinedrr.Perturbation(dcx=20, dcy=-10)),
    ]
    rounds = 5
    t0 = time.perf_counter()
    serial = [[renderer.render(v) for v in views] for _ in range(rounds)]
    t_serial = time.perf_counter() - t0

    results = [[None] * len(views) for _ in range(rounds)]

    def work(i):
        for r in range(rounds):
            results[r][i] = renderer.render(views[i])

    threads = [threading.Thread(target=work, args=(i,)) for i in range(len(views))]
    t0 = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    t_threads = time.perf_counter() - t0
    for r in range(rounds):
        for i in range(len(views)):
            assert same_bits(results[r][i], serial[r][i])
    print(f"\n4 views x {rounds}: serial {t_serial:.3f} s, 4 threads {t_threads:.3f} s, ratio {t_serial / t_threads:.2f}")
