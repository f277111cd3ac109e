"""The report's Findings, recomputed: every claim of `tables/findings.json` is derived again from the CSV
tables (with the `csv` module, not the Rust code), from reference/paper-results.toml or from study.toml,
and must print as the report prints it; every categorical word follows from its rule; the rows a claim
names are those its conditions select; the report's rules (fixed landmark sets, each family's largest
step, segments never pooled with single levels) are checked from the tables; and the prose holds no
number that findings.json does not.

Two studies: `--quick` (L1 on the quick grid) and a config that differs in every way the findings
depend on (another C-arm, skew and pixel-spacing families, a segment, landmark noise σ = 1 px)."""

import csv
import json
import math
import re
import tomllib
from pathlib import Path

import pytest
import tifffile

ROOT = Path(__file__).resolve().parents[2]
PAPER = tomllib.loads((ROOT / "reference" / "paper-results.toml").read_text())

# The report's rule constants, as its documentation states them (README, "Findings").
RULES = {"tie_pct": 2.0, "calibration_percentile": 95.0}


class Study:
    def __init__(self, out: Path):
        self.out = out
        self.findings = json.loads((out / "tables" / "findings.json").read_text())["findings"]
        self.config = tomllib.loads((out / "study.toml").read_text())
        self.report = (out / "report.md").read_text()
        self._tables = {}

    def table(self, name: str) -> list:
        if name not in self._tables:
            with open(self.out / "tables" / name, newline="") as f:
                self._tables[name] = list(csv.DictReader(f))
        return self._tables[name]

    def piercing(self, target: str, view: str):
        k = json.loads((self.out / "references" / f"{target}_{view}.json").read_text())["K"]
        return (k[0][2], k[1][2])


def select(rows, where):
    return [i for i, r in enumerate(rows) if all(r.get(k) in allowed for k, allowed in where.items())]


def is_segment(target: str) -> bool:
    return target == "segment" or target.endswith("-segment")


def lookup(doc, key):
    for part in key.split("."):
        doc = doc[part]
    return doc


