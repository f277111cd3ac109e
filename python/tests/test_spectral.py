"""The spectral model against independent references: μ/ρ against xraydb (Elam et al.'s tables, not the NIST
tables spinedrr embeds), TASMIP spectra against spekpy's physics model, and the polychromatic transmission
of water and bone boxes (analytic chords) against a numpy integration over the sidecar's own spectrum with
xraydb's μ/ρ and detector absorption."""

import json

import numpy as np
import pytest
import tifffile
import xraydb

import spinedrr

ENERGIES = [20.0, 40.0, 60.0, 80.0, 100.0]

# Mass fractions typed from their sources (ICRU Report 44 via NIST SRD 126 Table 2; ASTM F136), so that
# xraydb's mixture is built independently of spinedrr's table.
CORTICAL_BONE = {"H": 0.034, "C": 0.155, "N": 0.042, "O": 0.435, "Na": 0.001, "Mg": 0.002, "P": 0.103,
                 "S": 0.003, "Ca": 0.225}
TI6AL4V = {"Ti": 0.90, "Al": 0.06, "V": 0.04}


def xraydb_mu_rho(material: str, e_kev) -> np.ndarray:
    """μ/ρ (cm²/g) from xraydb: a formula or a {element: mass fraction} mixture."""
    e_ev = np.asarray(e_kev, dtype=float) * 1e3
    if isinstance(material, dict):
        return sum(w * xraydb.mu_elam(el, e_ev) for el, w in material.items())
    return xraydb.material_mu(material, e_ev, density=1.0)


@pytest.mark.parametrize("ours,ref", [("water", "H2O"), ("cortical_bone", CORTICAL_BONE),
                                      ("titanium", TI6AL4V)])
def test_mass_attenuation_within_one_percent_of_xraydb(ours, ref):
    got = spinedrr.material_mu_rho(ours, ENERGIES)
    want = xraydb_mu_rho(ref, ENERGIES)
    np.testing.assert_allclose(got, want, rtol=0.01)


# TASMIP's spectra are those of the tube Fewell et al. measured, with its inherent filtration; spekpy's are
# a bare 12° tungsten anode. With 2.0 mm Al more on spekpy's side (the equivalent of that inherent
# filtration, fitted once to TASMIP's 80 kV half-value layer) they agree at every potential below. Without
# it TASMIP is 2.7–3.2 keV harder (HVL 30–38 % thicker) at 2.5 mm Al: the difference is by design and
# bounded in the second test.
TASMIP_INHERENT_AL_MM = 2.0


@pytest.fixture(scope="module")
def spekpy_spectra():
    spekpy = pytest.importorskip("spekpy")
    out = {}
    for kv in (60, 80, 100, 120):
        for extra in (0.0, TASMIP_INHERENT_AL_MM):
            s = spekpy.Spek(kvp=kv, th=12)
            s.filter("Al", 2.5 + extra)
            out[kv, extra] = (s.get_emean(), s.get_hvl1())
    return out


@pytest.mark.parametrize("kv", [60, 80, 100, 120])
def test_tasmip_matches_spekpy_given_tasmips_inherent_filtration(kv, spekpy_spectra):
    ours = spinedrr.spectrum(str(kv), filters="al:2.5")
    mean, hvl = spekpy_spectra[kv, TASMIP_INHERENT_AL_MM]
    assert abs(ours["mean_energy_kev"] - mean) < 2.0, (ours["mean_energy_kev"], mean)
    assert abs(ours["hvl_al_mm"] / hvl - 1) < 0.05, (ours["hvl_al_mm"], hvl)


@pytest.mark.parametrize("kv", [60, 80, 100, 120])
def test_tasmip_is_harder_than_a_bare_anode_by_a_bounded_amount(kv, spekpy_spectra):
    ours = spinedrr.spectrum(str(kv), filters="al:2.5")
    mean, hvl = spekpy_spectra[kv, 0.0]
    assert 0.0 < ours["mean_energy_kev"] - mean < 4.0
    assert 1.0 < ours["hvl_al_mm"] / hvl < 1.45


@pytest.fixture(scope="module")
def coarse(cli, tmp_path_factory):
    """The default C-arm with its detector binned 8× (128², 2.4 mm pixels): the same rays, 64× fewer (the
    CLI the tests run is a debug build)."""
    path = tmp_path_factory.mktemp("geometry") / "coarse.toml"
    text = cli("geometry").stdout
    text = text.replace("width = 1024", "width = 128").replace("height = 1024", "height = 128")
    text = text.replace("pixel_spacing_mm = [0.30, 0.30]", "pixel_spacing_mm = [2.40, 2.40]")
    path.write_text(text)
    return path, spinedrr.CArm.from_file(str(path))


