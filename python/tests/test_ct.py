"""CT volume DRRs from nibabel arrays against `spinedrr render --ct`, bit for bit; bad inputs; the GIL is
released while a CT renders."""

import threading
import time

import nibabel as nib
import numpy as np
import pytest

import spinedrr
from conftest import same_bits


@pytest.fixture(scope="module")
def ct(phantom_dir):
    img = nib.load(phantom_dir / "ct.nii.gz")
    return img, phantom_dir / "ct.nii.gz"


@pytest.mark.parametrize("method", ["siddon", "trilinear"])
@pytest.mark.parametrize("view_name, spec", [("ap", "none"), ("lat", "df=500,dcx=20")])
def test_ct_render_equals_cli(cli, ct, carm, tmp_path, method, view_name, spec):
    img, path = ct
    expected = cli.render(tmp_path / "ct.tiff", "--ct", path, "--method", method, "--view", view_name, "--perturb", spec)
    view = carm.view(view_name).perturbed(spinedrr.Perturbation.parse(spec))
    hu = img.get_fdata()  # float64, Fortran order, as nibabel gives it
    assert hu.dtype == np.float64 and hu.flags["F_CONTIGUOUS"]
    image = spinedrr.render_ct(hu, img.affine, view, method=method)
    assert image.dtype == np.float32 and image.shape == (1024, 1024) and image.max() > 0.5
    assert same_bits(image, expected)


def test_ct_layouts_and_dtypes_agree(ct, carm):
    img, _ = ct
    view = carm.view("ap")
    raw = np.asanyarray(img.dataobj)  # the file's float32 voxels
    assert raw.dtype == np.float32
    a = spinedrr.render_ct(raw, img.affine, view)
    assert same_bits(a, spinedrr.render_ct(np.ascontiguousarray(raw), img.affine, view))
    assert same_bits(a, spinedrr.render_ct(img.get_fdata(), img.affine, view))


def test_ct_label_and_bone_masks_equal_cli(cli, ct, phantom_dir, carm, tmp_path):
    img, path = ct
    seg = np.asanyarray(nib.load(phantom_dir / "seg.nii.gz").dataobj)
    labels = [int(v) for v in np.unique(seg) if v != 0]
    assert len(labels) == 1  # L3 alone
    hu = img.get_fdata()
    view = carm.view("lat")
    expected = cli.render(tmp_path / "seg.tiff", "--ct", path, "--seg", phantom_dir / "seg.nii.gz", "--label", "L3", "--view", "lat")
    # The CLI moves the label's voxel centroid to the origin; Python does when asked for it.
    labelled = spinedrr.render_ct(hu, img.affine, view, mask=seg == labels[0], placement="label-centre")
    assert same_bits(labelled, expected)
    kept = cli.render(tmp_path / "keep.tiff", "--ct", path, "--placement", "keep", "--view", "lat")
    assert same_bits(spinedrr.render_ct(hu, img.affine, view, placement="keep"), kept)
    expected = cli.render(tmp_path / "bone.tiff", "--ct", path, "--bone-hu", "150", "--view", "lat")
    bone = spinedrr.render_ct(hu, img.affine, view, mask=hu.astype(np.float32) >= 150)
    assert same_bits(bone, expected)
    full = spinedrr.render_ct(hu, img.affine, view)
    assert np.all(bone <= full + 1e-6) and bone.max() > 0


def test_a_ct_renderer_renders_many_views_as_render_ct(ct, phantom_dir, carm):
    img, _ = ct
    hu = img.get_fdata()
    seg = np.asanyarray(nib.load(phantom_dir / "seg.nii.gz").dataobj)
    views = [carm.view("ap"), carm.view("lat"), carm.view("ap").perturbed(spinedrr.Perturbation.parse("df=500,dcx=20"))]
    for kwargs in [{}, {"mask": seg != 0, "placement": "label-centre"}, {"method": "trilinear"}]:
        renderer = spinedrr.CtRenderer(hu, img.affine, **kwargs)
        # Views in turn and again (the running sums are built by the first view along an axis, then reused).
        for view in views + views[:1]:
            image = renderer.render(view)
            assert image.dtype == np.float32 and image.max() > 0.1
            assert same_bits(image, spinedrr.render_ct(hu, img.affine, view, **kwargs))
    with pytest.raises(ValueError, match="unknown|siddon"):
        spinedrr.CtRenderer(hu, img.affine, method="joseph")
    with pytest.raises(ValueError, match="invalid mask: keeps no voxel"):
        spinedrr.CtRenderer(hu, img.affine, mask=np.zeros(hu.shape, dtype=bool))