class Recompute:
    """Every claim's and fact's value, derived independently; memoised by id."""

    def __init__(self, study: Study, finding: dict):
        self.s = study
        self.claims = {c["id"]: c for c in finding["claims"]}
        self.facts = {f["id"]: f for f in finding["facts"]}
        self.values = {}
        self.words = {}

    def value(self, cid: str) -> float:
        if cid not in self.values:
            self.values[cid] = self._value(self.claims[cid])
        return self.values[cid]

    def _value(self, c: dict) -> float:
        src = c["source"]
        kind = src["kind"]
        if kind in ("column", "points"):
            rows = self.s.table(src["table"])
            sel = select(rows, src["where"])
            assert sel == src["rows"], f"{c['id']}: its conditions select rows {sel}, it names {src['rows']}"
        if kind == "column":
            vals = [float(rows[i][src["column"]]) for i in sel]
            if src["transform"] == "one_minus":
                vals = [1.0 - v for v in vals]
            vals = [v for v in vals if math.isfinite(v)]
            stat = src["stat"]
            if stat == "value":
                assert len(sel) == 1, c["id"]
                return vals[0]
            return {
                "mean": lambda v: sum(v) / len(v),
                "min": min,
                "max": max,
                "rms": lambda v: math.sqrt(sum(x * x for x in v) / len(v)),
                "p95": lambda v: percentile(v, 95.0),
            }[stat](vals)
        if kind == "points":
            u, v = src["columns"]
            pts = [(float(rows[i][u]), float(rows[i][v])) for i in sel]
            mu = sum(p[0] for p in pts) / len(pts)
            mv = sum(p[1] for p in pts) / len(pts)
            view = rows[sel[0]]["view"]
            assert tuple(src["about"]) == self.s.piercing(rows[sel[0]]["target"], view), c["id"]
            if src["geometry"] == "offset":
                return math.hypot(mu - src["about"][0], mv - src["about"][1])
            return math.sqrt(sum((p[0] - mu) ** 2 + (p[1] - mv) ** 2 for p in pts) / len(pts))
        if kind == "formula":
            a = [self.value(x) for x in src["of"]]
            op = src["op"]
            if op == "ratio":
                return a[0] / a[1]
            if op == "hypot":
                return math.hypot(a[0], a[1])
            if op == "share_pct":
                return 100.0 * a[0] ** 2 / (a[0] ** 2 + a[1] ** 2)
            return {"min": min, "max": max, "value": lambda v: v[0]}[op](a)
        if kind == "count":
            return float(len(src["items"]))
        if kind == "count_greater":
            # Greater beyond the printed precision: equal texts are a tie.
            d = src["decimals"]
            return float(sum(
                self.value(a) > self.value(b) and printed(self.value(a), d) != printed(self.value(b), d)
                for a, b in src["pairs"]
            ))
        if kind == "paper":
            v = lookup(PAPER, src["key"])
            if src["mean_over_entries"]:
                col = [e[src["index"]] for e in v.values()]
                return sum(col) / len(col)
            return v[src["index"]] if src["index"] is not None else v
        if kind == "rule":
            return RULES[src["name"]]
        if kind == "config":
            return float(lookup(self.s.config, src["key"]))
        if kind == "detector":
            # A size in px at this detector in mm: px × the pixel pitch along u, SDD / fx of the sidecar.
            side = json.loads((self.s.out / src["reference"]).read_text())
            return src["px"] * side["sdd_mm"] / side["K"][0][0]
        if kind == "count_word":
            return float(sum(self.word(f) == src["word"] for f in src["facts"]))
        raise AssertionError(f"unknown source {kind}")

    def word(self, fid: str) -> str:
        if fid not in self.words:
            f = self.facts[fid]
            a = [] if f["rule"] == "paper" else [self.value(x) for x in f["of"]]
            if f["rule"] == "interval":
                lo, hi, plo, phi = a
                w = "inside" if lo >= plo and hi <= phi else "outside" if hi < plo or lo > phi else "overlapping"
            elif f["rule"] == "trend":
                first, last, cf, cl = a
                margin = sum(x if math.isfinite(x) else 0.0 for x in (cf, cl))
                w = "rising" if last - first > margin else "falling" if first - last > margin else "flat"
            elif f["rule"] == "tie":
                x, y, pct = a
                w = "tied" if abs(x - y) <= pct / 100 * max(abs(x), abs(y)) else "apart"
            elif f["rule"] == "paper":
                w = lookup(PAPER, f["of"][0])
            else:
                raise AssertionError(f"unknown rule {f['rule']}")
            self.words[fid] = w
        return self.words[fid]


def percentile(v: list, q: float) -> float:
    """Linear between order statistics at position q/100·(n − 1) (numpy's default)."""
    s = sorted(v)
    pos = q / 100 * (len(s) - 1)
    i, f = int(math.floor(pos)), pos - math.floor(pos)
    return s[i] * (1 - f) + s[i + 1] * f if i + 1 < len(s) else s[i]


def printed(v: float, decimals: int) -> str:
    return f"{v:.{decimals}f}"


def check_values(study: Study) -> int:
    """Every claim recomputed equals the printed value (or, for a building block, the stored value to
    1e-9 relative); every fact's word follows from its rule. Returns the number of claims checked."""
    n = 0
    for f in study.findings:
        r = Recompute(study, f)
        for c in f["claims"]:
            ours = r.value(c["id"])
            if c["text"] is not None:
                ok = printed(ours, c["decimals"]) == c["text"]
                # A value on a rounding boundary may round either way between two summation orders.
                ok = ok or (abs(ours - c["value"]) <= 1e-9 * max(1.0, abs(ours)) and printed(c["value"], c["decimals"]) == c["text"])
                assert ok, f"{f['id']}/{c['id']}: recomputed {ours!r}, printed {c['text']}"
            else:
                assert math.isclose(ours, c["value"], rel_tol=1e-9, abs_tol=1e-12), (f["id"], c["id"], ours, c["value"])
            n += 1
        for fact in f["facts"]:
            assert r.word(fact["id"]) == fact["word"], (f["id"], fact["id"], r.word(fact["id"]), fact["word"])
    return n