def box_obj(path, lo, hi):
    """An axis-aligned box as a Wavefront OBJ (outward-wound)."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    v = [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0),
         (x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)]
    quads = [(1, 4, 3, 2), (5, 6, 7, 8), (1, 2, 6, 5), (2, 3, 7, 6), (3, 4, 8, 7), (4, 1, 5, 8)]
    lines = [f"v {a} {b} {c}" for a, b, c in v]
    for a, b, c, d in quads:
        lines += [f"f {a} {b} {c}", f"f {a} {c} {d}"]
    path.write_text("\n".join(lines) + "\n")


def chords(view, lo, hi, pixels):
    """Exact path length (mm) of each pixel's ray through the box [lo, hi] (slab method)."""
    k, w2c = np.asarray(view.K), np.asarray(view.world_to_camera)
    r, t = w2c[:3, :3], w2c[:3, 3]
    source = -r.T @ t
    out = []
    for u, v in pixels:
        d = r.T @ np.linalg.solve(k, [u, v, 1.0])
        d /= np.linalg.norm(d)
        with np.errstate(divide="ignore"):
            a, b = (np.asarray(lo) - source) / d, (np.asarray(hi) - source) / d
        t0, t1 = np.max(np.minimum(a, b)), np.min(np.maximum(a, b))
        out.append(max(0.0, t1 - t0))
    return np.array(out)


def transmission(sidecar_spectral, material, density, chord_mm):
    """Σ Φ η E exp(−μ L) / Σ Φ η E over the sidecar's own bins, μ and η (0.6 mm CsI) from xraydb."""
    e = np.array(sidecar_spectral["energies_kev"])
    phi = np.array(sidecar_spectral["fluence"])
    eta = 1 - np.exp(-xraydb.material_mu("CsI", e * 1e3, density=4.51) * 0.06)
    w = phi * eta * e
    mu = xraydb_mu_rho(material, e) * density  # 1/cm
    return np.array([np.sum(w * np.exp(-mu * c / 10)) / np.sum(w) for c in chord_mm])


@pytest.mark.parametrize("name,ref,density,thicknesses", [
    ("water", "H2O", 1.0, [10.0, 50.0, 100.0, 200.0]),
    ("cortical_bone", CORTICAL_BONE, 1.92, [5.0, 20.0, 40.0]),
])
def test_box_transmission_equals_the_numpy_integration_and_hardens(cli, tmp_path, coarse, name, ref, density,
                                                                  thicknesses):
    geometry, carm = coarse
    view = carm.view("ap")
    r = np.asarray(view.world_to_camera)[:3, :3]
    axis = int(np.argmax(np.abs(r[2])))  # the world axis along the central ray
    k = np.asarray(view.K)
    pixels = [(k[0, 2] + du, k[1, 2] + dv) for du in (-18.5, 0.5, 11.5) for dv in (-15.5, 0.5, 25.5)]
    mu_eff = []
    for thick in thicknesses:
        lo, hi = np.full(3, -150.0), np.full(3, 150.0)
        lo[axis], hi[axis] = -thick / 2, thick / 2
        mesh = tmp_path / f"{name}_{thick}.obj"
        box_obj(mesh, lo, hi)
        out = tmp_path / f"{name}_{thick}.tiff"
        img = cli.render(out, "--mesh", f"{mesh}:{name}", "--geometry", geometry, "--view", "ap", "--spectrum",
                         "80", "--filter", "al:2.5")
        spectral = json.loads(out.with_suffix(".json").read_text())["details"]["spectral"]
        c = chords(view, lo, hi, pixels)
        got = np.exp(-np.array([img[int(round(v)), int(round(u))] for u, v in pixels], dtype=float))
        want = transmission(spectral, ref, density, c)
        np.testing.assert_allclose(got, want, rtol=0.005)
        mu_eff.append(-np.log(want[4]) / c[4])  # the central pixel
        # Our own effective μ follows the integration's.
        assert abs(-np.log(got[4]) / c[4] / mu_eff[-1] - 1) < 0.005
    # Beam hardening: the effective μ falls as the box thickens.
    assert all(b < a for a, b in zip(mu_eff, mu_eff[1:])), mu_eff