def test_a_gpu_ct_renderer_equals_the_cpu_renderer(ct, phantom_dir, carm):
    """``backend="gpu"`` (lavapipe in CI): the same integral within 1e-5 of the image's largest value, and
    of each pixel's own value where it carries a tenth of the largest. Trilinear's midpoint rule takes
    ⌈length / step⌉ samples, which jumps where a ray's length crosses a whole number of steps (in an AP
    view, on rings around the central ray; the CPU's image has the same rings): within f32's rounding of
    a ring a ray takes one sample more or fewer on the GPU than in f64 (measured: 12 of 48 000 rays here,
    off by ≤ 2.4e-5 of the image's largest value). Those are counted and held to 1e-4."""
    img, _ = ct
    hu = img.get_fdata()
    seg = np.asanyarray(nib.load(phantom_dir / "seg.nii.gz").dataobj)
    views = [carm.view("ap"), carm.view("lat").perturbed(spinedrr.Perturbation.parse("df=500,dcx=20"))]
    for kwargs in [{}, {"mask": seg != 0, "placement": "label-centre"}, {"method": "trilinear"}]:
        cpu = spinedrr.CtRenderer(hu, img.affine, **kwargs)
        gpu = spinedrr.CtRenderer(hu, img.affine, backend="gpu", **kwargs)
        assert cpu.adapter is None and gpu.adapter
        for view in views:
            a, b = cpu.render(view).astype(np.float64), gpu.render(view).astype(np.float64)
            top = a.max()
            assert top > 0.1
            diff = np.abs(b - a)
            if kwargs.get("method") == "trilinear":
                off = diff > 1e-5 * top
                assert off.sum() <= 1e-3 * (a > 0).sum() and diff.max() <= 1e-4 * top, (kwargs, off.sum())
                diff[off] = 0
            assert diff.max() <= 1e-5 * top, kwargs
            big = a >= 0.1 * top
            assert (diff[big] / a[big]).max() <= 1e-5, kwargs
    with pytest.raises(ValueError, match="cpu.*gpu"):
        spinedrr.CtRenderer(hu, img.affine, backend="cuda")


def test_bad_ct_inputs(ct, carm):
    img, _ = ct
    hu = img.get_fdata()
    view = carm.view("ap")
    with pytest.raises(ValueError, match="hu must be a 3-D array"):
        spinedrr.render_ct(hu[:, :, 0], img.affine, view)
    with pytest.raises(TypeError, match="hu must have dtype float32, float64 or int16, got complex128"):
        spinedrr.render_ct(hu.astype(np.complex128), img.affine, view)
    with pytest.raises(ValueError, match="hu must be C- or Fortran-contiguous"):
        spinedrr.render_ct(hu[::2], img.affine, view)
    with pytest.raises(ValueError, match=r"affine must have shape \(4, 4\)"):
        spinedrr.render_ct(hu, img.affine[:3], view)
    singular = img.affine.copy()
    singular[:3, 0] = 0
    with pytest.raises(ValueError, match="singular"):
        spinedrr.render_ct(hu, singular, view)
    with pytest.raises(ValueError, match="unknown|siddon"):
        spinedrr.render_ct(hu, img.affine, view, method="joseph")
    with pytest.raises(TypeError, match="mask must have dtype bool, got uint8"):
        spinedrr.render_ct(hu, img.affine, view, mask=np.ones(hu.shape, dtype=np.uint8))
    with pytest.raises(ValueError, match="mask has shape"):
        spinedrr.render_ct(hu, img.affine, view, mask=np.ones((2, 2, 2), dtype=bool))
    with pytest.raises(ValueError, match="invalid mask: keeps no voxel"):
        spinedrr.render_ct(hu, img.affine, view, mask=np.zeros(hu.shape, dtype=bool))


def test_python_runs_while_a_ct_renders(ct, carm):
    """A pure-Python thread keeps running during render_ct: the call does not hold the GIL."""
    img, _ = ct
    hu = np.asanyarray(img.dataobj)
    view = carm.view("lat")
    stamps = []
    stop = threading.Event()

    def spin():
        while not stop.is_set():
            stamps.append(time.perf_counter())
            time.sleep(0)  # let the render thread take the GIL back when it needs it

    t = threading.Thread(target=spin)
    t.start()
    time.sleep(0.05)
    t0 = time.perf_counter()
    spinedrr.render_ct(hu, img.affine, view, method="trilinear")
    t1 = time.perf_counter()
    stop.set()
    t.join()
    inside = [s for s in stamps if t0 <= s <= t1]
    # With the GIL held, the spinner would be frozen for the whole call (one gap of t1 - t0).
    gaps = np.diff([t0, *inside, t1])
    assert t1 - t0 > 0.05, "the render is too short to tell"
    assert gaps.max() < 0.5 * (t1 - t0), f"largest gap {gaps.max():.3f} s of a {t1 - t0:.3f} s render"