NUMBER = re.compile(r"(?<![A-Za-z0-9_./])[0-9]+(?:\.[0-9]+)?")


def prose_numbers(text: str) -> list:
    """The numbers a reader sees: outside links' targets and file names, outside code spans (formulas)."""
    text = re.sub(r"\[[^\]]*\]\([^)]*\)", " ", text)
    text = re.sub(r"`[^`]*`", " ", text)
    return NUMBER.findall(text)


def shown(v: float) -> str:
    return str(int(v)) if float(v).is_integer() else repr(float(v))


def check_prose(study: Study):
    """The report's Findings bullets are findings.json's texts, in order, and each number in them is a
    printed claim or a cell parameter of that finding."""
    section = study.report.split("## Findings\n", 1)[1].split("\n## ", 1)[0]
    bullets = [line[2:] for line in section.splitlines() if line.startswith("- ")]
    assert bullets == [f["text"] for f in study.findings]
    for f in study.findings:
        allowed = {c["text"].lstrip("-") for c in f["claims"] if c["text"] is not None}
        allowed |= {shown(abs(v)) for c in f["claims"] for v in c["cell"].values()}
        stray = [x for x in prose_numbers(f["text"]) if x not in allowed]
        assert not stray, f"{f['id']}: {stray} in the prose are not in findings.json:\n{f['text']}"
    # No clause left empty: a list with nothing in it would leave its punctuation behind.
    for f in study.findings:
        for junk in (",;", ": ;", ",.", ", .", ":  ", "  "):
            assert junk not in f["text"], f"{f['id']}: {junk!r} in\n{f['text']}"
    # The prose the rest of the report writes about Findings holds no number either.
    intro = section.split("\n- ", 1)[0]
    assert not prose_numbers(intro), intro


def cut_targets(study: Study) -> set:
    """Targets whose reference silhouette (pixels > 0) touches the detector's edge in some view."""
    cut = set()
    for p in (study.out / "references").glob("*.tiff"):
        target, _, view = p.stem.rpartition("_")
        if view not in ("ap", "lat"):
            continue
        a = tifffile.imread(p) > 0
        if a[0].any() or a[-1].any() or a[:, 0].any() or a[:, -1].any():
            cut.add(target)
    # ... or a perturbed silhouette of some cell does (the projection table's cut_by_edge).
    cut |= {r["target"] for r in study.table("projection.csv") if r["cut_by_edge"] == "true"}
    return cut


def fixed_landmarks(focal: list, target: str) -> list:
    """The report's fixed landmark set of `target`: the landmarks measured (every coordinate and the shift
    finite) in both views at every focal Δf of the focal rows `focal`."""
    mine = [r for r in focal if r["target"] == target]
    dfs = {r["df_px"] for r in mine}
    ok = lambda r: all(math.isfinite(float(r[k])) for k in ("ref_u_px", "ref_v_px", "meas_u_px", "meas_v_px", "shift_px"))
    return sorted(
        name
        for name in {r["landmark"] for r in mine}
        if all(
            any(r["view"] == v and r["df_px"] == d and r["landmark"] == name and ok(r) for r in mine)
            for v in ("ap", "lat")
            for d in dfs
        )
    )