def test_python_spectral_render_equals_the_cli(cli, tmp_path, coarse):
    geometry, carm = coarse
    view = carm.view("lat")
    img, spectral = spinedrr.render_spectral(view, "80", phantom="L3", screws=True, filters="al:2.5")
    ref = cli.render(tmp_path / "p.tiff", "--phantom", "L3", "--screws", "--geometry", geometry, "--view", "lat",
                     "--spectrum", "80", "--filter", "al:2.5")
    np.testing.assert_array_equal(img, ref)
    assert spectral["mean_energy_kev"] == json.loads((tmp_path / "p.json").read_text())["details"]["spectral"][
        "mean_energy_kev"]
    with pytest.raises(ValueError, match="unobtainium"):
        spinedrr.material_mu_rho("unobtainium", [60.0])
    with pytest.raises(ValueError, match="outside"):
        spinedrr.material_mu_rho("water", [500.0])
    with pytest.raises(TypeError, match="exactly one"):
        spinedrr.render_spectral(view, "80")


def test_python_spectral_gpu_render_equals_the_cli_and_the_raster(cli, tmp_path, coarse):
    """``backend="gpu"`` (lavapipe in CI): the channels on the GPU, the energy sum on the host — the CLI's
    `--backend gpu` image bit for bit, the raster's within 1e-5 of its maximum; with the level's screws
    (implants: the pixels they may cover are paired on the host) the same, and unlike the image without them."""
    geometry, carm = coarse
    view = carm.view("lat")
    img, spectral = spinedrr.render_spectral(view, "80", phantom="L3", backend="gpu")
    ref = cli.render(tmp_path / "g.tiff", "--phantom", "L3", "--geometry", geometry, "--view", "lat",
                     "--spectrum", "80", "--backend", "gpu")
    np.testing.assert_array_equal(img, ref)
    assert spectral["gpu_adapter"] == json.loads((tmp_path / "g.json").read_text())["details"]["gpu_adapter"]
    cpu, cpu_spectral = spinedrr.render_spectral(view, "80", phantom="L3")
    assert "gpu_adapter" not in cpu_spectral
    assert cpu.max() > 0.5
    assert np.abs(img - cpu).max() <= 1e-5 * cpu.max()
    screwed, _ = spinedrr.render_spectral(view, "80", phantom="L3", screws=True, backend="gpu")
    ref = cli.render(tmp_path / "s.tiff", "--phantom", "L3", "--geometry", geometry, "--view", "lat",
                     "--spectrum", "80", "--screws", "--backend", "gpu")
    np.testing.assert_array_equal(screwed, ref)
    cpu_screwed, _ = spinedrr.render_spectral(view, "80", phantom="L3", screws=True)
    assert np.abs(screwed - cpu_screwed).max() <= 1e-5 * cpu_screwed.max()
    assert np.abs(screwed - img).max() > 0.1


def test_python_spectral_ct_on_the_gpu_equals_the_cli_and_the_cpu(cli, tmp_path, coarse, phantom_dir):
    """A CT's spectral DRR with ``backend="gpu"``: its material channels on the GPU — the CLI's
    `--ct … --spectrum --backend gpu` bit for bit, the CPU's within 1e-5 of its peak; with a planned screw
    (cut out of the GPU's channels on the host along its paired crossings) the same."""
    nib = pytest.importorskip("nibabel")
    geometry, carm = coarse
    view = carm.view("lat")
    ct_path = phantom_dir / "ct.nii.gz"
    img = nib.load(ct_path)
    hu = img.get_fdata()
    got, spectral = spinedrr.render_spectral(view, "80", ct=hu, affine=img.affine, backend="gpu")
    ref = cli.render(tmp_path / "ct.tiff", "--ct", ct_path, "--geometry", geometry, "--view", "lat",
                     "--spectrum", "80", "--backend", "gpu")
    np.testing.assert_array_equal(got, ref)
    assert spectral["gpu_adapter"] == json.loads((tmp_path / "ct.json").read_text())["details"]["gpu_adapter"]
    cpu, _ = spinedrr.render_spectral(view, "80", ct=hu, affine=img.affine)
    assert cpu.max() > 0.5
    assert np.abs(got - cpu).max() <= 1e-5 * cpu.max()
    plan = {"left_pedicle_entry": [18.0, -32.0, 1.0], "left_pedicle_tip": [8.0, 4.0, 0.0]}
    screwed, _ = spinedrr.render_spectral(view, "80", ct=hu, affine=img.affine, screws_at=plan,
                                          backend="gpu")
    plan_path = tmp_path / "plan.json"
    plan_path.write_text(json.dumps([{"level": "L3", "landmarks": plan}]))
    ref = cli.render(tmp_path / "cts.tiff", "--ct", ct_path, "--geometry", geometry, "--view", "lat",
                     "--spectrum", "80", "--screws-at", plan_path, "--backend", "gpu")
    np.testing.assert_array_equal(screwed, ref)
    cpu_screwed, _ = spinedrr.render_spectral(view, "80", ct=hu, affine=img.affine, screws_at=plan)
    assert np.abs(screwed - cpu_screwed).max() <= 1e-5 * cpu_screwed.max()
    assert np.abs(screwed - got).max() > 0.1


