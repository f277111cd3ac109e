"""The report's cohort section (`[[anatomy.dataset]]`), recomputed from the study's CSV tables with the
`csv` module: the LAT/AP ratio (each level's RMS shift on its fixed landmark set, as the Findings' table
computes it), its per-patient range, Dice and registration error at the largest Δf (median and 5th–95th
percentile across the cases' levels), and the per-case table. Two synthetic cases that differ (CT voxels
of 1.0 and 1.5 mm) and two levels each, so the statistics are over four distinct samples."""

import re
import statistics

import pytest

from test_findings import Study, fixed_landmarks, percentile, small_study

COHORT = """experiments = ["projection", "landmarks", "registration"]
heatmaps_df_px = []

[anatomy]
levels = []

[[anatomy.dataset]]
name = "syn"
folder = "ds"
layout = "totalseg"
levels = ["L1", "L2"]

[geometry]
binning = 4

[perturbations]
df_px = [100.0, 500.0]
piercing_px = [0.0, 50.0]
skew_px = []
pixel_scale = []

[registration]
methods = ["direct-ap", "direct-lat", "kabsch"]
df_px = [0.0, 500.0]
piercing_px = [0.0]
trials = 3
trials_per_unit = 3
"""

CASES = {"a": "1.0", "b": "1.5"}


@pytest.fixture(scope="module")
def cohort(cli, tmp_path_factory) -> Study:
    folder = tmp_path_factory.mktemp("cohort")
    for case, voxel in CASES.items():
        d = folder / "ds" / case
        cli("phantom", "--levels", "L1-L2", "--no-discs", "--voxel-mm", "1.5", "--ct-voxel-mm", voxel,
            "--ct", d / "ct.nii.gz", "--labels-out", d / "segmentations.nii.gz", "--out", d / "mesh")
    return small_study(cli, folder, COHORT)


def case_of(target: str) -> str:
    return "syn/" + target.split("-")[1]


def spread(values: list, digits: int) -> str:
    return (f"{statistics.median(values):.{digits}f} (5th–95th percentile {percentile(values, 5):.{digits}f}–"
            f"{percentile(values, 95):.{digits}f}, n = {len(values)})")


def section(study: Study) -> str:
    report = study.report
    start = report.index("## Cohort: spread across patients")
    return report[start:report.index("\n## ", start + 1)]


def lat_ap_ratios(study: Study) -> dict:
    """Per level target: LAT/AP of the RMS shift at its largest focal Δf over its fixed landmark set."""
    rows = [r for r in study.table("landmarks.csv") if r["family"] == "focal"]
    out = {}
    for target in {r["target"] for r in rows}:
        fixed = fixed_landmarks(rows, target)
        df = max(float(r["df_px"]) for r in rows if r["target"] == target)

        def rms(view):
            s = [float(r["shift_px"]) ** 2 for r in rows
                 if r["target"] == target and r["view"] == view and float(r["df_px"]) == df
                 and r["landmark"] in fixed]
            return (sum(s) / len(s)) ** 0.5

        out[target] = rms("lat") / rms("ap")
    return out


def test_the_cohort_section_says_what_its_tables_give(cohort):
    text = section(cohort)
    assert text.startswith("## Cohort: spread across patients\n\n2 cases from syn (4 level targets), 0 left out."), text
    assert "segment" not in text, "a run without segment targets says why they are not samples"

    ratios = lat_ap_ratios(cohort)
    assert len(ratios) == 4 and len(set(round(v, 6) for v in ratios.values())) > 1, ratios
    per_case = {}
    for t, v in ratios.items():
        per_case.setdefault(case_of(t), []).append(v)
    lo, hi = (f"{f(statistics.mean(v) for v in per_case.values()):.2f}" for f in (min, max))
    # Patients whose means print alike are said to be equal, not to range from a value to itself.
    per_patient = (f"it is {lo} in each of the 2 patients" if lo == hi
                   else f"it ranges from {lo} to {hi} over 2 patients")
    expected = (f"the LAT/AP ratio of the RMS landmark shift (each level on its fixed landmark set, the column "
                f"\"LAT/AP measured\" of the table above) is {spread(list(ratios.values()), 2)} across the cases' "
                f"levels; per patient (mean over its levels) {per_patient}.")
    assert expected in text, f"{expected}\n---\n{text}"
    # The same ratios are the Findings table's "LAT/AP measured" column.
    for t, v in ratios.items():
        assert re.search(rf"^\| {re.escape(t)} \|(?:[^|]*\|){{4}} {v:.3f} \|", cohort.report, re.M), t

    projection = cohort.table("projection.csv")
    df = max(float(r["df_px"]) for r in projection if r["family"] == "focal")
    for view in ("ap", "lat"):
        dice = [float(r["dice"]) for r in projection
                if r["family"] == "focal" and float(r["df_px"]) == df and r["view"] == view]
        assert len(dice) == 4
        line = f"{view.upper()} silhouette Dice at Δf = {df:.0f} px (an SDD error of"
        said = next(l for l in text.splitlines() if line in l)
        assert said.endswith(f": {spread(dice, 4)}."), said

    summary = cohort.table("registration_summary.csv")
    reg_df = max(float(r["df_px"]) for r in summary)
    said = next(l for l in text.splitlines() if l.startswith("- Registration translation error"))
    assert "and no piercing shift" in said and "((" not in said and ") (" not in said, said
    for method in ("direct-ap", "direct-lat", "kabsch"):
        means = [float(r["trans_err_mm_mean"]) for r in summary
                 if r["method"] == method and float(r["df_px"]) == reg_df and float(r["piercing_px"]) == 0]
        assert len(means) == 4
        assert f"{method} {spread(means, 2)} mm" in said, (method, said)

    # The per-case table: each case's median Dice over its levels at the largest Δf.
    for case in CASES:
        cells = []
        for view in ("ap", "lat"):
            v = [float(r["dice"]) for r in projection if r["family"] == "focal" and float(r["df_px"]) == df
                 and r["view"] == view and case_of(r["target"]) == f"syn/{case}"]
            cells.append(f"{statistics.median(v):.4f}")
        assert f"| syn/{case} | 2 | {cells[0]} | {cells[1]} |" in text, text


def test_the_cohort_figures_are_numbered_in_their_section_and_say_their_scales(cohort):
    """The four cohort figures are shown (numbered) in the cohort section, nowhere else as a link, and their
    captions say which panels share a y scale."""
    text = section(cohort)
    figures = re.findall(r"^_Figure (\d+)\. (Cohort: [^(]*)", text, re.M)
    assert [t.split(":")[1].strip() for _, t in figures] == [
        "mean landmark shift, AP vs LAT", "silhouette Dice vs focal offset",
        "landmark shift vs focal offset, per landmark", "registration translation error vs focal offset"], figures
    numbers = [int(n) for n, _ in figures]
    assert numbers == list(range(numbers[0], numbers[0] + 4)), numbers
    assert text.count("the views at one y scale") == 2, text
    assert "a method's AP and LAT panels share one" in text, text
    rest = cohort.report.replace(text, "")
    assert "cohort_" not in rest.split("## Products")[0], "a cohort figure linked outside its section"