def check_rules(study: Study):
    """The report's rules, recomputed from the tables."""
    by_id = {f["id"]: f for f in study.findings}
    cut = cut_targets(study)
    for f in study.findings:
        for c in f["claims"]:
            targets = c["source"].get("where", {}).get("target", [])
            assert not (any(map(is_segment, targets)) and not all(map(is_segment, targets))), (
                f"{c['id']} pools a segment with single levels: {targets}"
            )
            # Silhouettes, structures and marker images see the detector's edge; registration observes its
            # landmarks analytically, so a cut level is pooled there like any other.
            table = c["source"].get("table", "")
            assert len(targets) < 2 or not cut & set(targets) or table.startswith("registration"), (
                f"{c['id']} pools a cut target: {targets}"
            )
            if table.startswith("registration") and len(targets) > 1 and not any(map(is_segment, targets)):
                levels = {r["target"] for r in study.table(table) if not is_segment(r["target"])}
                assert set(targets) == levels, f"{c['id']} leaves out single levels: {targets}"
    proj = study.table("projection.csv")
    if "dice_by_family" in by_id:
        fam_col = {"focal": "df_px", "piercing": "dcx_px", "joint": "df_px", "skew": "skew_px", "scale": "sy"}
        seen = set()
        for c in by_id["dice_by_family"]["claims"]:
            w = c["source"].get("where", {})
            if "family" not in w:
                continue
            fam = w["family"][0]
            col = fam_col[fam]
            steps = {float(r[col]) for r in proj if r["family"] == fam}
            base = 1.0 if fam == "scale" else 0.0
            top = max(steps, key=lambda s: abs(s - base))
            assert float(w[col][0]) == top, f"{c['id']}: not the family's largest step {top}"
            seen.add(fam)
            if ".levels." in c["id"]:
                levels = sorted({r["target"] for r in proj if not is_segment(r["target"]) and r["target"] not in cut})
                assert sorted(w["target"]) == levels, c["id"]
        assert seen == {r["family"] for r in proj}, f"families with rows but no finding: {seen}"
    if "landmark_ratio" in by_id:
        lm = study.table("landmarks.csv")
        focal = [r for r in lm if r["family"] == "focal"]
        for c in by_id["landmark_ratio"]["claims"]:
            m = re.fullmatch(r"ratio\.(.+)\.rms_(ap|lat)", c["id"])
            if not m:
                continue
            target = m.group(1)
            dfs = {r["df_px"] for r in focal if r["target"] == target}
            w = c["source"]["where"]
            assert sorted(w["landmark"]) == fixed_landmarks(focal, target), f"{c['id']}: not the fixed landmark set"
            assert float(w["df_px"][0]) == max(map(float, dfs)), f"{c['id']}: not the largest focal Δf"


def check_law(study: Study):
    """Per target, the measured LAT/AP focal-shift ratio on the fixed set equals the ratio of the RMS
    distances from the piercing point within 1 %, and offset² + spread² multiplies back to d²."""
    f = next((f for f in study.findings if f["id"] == "landmark_ratio"), None)
    assert f is not None
    r = Recompute(study, f)
    targets = {m.group(1) for c in f["claims"] if (m := re.fullmatch(r"ratio\.(.+)\.measured", c["id"]))}
    assert targets
    for t in targets:
        measured = r.value(f"ratio.{t}.rms_lat") / r.value(f"ratio.{t}.rms_ap")
        predicted = r.value(f"ratio.{t}.d_lat") / r.value(f"ratio.{t}.d_ap")
        assert abs(measured / predicted - 1) < 0.01, (t, measured, predicted)
        for v in ("ap", "lat"):
            d2 = r.value(f"ratio.{t}.offset_{v}") ** 2 + r.value(f"ratio.{t}.spread_{v}") ** 2
            assert math.isclose(d2, r.value(f"ratio.{t}.d_{v}") ** 2, rel_tol=1e-12)


def check(study: Study):
    assert study.findings, "no findings"
    assert check_values(study) > 0
    check_prose(study)
    check_rules(study)
    check_law(study)


@pytest.fixture(scope="module")
def quick(cli, tmp_path_factory) -> Study:
    out = tmp_path_factory.mktemp("quick")
    cli("study", "--quick", "--out", out)
    return Study(out)


OTHER = """
seed = 7
experiments = ["projection", "landmarks", "registration", "calibration"]
heatmaps_df_px = [500.0]

[anatomy]
levels = ["L1", "L2"]
segment = true
voxel_mm = 1.2
marker_radius_mm = 4.0

[geometry]
file = "carm.toml"
binning = 4

[perturbations]
df_px = [100.0, 300.0, 500.0]
piercing_px = [0.0, 20.0, 40.0]
skew_px = [2.0, 6.0]
pixel_scale = [0.99, 1.03]

[registration]
methods = ["direct-ap", "direct-lat", "direct-ap+lat", "kabsch"]
df_px = [0.0, 100.0, 500.0]
piercing_px = [0.0, 40.0]
trials = 6
trials_per_unit = 6
noise_px = 1.0

[calibration]
phantoms = ["helix"]
noise_px = [0.5, 1.0]
trials = 10
trials_per_unit = 10
silhouette_trials = 0
intensity_trials = 0
"""