def test_python_spectral_ct_and_posed_implants_equal_the_cli(cli, tmp_path, coarse, phantom_dir):
    """A CT with screws from a plan, and meshes with an implant placed by a pose: bit for bit the CLI's
    `--ct … --screws-at` and `--implant FILE:MATERIAL:POSE.json`."""
    nib = pytest.importorskip("nibabel")
    geometry, carm = coarse
    view = carm.view("lat")
    ct_path = phantom_dir / "ct.nii.gz"
    img = nib.load(ct_path)
    plan = {"left_pedicle_entry": [18.0, -32.0, 1.0], "left_pedicle_tip": [8.0, 4.0, 0.0]}
    (tmp_path / "plan.json").write_text(json.dumps([{"level": "L3", "landmarks": plan}]))
    ref = cli.render(tmp_path / "ct.tiff", "--ct", ct_path, "--geometry", geometry, "--view", "lat",
                     "--spectrum", "80", "--screws-at", tmp_path / "plan.json")
    hu = img.get_fdata()
    got, spectral = spinedrr.render_spectral(view, "80", ct=hu, affine=img.affine, screws_at=plan)
    np.testing.assert_array_equal(got, ref)
    assert len(spectral["implants"]) == 2  # the screw's shank and head
    plain, _ = spinedrr.render_spectral(view, "80", ct=hu, affine=img.affine)
    assert np.count_nonzero(got > plain + 0.5) > 5  # the screw shows
    # A titanium rod in its own frame, placed by a pose, in the L3 cortical mesh.
    rod = tmp_path / "rod.obj"
    box_obj(rod, (-2.0, -2.0, 0.0), (2.0, 2.0, 30.0))
    c, s = np.cos(0.7), np.sin(0.7)
    pose = np.array([[1.0, 0, 0, 4.0], [0, c, -s, -20.0], [0, s, c, 3.0], [0, 0, 0, 1.0]])
    (tmp_path / "pose.json").write_text(json.dumps({"matrix": pose.tolist()}))
    cortical = phantom_dir / "L3_cortical.stl"
    ref = cli.render(tmp_path / "m.tiff", "--mesh", f"{cortical}:cortical_bone", "--geometry", geometry,
                     "--view", "lat", "--spectrum", "80", "--implant", f"{rod}:titanium:{tmp_path / 'pose.json'}")
    got, _ = spinedrr.render_spectral(view, "80", meshes=[(spinedrr.read_mesh(str(cortical)), "cortical_bone")],
                                      implants=[(spinedrr.read_mesh(str(rod)), "titanium", pose)])
    np.testing.assert_array_equal(got, ref)
    unposed, _ = spinedrr.render_spectral(view, "80", meshes=[(spinedrr.read_mesh(str(cortical)), "cortical_bone")],
                                          implants=[(spinedrr.read_mesh(str(rod)), "titanium")])
    assert np.count_nonzero(np.abs(unposed - got) > 0.1) > 5  # the pose moved the rod
    # Bad inputs say what is wrong.
    with pytest.raises(TypeError, match="exactly one"):
        spinedrr.render_spectral(view, "80", phantom="L3", ct=hu, affine=img.affine)
    with pytest.raises(TypeError, match="affine"):
        spinedrr.render_spectral(view, "80", ct=hu)
    with pytest.raises(ValueError, match="pedicle_entry"):
        spinedrr.render_spectral(view, "80", ct=hu, affine=img.affine, screws_at={"center": [0.0, 0.0, 0.0]})
    with pytest.raises(ValueError, match="reflection"):
        spinedrr.render_spectral(view, "80", phantom="L3",
                                 implants=[(spinedrr.read_mesh(str(rod)), "titanium", np.diag([1.0, 1, -1, 1]))])
    with pytest.raises(ValueError, match="unobtainium"):
        spinedrr.render_spectral(view, "80", phantom="L3", implants=[(spinedrr.read_mesh(str(rod)), "unobtainium")])