@pytest.fixture(scope="module")
def other(cli, tmp_path_factory) -> Study:
    """Another C-arm (SDD 1200 mm, LAT source 600 mm from the aim), the skew and pixel-spacing families,
    L1, L2 and their segment, σ = 1 px, and a calibration-in-the-loop grid."""
    d = tmp_path_factory.mktemp("other")
    carm = cli("geometry").stdout
    carm = carm.replace("sdd_mm = 1350.0", "sdd_mm = 1200.0").replace(
        "source_mm = [-900.0, -25.0, 20.0]", "source_mm = [-600.0, -25.0, 10.0]"
    ).replace("target_mm = [0.0, -25.0, 20.0]", "target_mm = [0.0, -25.0, 10.0]")
    assert "sdd_mm = 1200.0" in carm and "-600.0" in carm
    (d / "carm.toml").write_text(carm)
    (d / "study.toml").write_text(OTHER)
    cli("study", "--config", d / "study.toml", "--out", d / "out")
    return Study(d / "out")


def test_every_number_of_the_quick_study_findings_is_recomputed_from_its_tables(quick):
    check(quick)
    # With projection.csv and landmarks.csv written, the report says how they are measured (a run
    # without them leaves those bullets out: tests/it/study_physical.rs).
    tables = quick.out / "tables"
    assert (tables / "projection.csv").exists() and (tables / "landmarks.csv").exists()
    how = quick.report.split("## How each measurement is made")[1].split("\n## ")[0]
    assert "marker sphere" in how and "projection.csv" in how and "Landmark overlays" in how, how
    # …and its Setup states the perturbation grid and where each target lies (tests/it/study_physical.rs:
    # neither without the experiments that use them).
    assert "perturbations of K" in quick.report and "| target | view | centroid" in quick.report


def test_every_number_of_a_different_study_is_recomputed_from_its_tables(other):
    check(other)
    families = {c["source"]["where"]["family"][0] for f in other.findings if f["id"] == "dice_by_family"
                for c in f["claims"] if "family" in c["source"].get("where", {})}
    assert {"skew", "scale", "focal", "piercing", "joint"} <= families
    sigma = [c for f in other.findings for c in f["claims"] if c["id"] == "registration.noise_px"]
    assert sigma and sigma[0]["text"] == "1"
    assert any(f["id"] == "calibration_headline" for f in other.findings)
    # The intensity-registration experiment did not run (its table is absent), so no section of it is
    # written, though its `images` default names spectral fixed images.
    assert not (other.out / "tables" / "intensity_registration_summary.csv").exists()
    headings = [line for line in other.report.splitlines() if line.startswith("#")]
    assert not [h for h in headings if "ntensity" in h or "Spectral" in h], headings


def test_a_piercing_shift_in_mm_is_said_per_axis(quick, other):
    """A piercing shift (p, p) moves the piercing point p px along u and p px along v (√2·p px in all), so
    its mm in the Findings is per axis and the prose says so; a focal offset's mm is an SDD error."""
    import re

    seen = 0
    for study in (quick, other):
        for f in study.findings:
            assert "mm on the detector" not in f["text"], f["text"]
            for c in f["claims"]:
                if c["source"]["kind"] != "detector":
                    continue
                if c["id"].endswith(".p_mm") or ".piercing_px." in c["id"]:
                    seen += 1
                    # The value alone or either end of a span `a–b mm`.
                    said = rf"(?<![0-9.]){re.escape(c['text'])}(–[0-9.]+)? mm along u and v on the detector"
                    assert re.search(said, f["text"]), (c["id"], f["text"])
                else:  # a focal offset's mm
                    assert "SDD error" in f["text"], (c["id"], f["text"])
    assert seen >= 3, seen


# L1 alone on the detector binned by 4: the small studies below add their experiments and grids to it.
L1_BINNED = """
[anatomy]
levels = ["L1"]
segment = false
voxel_mm = 1.2

[geometry]
binning = 4
"""

LAT_ONLY = 'experiments = ["projection", "registration"]\nheatmaps_df_px = []\n' + L1_BINNED + """views = ["lat"]

[perturbations]
df_px = [100.0, 500.0]
piercing_px = [0.0, 50.0]
skew_px = []
pixel_scale = []

[registration]
methods = ["direct-lat", "opencv-lat"]
df_px = [0.0, 500.0]
piercing_px = [0.0, 50.0]
trials = 4
trials_per_unit = 4
"""


def small_study(cli, folder, config: str) -> Study:
    """The study of `config` run into `folder`/out, its findings' numbers and prose checked against its
    tables (check() without the LAT/AP law, which needs both views and the landmarks)."""
    (folder / "study.toml").write_text(config)
    cli("study", "--config", folder / "study.toml", "--out", folder / "out")
    study = Study(folder / "out")
    assert check_values(study) > 0
    check_prose(study)
    return study


def test_a_one_view_study_states_what_its_one_view_measured(cli, tmp_path):
    """LAT alone: every claim recomputed as for the others; the structures' mean is over the LAT view (not
    'both views'), and the registration finding states the run's own methods, none of the two-view ones."""
    study = small_study(cli, tmp_path, LAT_ONLY)
    check_rules(study)
    assert not any(f["id"] == "landmark_ratio" for f in study.findings)
    by_id = {f["id"]: f["text"] for f in study.findings}
    assert "over the single levels and the LAT view" in by_id["structures"], by_id["structures"]
    reg = by_id["registration_by_family"]
    assert ": ;" not in reg and "direct-lat " in reg and "opencv-lat " in reg, reg
    assert "kabsch" not in reg and "direct-ap" not in reg, reg


CUT_BY_THE_EDGE = 'experiments = ["projection"]\nheatmaps_df_px = []\n' + L1_BINNED + """
[perturbations]
df_px = [100.0]
piercing_px = [0.0, 90.0]
skew_px = []
pixel_scale = []
"""


def test_a_level_cut_by_the_edge_is_reported_apart_in_a_sentence_that_reads(cli, tmp_path):
    """A piercing shift that pushes L1 over the LAT detector's edge: its silhouette loss is reported apart
    (not pooled with whole levels), and with no whole level the family's clause opens with it."""
    study = small_study(cli, tmp_path, CUT_BY_THE_EDGE)
    assert any(r["cut_by_edge"] == "true" for r in study.table("projection.csv") if r["target"] == "L1")
    text = next(f["text"] for f in study.findings if f["id"] == "dice_by_family")
    assert "single levels" not in text and " L1 AP " in text, text


def test_a_changed_table_cell_is_caught(quick, tmp_path):
    """The recomputation is not vacuous: one Dice cell changed in the CSV fails it."""
    import shutil

    out = tmp_path / "copy"
    shutil.copytree(quick.out, out)
    study = Study(out)
    rows = study.table("projection.csv")
    c = next(c for f in study.findings for c in f["claims"] if c["source"].get("column") == "dice" and c["text"])
    i = c["source"]["rows"][0]
    rows[i]["dice"] = str(float(rows[i]["dice"]) - 0.01)
    with pytest.raises(AssertionError):
        check_values(study)


def test_a_number_in_the_prose_but_not_in_findings_json_is_caught(quick, tmp_path):
    import shutil

    out = tmp_path / "copy"
    shutil.copytree(quick.out, out)
    f = quick.findings[0]
    (out / "report.md").write_text(quick.report.replace(f["text"], f["text"] + " About 42.5 % more."))
    study = Study(out)
    study.findings[0]["text"] += " About 42.5 % more."
    with pytest.raises(AssertionError, match="42.5"):
        check_prose(study)
